"""`zensim loco`, the walking controller, as users run it: a real sim, a real router, a plain zenoh client.

The walking figures run under `clock: lockstep` (the controller is the clock: sim time moves at the pace
of its commands, whatever loads the machine), so they are exact and the same on a loaded CI machine;
the sim's physics is the same as in real time.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import textwrap
import time

import msgspec
import pytest

from support import TWO_JOINT_ARM, Latest, ctl, wait_for
from zensim.schemas import Keys, LocoStatus, Odometry, SimStatus

# A stand-up is 1 s to the squat and 1.5 s to the stance (walking.toml): 3 s of sim time leaves room.
STAND_UP_S = 3.0


def put_velocity(session, keys: Keys, vx: float = 0.0, vy: float = 0.0, wz: float = 0.0, timeout_s: float = 0.5) -> None:
    session.put(keys.velocity, json.dumps({"vx": vx, "vy": vy, "wz": wz, "timeout_s": timeout_s}))


class Walker:
    """A lockstep sim, `zensim loco` and the test's plain client watching odometry and state/loco."""

    def __init__(self, start_service, zsession, robot_id: str) -> None:
        self.keys = Keys(robot_id)
        self.session = zsession
        self.sim = start_service("sim", "--clock", "lockstep")
        self.odom = Latest(zsession, self.keys.odom, Odometry)
        self.status = Latest(zsession, self.keys.sim_status, SimStatus)
        self.status.keep_history = True
        self.loco_status = Latest(zsession, self.keys.loco_status, LocoStatus)
        self.odom.wait(timeout_s=60, what="the sim's first state")
        self.loco = start_service("loco")
        wait_for(lambda: "zensim loco up" in self.loco.log() or not self.loco.alive(), 60, "zensim loco to start")
        assert self.loco.alive(), self.loco.log()
        # Its alive/loco token is declared after its queryable: once this session sees the token, a query
        # reaches the queryable (before, the router may not have passed the declaration on yet).
        wait_for(lambda: any(r.ok is not None for r in zsession.liveliness().get(self.keys.alive("loco"), timeout=1)),
                 30, "alive/loco")

    def run_until(self, sim_time_s: float) -> Odometry:
        return self.odom.wait(lambda m: m.sim_time_s >= sim_time_s, 30 + 6 * max(0.0, sim_time_s - self.now()),
                              f"sim time {sim_time_s:.2f} s")

    def now(self) -> float:
        return self.odom.wait(timeout_s=30).sim_time_s

    def fell(self) -> bool:
        return any(s.fallen for s in self.status.history)

    def stand_up(self) -> Odometry:
        reply = ctl(self.session, self.keys.ctl_loco, {"verb": "walk"})
        assert reply["ok"] and reply["active"] and reply["fsm_id"] == 500, reply
        return self.run_until(self.now() + STAND_UP_S)


@pytest.fixture
def walker(start_service, zsession, robot_id):
    return Walker(start_service, zsession, robot_id)


def test_a_zenoh_client_walks_the_g1_stops_it_planted_and_walks_it_again(walker):
    """Issue 28: cmd/velocity 0.4 m/s for 10 s walks 3-5 m straight; at zero the robot stops stepping and
    stands still (< 2 cm in 5 s; the policy alone steps in place and creeps ~5 cm a second); it walks again."""
    stood = walker.stand_up()
    assert stood.pos[2] > 0.72, stood.pos
    start = walker.odom.value
    put_velocity(walker.session, walker.keys, vx=0.4, timeout_s=10.0)
    walked = walker.run_until(start.sim_time_s + 10.0)
    forward, lateral = walked.pos[0] - start.pos[0], walked.pos[1] - start.pos[1]
    assert 3.0 <= forward <= 5.0 and abs(lateral) < 0.5, (start.pos, walked.pos)
    assert walked.pos[2] > 0.6 and not walker.fell()
    # The command lapsed at +10 s: the robot stops stepping and plants both feet.
    walker.loco_status.wait(lambda s: s.walking and not s.stepping and s.commanded == (0.0, 0.0, 0.0), 30,
                            "the controller to stop stepping")
    settled = walker.run_until(walker.now() + 1.0)
    still = walker.run_until(settled.sim_time_s + 5.0)
    drift = math.dist(settled.pos[:2], still.pos[:2])
    assert drift < 0.02, (settled.pos, still.pos)
    assert still.pos[2] > 0.7 and not walker.fell()
    # The next command: it walks again.
    put_velocity(walker.session, walker.keys, vx=0.4, timeout_s=3.0)
    again = walker.run_until(still.sim_time_s + 3.0)
    assert again.pos[0] - still.pos[0] > 0.5, (still.pos, again.pos)
    status = walker.loco_status.wait(lambda s: s.policy_steps > 0, 10, "a status")
    assert status.velocity_refused == 0 and status.fsm_id == 500 and not walker.fell()


CLIENT = textwrap.dedent("""
    import json, sys, time, zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        print("up", flush=True)
        while True:  # a teleop client: the same command ten times a second, each good for 2 s of sim time
            # (lockstep runs several times faster than the wall clock: with the default 0.5 s a command could
            # lapse between two puts, and the test would not see it in force)
            session.put(sys.argv[2], json.dumps({"vx": 0.3, "timeout_s": 2.0}))
            time.sleep(0.1)
""")


def test_the_velocity_timeout_stops_a_robot_whose_client_died(walker, router_endpoint):
    walker.stand_up()
    client = subprocess.Popen([sys.executable, "-c", CLIENT, router_endpoint, walker.keys.velocity],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert client.stdout.readline().strip() == "up"
        walker.loco_status.wait(lambda s: s.commanded[0] == 0.3, 30, "the client's command in force")
    finally:
        client.send_signal(signal.SIGKILL)  # died: no last "stop" ever comes
        client.wait(10)
        client.stdout.close()
    stopped = walker.loco_status.wait(lambda s: s.commanded == (0.0, 0.0, 0.0) and not s.stepping, 60,
                                      "the robot to stop after its client died")
    assert stopped.velocity_received > 0
    # Nothing came after the client died: the timeout stopped it (a later status counts no more commands).
    later_status = walker.loco_status.wait(lambda s: s.seq >= stopped.seq + 2, 30, "two more statuses")
    assert later_status.velocity_received == stopped.velocity_received and later_status.commanded == (0.0, 0.0, 0.0)
    settled = walker.run_until(walker.now() + 1.0)
    later = walker.run_until(settled.sim_time_s + 2.0)
    assert math.dist(settled.pos[:2], later.pos[:2]) < 0.02 and not walker.fell()


def test_bad_velocity_commands_and_requests_are_refused_counted_and_the_robot_stays_up(walker):
    """NaN, 1e9, oversize (10 kB: the router itself drops cmd/** payloads over 64 kB), unknown fields, unknown FSM ids, a wildcard query, a flood: refused or shed, counted;
    the controller goes on (it keeps time: states and policy steps go on) and the robot stays up."""
    walker.stand_up()
    keys, session = walker.keys, walker.session
    before = walker.loco_status.wait(what="a status")
    bad = [json.dumps({"vx": 1e9}), json.dumps({"vx": 0.3, "timeout_s": -1}), json.dumps({"vx": 0.3, "timeout_s": 1e9}),
           '{"vx": NaN}', json.dumps({"v_x": 0.3}), json.dumps({"vx": "fast"}), b"\xff" * 10,
           json.dumps({"vx": 0.3, "pad": "x" * 10_000}), msgspec.msgpack.encode({"vx": float("nan")})]
    for i, payload in enumerate(bad, 1):
        session.put(keys.velocity, payload)
        walker.loco_status.wait(lambda s, i=i: s.velocity_received >= before.velocity_received + i, 30,
                                f"bad command {i} read")
    status = walker.loco_status.wait(lambda s: s.velocity_refused + s.velocity_shed - before.velocity_refused
                                     - before.velocity_shed >= len(bad), 30, "every bad command refused or shed")
    assert status.commanded == (0.0, 0.0, 0.0)  # none of them moved the robot
    assert status.error  # the latest refusal's reason is reported
    for request in ({"fsm_id": 12345}, {"verb": "fly"}, {"fsm_id": 2**40}, {"verb": "walk", "fsm_id": 1}, {"x": 1},
                    {"balance_mode": 7}):
        reply = ctl(session, keys.ctl_loco, request)
        assert not reply["ok"] and reply["error"], (request, reply)
        assert reply["fsm_id"] == 500  # nothing changed
    replies = list(session.get(f"{keys.root}/ctl/*", payload=json.dumps({"verb": "damp"}), timeout=10))
    loco_replies = [json.loads(r.ok.payload.to_bytes()) for r in replies
                    if r.ok is not None and str(r.ok.key_expr) == keys.ctl_loco]
    assert loco_replies and not loco_replies[0]["ok"]  # a wildcard query does nothing
    # A flood: 20 000 velocity commands as fast as a client can put them; latest wins, the rest shed.
    flood_start = walker.loco_status.wait(what="a status")
    for _ in range(20_000):
        session.put(keys.velocity, b'{"vx": 0.0}')
    # Zenoh itself drops some of a burst on its way (puts are best effort): wait until what arrived is read,
    # then most of it must have been shed, not run one by one.
    last = [flood_start.velocity_received, time.monotonic()]

    def settled(s: LocoStatus) -> bool:
        if s.velocity_received != last[0]:
            last[:] = [s.velocity_received, time.monotonic()]
        return s.velocity_received > flood_start.velocity_received + 1000 and time.monotonic() - last[1] > 1.0

    flooded = walker.loco_status.wait(settled, 60, "the flood read")
    arrived = flooded.velocity_received - flood_start.velocity_received
    assert flooded.velocity_shed - flood_start.velocity_shed > 0.75 * arrived, (arrived, flooded)
    later = walker.run_until(walker.now() + 2.0)
    assert later.pos[2] > 0.7 and not walker.fell()
    final = walker.loco_status.wait(lambda s: s.sim_time_s >= later.sim_time_s - 0.5, 30, "a newer status")
    assert final.fsm_id == 500 and final.walking and final.requests_refused >= before.requests_refused + 7
    assert walker.loco.alive()


def test_one_robot_one_walking_controller(walker, start_service):
    second = start_service("loco")
    assert second.proc.wait(30) == 2
    assert "already has a walking controller" in second.log(), second.log()
    assert walker.loco.alive()


def test_a_robot_without_a_walking_controller_says_so_in_one_line(start_service, tmp_path):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(TWO_JOINT_ARM)
    start_service("sim", "--urdf", str(urdf))
    loco = start_service("loco")
    assert loco.proc.wait(60) == 0, loco.log()
    lines = [line for line in loco.log().splitlines() if "no walking controller" in line]
    assert len(lines) == 1 and "2 joints" in lines[0], loco.log()


def test_a_restarted_sim_is_followed_and_another_robot_ends_the_walking_service(walker, start_service, tmp_path):
    """A restarted sim of the same G1 (a new run): the controller learns it again and stands it up on the next
    request; a sim restarted with another robot has no joints for this controller: it exits, saying so."""
    walker.stand_up()
    assert walker.sim.stop() == 0
    walker.sim = start_service("sim", "--clock", "lockstep")
    wait_for(lambda: "learning the robot again" in walker.loco.log() or not walker.loco.alive(), 60,
             "the walking service to see the new sim run")
    walker.odom.wait(lambda m: m.sim_time_s < 1.0, 60, "the new sim's first state")
    # Released at the restart (the new robot stands in its spawn squat): a new request stands it up.
    wait_for(lambda: walker.loco_status.value is not None and not walker.loco_status.value.active, 30,
             "the controller released after the restart")
    stood = walker.stand_up()
    assert stood.pos[2] > 0.72 and walker.loco.alive(), (stood.pos, walker.loco.log())
    assert walker.sim.stop() == 0
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(TWO_JOINT_ARM)
    start_service("sim", "--urdf", str(urdf))
    assert walker.loco.proc.wait(60) == 1, walker.loco.log()
    assert "the restarted sim runs another robot" in walker.loco.log()


def test_under_a_state_delay_the_lockstep_walker_keeps_the_sim_moving(walker):
    """A state delay's first state repeats an instant the controller already ticked on (its ticks follow the
    states' sim time), so it sends nothing and the lockstep sim would wait for ever; once the sim has waited on it
    at one instant for a few statuses, it ticks on its newest state (LocoStatus.stall_ticks) and the walk goes on."""
    walker.stand_up()
    set_at = walker.now()
    reply = ctl(walker.session, walker.keys.ctl("faults"), {"verb": "set", "link": {"state_delay_steps": 10}})
    assert reply["ok"], reply
    walked = walker.run_until(set_at + 2.0)
    assert walked.pos[2] > 0.6, "still standing"
    status = walker.loco_status.wait(lambda s: s.stall_ticks >= 1, 10, "a tick on the stalled sim")
    assert status.stall_ticks <= 3, status  # once as the delay starts (a few under load), not every state


def test_a_flood_of_forged_waiting_statuses_gives_at_most_one_stall_tick_per_period(walker):
    """state/sim is input too: 2000 forged 'lockstep, waiting at one instant' statuses in a burst make at most a
    couple of stall ticks (one per 0.2 s of wall time), not a flood of commands into the sim."""
    walker.stand_up()
    before = walker.loco_status.wait(lambda s: s.policy_steps > 0, 10, "a status").stall_ticks
    forged = json.dumps({"type": "sim_status", "sim_time_s": 123.0, "rtf": 0.0, "paused": False, "mode": "floating",
                         "fallen": False, "clock": "lockstep", "waiting": True})
    started = time.monotonic()
    for _ in range(2000):
        walker.session.put(walker.keys.sim_status, forged)
    elapsed = time.monotonic() - started
    time.sleep(0.5)
    after = walker.loco_status.wait(lambda s: True, 10, "a status").stall_ticks
    assert after - before <= 2 + elapsed / 0.2, (before, after, elapsed)
