"""One engine for a robot alone and a world (services/sim/engine.py): what leaked when they were two.

- A robot's ctl/reset in a world leaves the world's schedule alone (it replaced the world's one pacer:
  every robot's schedule restarted, so resets at a steady rate ran the world faster than its rtf).
- world/step of a paused world checks MuJoCo's warnings and says so (they are the world's; a robot's own
  check skipped them, and a world MuJoCo had silently reset answered `ok`). A robot of a world of several
  refuses ctl/step: it would step every robot (issue 26).
- A world of 8 robots compiles MuJoCo once (each robot compiled its other mode again, only to describe it);
  ctl/reset with a mode and `zensim robot build` compile once (they compiled twice).
- A world of several robots refuses a mode switch and says why; a world of one rebuilds.
- Issue 27: resets are logged at a bounded rate; a deeply nested world file is one line, not a traceback; a
  command put on a wildcard (`zensim/*/cmd/motors`) is refused by every robot; sources a sender claims buy
  no more decodes (a budget per take, least recently served first).

Real zenoh on loopback, real MuJoCo, `zensim sim` as users start it where the schedule is measured.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import mujoco
import pytest
import zenoh

from support import Latest, Service, ctl, plain_client, wait_for
from test_sim_process import wait_alive
from zensim.robots.cli import main as robot_cli
from zensim.schemas import JointState, Keys, SimStatus
from zensim.sim.commands import Turns
from zensim.sim.service import SimService, load_world
from zensim.sim.settings import SimSettings

STIFF_WRIST = {"names": ["left_wrist_roll_joint", "left_wrist_pitch_joint", "left_wrist_yaw_joint", "left_elbow_joint"],
               "q": [0.5] * 4, "kp": [5000.0] * 4, "kd": [0.0] * 4}
"""Allowed values no integrator survives at a 50 ms step (test_hostile_clients' broken-physics command)."""


def world_file(tmp_path: Path, world_id: str, robots: list[str], mode: str = "fixed") -> str:
    path = tmp_path / "world.toml"
    path.write_text(f'id = "{world_id}"\n' + "".join(
        f'[[robots]]\nid = "{robot}"\nmode = "{mode}"\nxy = [{2.0 * k}, 0.0]\n' for k, robot in enumerate(robots)))
    return str(path)


@pytest.fixture
def compiles(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """Counts MuJoCo compiles (MjSpec.compile, whoever calls it) in this process."""
    count = [0]
    original = mujoco.MjSpec.compile

    def counted(self: mujoco.MjSpec, *args: object, **kwargs: object) -> mujoco.MjModel:
        count[0] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(mujoco.MjSpec, "compile", counted)
    yield count


def serve(router_endpoint: str, settings: SimSettings, world_and_file: tuple) -> tuple[SimService, threading.Event,
                                                                                      threading.Thread, zenoh.Session]:
    session = plain_client(router_endpoint)
    stop = threading.Event()
    service = SimService(session, settings, stop, *world_and_file)
    thread = threading.Thread(target=service.run, name="sim-loop", daemon=True)
    thread.start()
    return service, stop, thread, session


def shut(service: SimService, stop: threading.Event, thread: threading.Thread, session: zenoh.Session) -> None:
    stop.set()
    thread.join(10)
    service.close()
    session.close()


def test_a_world_of_8_robots_compiles_mujoco_once(tmp_path: Path, router_endpoint: str, robot_id: str,
                                                  compiles: list[int]) -> None:
    robots = [f"{robot_id}-{k}" for k in range(8)]
    settings = SimSettings(world=world_file(tmp_path, f"{robot_id}-w", robots, mode="floating"))
    served = serve(router_endpoint, settings, load_world(settings))
    try:
        with plain_client(router_endpoint) as client:
            # Every robot is described in both modes all the same (the figures of the other mode come from
            # the robot's control file, not from a model compiled for it).
            for robot in robots:
                info = ctl(client, Keys(robot).robot_info + "?format=json")
                assert info["base_height_m"] == {"floating": 0.85, "fixed": 0.79}, info["base_height_m"]
                assert set(info["gains"]) == set(info["default_q"]) == {"floating", "fixed"}
    finally:
        shut(*served)
    assert compiles[0] == 1, f"MuJoCo compiled {compiles[0]} times for a world of 8 robots"


def test_a_reset_with_a_mode_and_robot_build_compile_once(tmp_path: Path, router_endpoint: str, robot_id: str,
                                                          compiles: list[int]) -> None:
    settings = SimSettings(robot_id=robot_id, mode="fixed")
    served = serve(router_endpoint, settings, load_world(settings))
    try:
        with plain_client(router_endpoint) as client:
            keys = Keys(robot_id)
            wait_for(lambda: list(client.liveliness().get(keys.alive("sim"), timeout=1)), 10, "the sim up")
            before = compiles[0]
            reply = ctl(client, keys.ctl("reset"), {"mode": "floating"})
            assert reply["ok"] and reply["mode"] == "floating", reply
            assert compiles[0] - before == 1, f"ctl/reset with a mode compiled {compiles[0] - before} times"
            assert ctl(client, keys.robot_info + "?format=json")["mode"] == "floating"
    finally:
        shut(*served)
    before = compiles[0]
    assert robot_cli(["build", "g1", "--mode", "fixed", "-o", str(tmp_path / "out")]) == 0
    assert compiles[0] - before == 1, f"`zensim robot build` compiled {compiles[0] - before} times"


def test_a_robots_reset_in_a_world_leaves_the_others_schedule_alone(
        tmp_path: Path, start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> None:
    """At rtf 0.1 a step is due every 20 ms. A robot's reset used to give the world a new pacer, whose first
    step is due at once: resets at a steady rate ran every robot of the world twice as fast as asked."""
    a, b = f"{robot_id}-a", f"{robot_id}-b"
    start_service("sim", "--world", world_file(tmp_path, f"{robot_id}-w", [a, b]), "--rtf", "0.1")
    status = Latest(zsession, Keys(b).sim_status, SimStatus)
    wait_alive(zsession, Keys(a))
    status.wait(lambda s: s.sim_time_s > 0.02, 30, "the world running")
    resets = 0
    first = status.wait(lambda s: True, 5, "a status of b")
    started = time.monotonic()
    while time.monotonic() - started < 4.0:
        assert ctl(zsession, Keys(a).ctl("reset"))["ok"]
        resets += 1
    seq = status.value.seq
    last = status.wait(lambda s: s.seq > seq, 5, "a fresh status of b")
    wall_s = time.monotonic() - started
    rate = (last.sim_time_s - first.sim_time_s) / wall_s
    assert resets >= 20, f"only {resets} resets went through in {wall_s:.1f} s"
    assert last.resets == first.resets, "b was reset with a"
    # Loosely: a loaded machine runs slower than asked, never faster (0.2 and more with the leak).
    assert rate < 0.14, f"b's sim time ran at {rate:.3f} x real time while a was reset {resets} times (rtf 0.1)"


def test_world_step_in_a_paused_world_checks_mujocos_warnings_and_a_mode_switch_is_refused(
        tmp_path: Path, start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> None:
    a, b = f"{robot_id}-a", f"{robot_id}-b"
    start_service("sim", "--world", world_file(tmp_path, f"{robot_id}-w", [a, b]), "--timestep-s", "0.05",
                  "--paused", "true", "--watchdog-timeout-s", "60")
    status_a = Latest(zsession, Keys(a).sim_status, SimStatus)
    status_b = Latest(zsession, Keys(b).sim_status, SimStatus)
    wait_alive(zsession, Keys(a))
    zsession.put(Keys(a).motors, json.dumps(STIFF_WRIST))
    status_a.wait(lambda s: s.command_age_s is not None, 10, "the stiff command held")
    reply = ctl(zsession, Keys(f"{robot_id}-w").world_step, {"n": 20})
    assert reply["ok"] is False and "physics broke" in reply["error"] and "MuJoCo" in reply["error"], reply
    # MuJoCo's warnings are the whole world's: every robot was reset, and says why.
    for status in (status_a, status_b):
        said = status.wait(lambda s: s.physics_resets > 0, 10, "the reset said")
        assert "MuJoCo" in said.last_reset_reason
    # A world of several robots keeps its mode, and the reply says so (a robot alone rebuilds).
    for verb, request in (("mode", {"mode": "floating"}), ("reset", {"mode": "floating"})):
        refused = ctl(zsession, Keys(a).ctl(verb), request)
        assert refused["ok"] is False and "keeps its mode" in refused["error"] and refused["mode"] == "fixed", refused


def test_the_sim_logs_resets_at_a_bounded_rate(start_service: Callable[..., Service], zsession: zenoh.Session,
                                              robot_id: str) -> None:
    """Issue 27: the sim logged one line per ctl/reset (862 lines a second under a reset flood)."""
    keys = Keys(robot_id)
    sim = start_service("sim", "--mode", "fixed")
    wait_alive(zsession, keys)
    started = time.monotonic()
    resets = 0
    while time.monotonic() - started < 2.0:
        assert ctl(zsession, keys.ctl("reset"))["ok"]
        resets += 1
    seconds = time.monotonic() - started
    lines = [line for line in sim.log().splitlines() if " reset (mode " in line]
    assert resets >= 20, f"only {resets} resets in {seconds:.1f} s"
    assert 1 <= len(lines) <= seconds + 2, f"{len(lines)} log lines for {resets} resets in {seconds:.1f} s"
    assert "more like it held back" in sim.log()


def test_a_deeply_nested_world_file_is_one_line_naming_it(tmp_path: Path) -> None:
    """Issue 27: a deeply nested world file raised RecursionError, a traceback, instead of naming the file."""
    nested = tmp_path / "nested.toml"
    nested.write_text("robots = " + "[" * 100_000 + "]" * 100_000 + "\n")
    result = subprocess.run([sys.executable, "-m", "zensim", "sim", "--world", str(nested)], capture_output=True,
                            text=True, timeout=60, env={**os.environ, "ZENSIM_ZENOH_MULTICAST_SCOUTING": "false"})
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr[-2000:]
    lines = [line for line in result.stderr.splitlines() if line.startswith("zensim ")]
    assert len(lines) == 1 and "nested.toml" in lines[0] and "--world" in lines[0], result.stderr[-2000:]


def test_a_command_put_on_a_wildcard_is_refused_by_every_robot(
        tmp_path: Path, start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> None:
    """Issue 27 item 4: a put on `zensim/*/cmd/motors` reached every robot of a world and moved them all (a
    flood of them took a world down to 0.12 x real time). It is refused, counted, shed like any flood."""
    a, b = f"{robot_id}-a", f"{robot_id}-b"
    start_service("sim", "--world", world_file(tmp_path, f"{robot_id}-w", [a, b]), "--watchdog-timeout-s", "60")
    statuses = {robot: Latest(zsession, Keys(robot).sim_status, SimStatus) for robot in (a, b)}
    joints = {robot: Latest(zsession, Keys(robot).joints, JointState) for robot in (a, b)}
    wait_alive(zsession, Keys(b))
    info = ctl(zsession, Keys(a).robot_info + "?format=json")
    elbow = info["joint_names"].index("left_elbow_joint")
    default = info["default_q"]["fixed"][elbow]
    wildcard = json.dumps({"names": ["left_elbow_joint"], "q": [default + 0.8]})
    for _ in range(200):
        zsession.put("zensim/*/cmd/motors", wildcard)
        time.sleep(0.002)
    for robot in (a, b):
        refused = statuses[robot].wait(lambda s: s.rejected_commands > 0, 10, f"{robot} refusing the wildcard")
        assert "wildcard" in (refused.last_error or ""), refused.last_error
        t = joints[robot].wait(lambda m: True, 5, "a state").sim_time_s
        later = joints[robot].wait(lambda m: m.sim_time_s > t + 0.3, 10, "a later state")
        assert abs(later.q[elbow] - default) < 0.05, f"{robot}'s elbow moved to {later.q[elbow]:.2f} on a wildcard put"
    # The same command put on a robot's own key moves that robot.
    zsession.put(Keys(a).motors, wildcard)
    joints[a].wait(lambda m: abs(m.q[elbow] - default - 0.8) < 0.05, 10, "a's elbow following its own command")


def test_turns_go_to_the_least_recently_served_source_and_a_refused_one_waits() -> None:
    """Pure: the budget per take, and who gets it (services/sim/commands.py `Turns`)."""
    turns = Turns(budget=2)
    assert turns.choose(["controller"]) == ([0], [])  # a controller's command, before any flood
    turns.served("controller", accepted=True)
    flood = [f"f{k}" for k in range(6)]
    served: list[str] = []
    for _ in range(3):  # six flooding sources, two turns per take: each waits its turn in rotation
        chosen, shed = turns.choose(flood)
        assert len(chosen) == 2 and len(shed) == 4
        for position in chosen:
            turns.served(flood[position], accepted=True)
            served.append(flood[position])
    assert sorted(served) == sorted(flood), "every flooding source got one turn in three takes"
    # The controller's next command, among them, is served at once: it waited longer than any flooder (a
    # flooder claiming a fresh source for each command waits behind it too).
    chosen, _ = turns.choose([*flood, "fresh", "controller"])
    assert 7 in chosen and 6 not in chosen
    # A source whose command was refused goes behind every other for a while.
    turns.served("controller", accepted=False)
    for _ in range(10):
        chosen, _ = turns.choose(["controller", "f0", "f1"])
        assert 0 not in chosen
        for position in chosen:
            turns.served(["controller", "f0", "f1"][position], accepted=True)


def test_a_flood_from_many_claimed_sources_costs_the_sim_a_bounded_number_of_decodes(
        start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> None:
    """Issue 27 item 3: the newest command of each source was decoded at every take, and a source is what the
    sender claims: 64 publishers of one client bought 64 decodes per take (the sim fell to 0.58 x real
    time). Now a robot decodes at most MAX_DECODES_PER_TAKE per take, a source whose command was refused
    waits its next turn, and the rest are shed unread."""
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--mode", "fixed", "--watchdog-timeout-s", "60")
    wait_alive(zsession, keys)
    before = status.wait(lambda s: True, 10, "a status")
    publishers = [zsession.declare_publisher(keys.motors) for _ in range(64)]
    bad = json.dumps({"names": ["no_such_joint"], "q": [0.0]}).encode()
    started = time.monotonic()
    bursts = 0
    while bursts < 300:  # 100 bursts a second of one bad command from each of 64 claimed sources
        bursts += 1
        for publisher in publishers:
            publisher.put(bad, source_info=zenoh.SourceInfo(publisher.id, bursts))
        time.sleep(max(0.0, started + 0.01 * bursts - time.monotonic()))
    seq = status.value.seq
    after = status.wait(lambda s: s.seq > seq + 2, 10, "statuses after the flood")
    decoded = after.rejected_commands - before.rejected_commands
    shed = after.shed_commands - before.shed_commands
    sent = 64 * bursts
    assert decoded + shed >= sent // 4, f"only {decoded + shed} of {sent} commands reached the sim"
    # Every source had its turn (16 takes of 4), then each refused one waited REFUSED_PENALTY_TAKES takes for its
    # next: at most a tenth of the flood was decoded. Before, each take decoded the newest of all 64 sources:
    # every command of the flood, or nearly, as the takes kept up with the bursts.
    assert 64 <= decoded <= 0.25 * sent, f"{decoded} of {sent} decoded ({shed} shed): the claimed sources bought decodes"
    for publisher in publishers:
        publisher.undeclare()


def test_candidates_keep_the_newest_or_a_uniform_sample_of_a_suspects_flood() -> None:
    """Pure (services/sim/commands.py `Candidates`, `Turns.contested`): a source's newest wins; a contested
    source's flood keeps a good sample among 10 garbage ones keep/10 of the time wherever it came."""
    import random

    from zensim.sim.commands import Candidates

    newest: Candidates[int] = Candidates(1, random.Random(1))
    assert [newest.add(k) for k in range(5)] == [0, 1, 1, 1, 1] and newest.newest_first() == [4]
    kept = 0
    for trial in range(2000):
        suspect: Candidates[str] = Candidates(4, random.Random(trial))
        good_at = trial % 10
        for k in range(10):
            suspect.add("good" if k == good_at else f"garbage{k}")
        samples = suspect.newest_first()
        assert len(samples) == 4
        kept += "good" in samples
    assert 0.3 < kept / 2000 < 0.5, kept  # 4 of 10, whichever arrival was the good one
    turns = Turns()
    turns.choose(["garbage", "client"])
    turns.served("garbage", accepted=False)
    assert not turns.contested("garbage")  # garbage alone: newest-wins, nothing to find among it
    turns.served("client", accepted=True, refused=True)  # a refused command, then an accepted one, in one turn
    assert turns.contested("client")


def test_garbage_claiming_a_clients_own_source_does_not_starve_it(
        start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str, router_endpoint: str) -> None:
    """Issue 27 item 3: a flood of garbage put under a good client's own zenoh source id (read off its samples,
    as any subscriber can) replaced each of the client's commands before a take (newest wins per source):
    its commands stopped applying (command age 51-163 ms median beside a 10 kHz flood, 25-39 ms once fixed).
    Now a source with accepted and refused commands keeps a uniform sample of its arrivals, tried newest first:
    the client's apply.

    What a user notices, asserted: the client keeps control of its robot beside the flood, its command age p50
    under 100 ms and p90 under 500 ms. Not asserted: how much better than newest-wins it does. On the slower
    machine of 2026-11-27 late, newest-wins (SUSPECT_KEEP = 1) and the fix gave the same figures (p50 38-49 ms,
    p90 136-163 ms; the same flood from a source of its own: p50 10 ms), and the earlier 60/200 ms bounds
    failed the fixed code there (p50 58, p90 221 ms): they measured the machine. docs/benchmarks.md keeps the
    figures; whether the reservoir still helps is an open question there."""
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    status.keep_history = True
    start_service("sim", "--mode", "fixed", "--watchdog-timeout-s", "60", "--status-rate-hz", "50")
    wait_alive(zsession, keys)
    good = zsession.declare_publisher(keys.motors)
    command = json.dumps({"names": ["left_elbow_joint"], "q": [0.5]})
    flooder = subprocess.Popen([sys.executable, "-c", FORGED_FLOOD, router_endpoint, keys.motors, "6"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        sn = 0
        flooding_from = None
        while flooder.poll() is None:  # a 50 Hz controller, its source info set as zensim's publishers set it
            sn += 1
            good.put(command, source_info=zenoh.SourceInfo(good.id, sn))
            if flooding_from is None and status.value is not None and status.value.rejected_commands > 100:
                flooding_from = len(status.history)
            time.sleep(0.02)
    finally:
        if flooder.poll() is None:
            flooder.kill()
        out = flooder.communicate(timeout=10)[0]  # reads and closes its pipe
        good.undeclare()
    assert flooder.returncode == 0 and flooding_from is not None, out
    ages = sorted(s.command_age_s for s in status.history[flooding_from:-5])
    median, p90 = ages[len(ages) // 2], ages[len(ages) * 9 // 10]
    print(f"\nflood: {out.strip()}; good client's command age p50 {median * 1e3:.0f} ms, p90 {p90 * 1e3:.0f} ms, "
          f"max {ages[-1] * 1e3:.0f} ms over {len(ages)} statuses")
    assert len(ages) > 50 and median < 0.1 and p90 < 0.5, (median, p90, ages[-5:])

FORGED_FLOOD = r"""
import json, os, sys, time, zenoh
endpoint, key, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
with zenoh.open(conf) as session:
    seen = []
    sub = session.declare_subscriber(key, lambda s: s.source_info is not None and seen.append(s.source_info.source_id))
    deadline = time.monotonic() + 10
    while not seen and time.monotonic() < deadline:
        time.sleep(0.01)
    sub.undeclare()
    if not seen:
        sys.exit("no sample with source info from the good client")
    pub = session.declare_publisher(key)
    garbage = [os.urandom(1 + k % 199) for k in range(500)]
    sent, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        pub.put(garbage[sent % 500], source_info=zenoh.SourceInfo(seen[0], sent + 1))
        sent += 1
        if sent % 10 == 0:
            time.sleep(0.001)  # about 10 kHz at most
    print(json.dumps({"sent": sent, "rate_hz": round(sent / (time.perf_counter() - start))}))
"""
