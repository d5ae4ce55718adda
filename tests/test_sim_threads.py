"""The sim's threading rule (docs/architecture.md, "Threads") and the races it closes.

- MjData is touched only by the thread holding the physics lock: checked on the real Simulation and
  SimService (real zenoh on loopback, real MuJoCo) while clients send commands, ctl requests,
  ctl/advance, wildcard and malformed queries and the loop publishes states and statuses. A race
  on MjData cannot be forced reliably (it needs a status read to land inside mj_step), so the test
  checks the rule that prevents it: every MjData access, on any thread, with the lock held.
- A ctl request whose client gave up is dropped, not run: no late reset; at most 16 wait at once.
- info/robot pairs mode and episode from one value: a mode switch never shows the old mode with
  the new episode.
"""

from __future__ import annotations

import json
import threading
import time
import traceback
from typing import Literal

import pytest
import zenoh

from support import Latest, ctl, plain_client, wait_for
from test_sim_process import wait_alive
from zensim.schemas import Keys, SimStatus
from zensim.sim.engine import PhysicsLock
from zensim.sim.physics import Simulation
from zensim.sim.service import SimService, load_world
from zensim.sim.settings import SimSettings
from zensim.sim.world import World


class Guarded:
    """Every access to an object's MjData (`data`) from a thread without the physics lock is recorded."""

    physics: PhysicsLock | None = None
    offences: list[str] = []

    @property
    def data(self):
        lock = Guarded.physics
        if lock is not None and not lock.held():
            frames = traceback.extract_stack(limit=6)[:-1]
            where = " <- ".join(f"{f.name}:{f.lineno}" for f in reversed(frames))
            Guarded.offences.append(f"{threading.current_thread().name}: {where}")
        return self.__dict__["data"]

    @data.setter
    def data(self, value) -> None:
        self.__dict__["data"] = value


class GuardedWorld(Guarded, World):
    """The real World; its MjData guarded."""


class GuardedSimulation(Guarded, Simulation):
    """The real Simulation; its view of the world's MjData guarded."""


def serve_in_thread(router_endpoint: str, settings: SimSettings) -> tuple[SimService, list[str], threading.Thread,
                                                                           threading.Event, zenoh.Session]:
    world, _ = load_world(settings)
    world.__class__ = GuardedWorld
    for sim in world.robots:
        sim.__class__ = GuardedSimulation
    session = plain_client(router_endpoint)
    stop = threading.Event()
    service = SimService(session, settings, stop, world)
    Guarded.offences = []
    Guarded.physics = service.engine.physics  # from here on, every MjData access must hold it
    thread = threading.Thread(target=service.run, name="sim-loop", daemon=True)
    thread.start()
    return service, Guarded.offences, thread, stop, session


def bad_and_wildcard_queries(client: zenoh.Session, keys: Keys) -> None:
    """What a careless or hostile client sends: replies made off the loop thread."""
    for _ in client.get(f"{keys.root}/**", timeout=2.0):  # every queryable at once
        pass
    for verb in ("reset", "step"):
        for _ in client.get(keys.ctl(verb), payload=b"{not json", timeout=2.0):
            pass


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_mjdata_is_touched_only_with_the_physics_lock_held(router_endpoint: str, robot_id: str,
                                                          clock: Literal["realtime", "lockstep"]) -> None:
    keys = Keys(robot_id)
    settings = SimSettings(robot_id=robot_id, mode="fixed", clock=clock, status_rate_hz=100.0, state_rate_hz=250.0,
                           watchdog_timeout_s=30.0)
    service, offences, thread, stop, session = serve_in_thread(router_endpoint, settings)
    n = service.world.robots[0].robot.nu
    try:
        with plain_client(router_endpoint) as client:
            status = Latest(client, keys.sim_status, SimStatus)
            status.wait(what="a first status", timeout_s=15)
            motors = client.declare_publisher(keys.motors)
            sent = threading.Event()

            def commands() -> None:  # a controller streaming full-body commands meanwhile
                while not sent.is_set():
                    motors.put(json.dumps({"q": [0.1] * n}))
                    time.sleep(0.002)

            streamer = threading.Thread(target=commands, daemon=True)
            streamer.start()
            deadline = time.monotonic() + 3.0
            rounds = 0
            while time.monotonic() < deadline:
                bad_and_wildcard_queries(client, keys)
                for _ in client.get(keys.robot_info, timeout=2.0):
                    pass
                if clock == "lockstep":
                    assert ctl(client, keys.ctl("advance"), {"q": [0.0] * n})["ok"]
                else:
                    assert ctl(client, keys.ctl("pause"))["ok"]
                    assert ctl(client, keys.ctl("step"), {"n": 5})["ok"]
                    assert ctl(client, keys.ctl("resume"))["ok"]
                assert ctl(client, keys.ctl("reset"))["ok"]
                rounds += 1
            sent.set()
            streamer.join(2)
            last = status.wait(lambda m: m.seq > 100, what="statuses published meanwhile", timeout_s=10)
            assert rounds >= 3
            assert last.steps > 0 or last.resets > 0
    finally:
        stop.set()
        thread.join(10)
        service.close()
        session.close()
    Guarded.physics = None
    assert not offences, f"{len(offences)} MjData accesses without the physics lock, e.g.:\n" + \
        "\n".join(sorted(set(offences))[:10])


def handled_in_order(session: zenoh.Session, keys: Keys) -> None:
    """Return once the sim's ctl/step callback has taken every step request sent before: a malformed one
    is refused by that callback itself, in arrival order, so its refusal comes after they were queued."""
    replies = list(session.get(keys.ctl("step"), payload=b'{"n": "many"}', timeout=10))
    assert len(replies) == 1 and replies[0].ok is not None and not json.loads(replies[0].ok.payload.to_bytes())["ok"]


def test_a_reset_whose_client_gave_up_is_dropped_not_run(start_service, zsession: zenoh.Session, robot_id: str) -> None:
    """A reset queued behind long steps, whose client stopped waiting after 1 s, must never happen later."""
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--mode", "floating", "--paused", "true")
    wait_alive(zsession, keys)
    before = status.wait(what="a status")
    # Eight long steps queued at once, then the reset behind them. A request runs only if it could start
    # within 2 s of arriving, so the steps that run keep the loop busy for more than 2 s on any machine
    # (eight would have to take under 0.25 s each, 2.5 us a step, to fall short): the reset behind them
    # waits past 2 s and must be dropped.
    long_steps = [zsession.get(keys.ctl("step"), payload=json.dumps({"n": 100000}), timeout=120) for _ in range(8)]
    handled_in_order(zsession, keys)
    replies = list(zsession.get(keys.ctl("reset"), payload=b"{}", timeout=1.0))  # gives up after 1 s
    steps = [json.loads(r.ok.payload.to_bytes()) for pending in long_steps for r in pending if r.ok is not None]
    assert len(steps) == 8 and any(s["ok"] for s in steps)
    # Either the client got a refusal in time, or nothing: never an ok after it stopped waiting.
    assert all(r.ok is None or not json.loads(r.ok.payload.to_bytes())["ok"] for r in replies)
    seq = status.value.seq
    after = status.wait(lambda m: m.seq > seq, what="a status after every step request was answered")
    assert after.resets == before.resets, "a reset ran after its client had given up"
    assert after.episode == before.episode
    assert after.steps > 0  # the steps did run (nothing was reset after them)


def test_requests_beyond_16_waiting_are_answered_busy_at_once(start_service, zsession: zenoh.Session,
                                                              robot_id: str) -> None:
    """While the loop is busy, 16 requests may wait; the rest get `busy` at once instead of a queue slot."""
    keys = Keys(robot_id)
    start_service("sim", "--mode", "floating", "--paused", "true")
    wait_alive(zsession, keys)
    answers: list[tuple[float, dict | None]] = []
    lock = threading.Lock()

    def answered(reply: zenoh.Reply) -> None:
        with lock:
            answers.append((time.monotonic(), json.loads(reply.ok.payload.to_bytes()) if reply.ok is not None else None))

    # The long step queued first, then the burst right behind it: the burst is in while the step runs,
    # however fast the machine (100000 steps take far longer than 24 sends).
    step = zsession.get(keys.ctl("step"), payload=json.dumps({"n": 100000}), timeout=120)
    handled_in_order(zsession, keys)
    sent = time.monotonic()
    for _ in range(24):
        zsession.get(keys.ctl("pause"), answered, payload=b"{}", timeout=120.0)  # as long as the step may take
    assert [r.ok is not None for r in step] == [True], "the step gets one reply"
    wait_for(lambda: len(answers) == 24, 60, "a reply to each of the 24 requests")
    assert all(reply is not None for _, reply in answers), "every request gets one reply"
    busy = [(t - sent, reply) for t, reply in answers if not reply["ok"] and reply["error"].startswith("busy")]
    assert len(busy) >= 24 - 16, [(reply["ok"], reply["error"]) for _, reply in answers]
    assert all(t < 5.0 for t, _ in busy), "a busy answer comes at once, not after the wait"


def test_info_never_pairs_the_old_mode_with_the_new_episode(start_service, zsession: zenoh.Session,
                                                            robot_id: str) -> None:
    keys = Keys(robot_id)
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, keys)
    seen: dict[str, set[str]] = {}
    stop = threading.Event()

    def ask() -> None:
        while not stop.is_set():
            for r in zsession.get(keys.robot_info + "?format=json", timeout=5.0):
                if r.ok is not None:
                    info = json.loads(r.ok.payload.to_bytes())
                    seen.setdefault(info["episode"], set()).add(info["mode"])

    askers = [threading.Thread(target=ask, daemon=True) for _ in range(3)]
    for asker in askers:
        asker.start()
    episodes = set()
    try:
        for mode in ("floating", "fixed") * 4:
            reply = ctl(zsession, keys.ctl("mode"), {"mode": mode}, timeout_s=30)
            assert reply["ok"] and reply["mode"] == mode
            episodes.add((reply["episode"], mode))
    finally:
        stop.set()
        for asker in askers:
            asker.join(10)
    # What ctl/mode said of each new episode, info/robot says too, and never anything else.
    for episode, mode in episodes:
        assert seen.get(episode, {mode}) == {mode}, f"episode {episode}: info/robot said {seen[episode]}"
    mixed = {e: modes for e, modes in seen.items() if len(modes) > 1}
    assert not mixed, f"one episode described with two modes: {mixed}"
    wait_for(lambda: len(seen) >= 4, 1, "info/robot answered across the switches")
