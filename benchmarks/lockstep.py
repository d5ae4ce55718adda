"""How fast a 50 Hz controller can drive the sim in lockstep over Zenoh, against the sim alone and bare Zenoh.

    .venv/bin/python benchmarks/lockstep.py [--steps 1500] [--pings 2000]

Starts a router, an echo process and sims (floating G1) as real processes on loopback; this
process is the controller (a separate process from the sim, as a user's policy would be). It
measures, in one run:

- bare zenoh: put -> echo process -> put back (pub/sub round trip), and get -> echo queryable -> reply;
- lockstep, request/reply: `get` on ctl/advance with a MotorCommand, reply = the new states;
- lockstep, pub/sub: MotorCommand on cmd/motors, wait for the state/joints of the new instant;
- the sim's own speed: `zensim sim --rtf 0` (the rtf its state/sim reports) and, in this process,
  the physics alone (a world of one advancing `lockstep_steps` steps, as the sim does, no network).

The controller runs at 50 Hz of sim time (lockstep_steps 10 x 2 ms): each command is a PD-style
function of the state it got back (a squat-and-sway pattern on every joint), encoded as msgpack.
Figures: sim seconds per wall second, and the per-step round trip, p50 / p99, with the per-step
overhead (round trip - physics time of the 10 steps) as a multiple of the bare round trip.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

import numpy as np
import zenoh

from harness import Processes, free_port, is_alive, plain_client, wait_for
from zensim.common.wire import payload_of
from zensim.robots import robot_files
from zensim.schemas import AdvanceReply, Codec, JointState, Keys, MotorCommand, RobotInfo, SimStatus
from zensim.sim.physics import Limits
from zensim.sim.world import World

ECHO = """
import sys, threading, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%(endpoint)s"]')
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as s:
    pub = s.declare_publisher("%(root)s/bench/pong")
    sub = s.declare_subscriber("%(root)s/bench/ping", lambda sample: pub.put(sample.payload))
    qbl = s.declare_queryable("%(root)s/bench/echo", lambda q: q.reply(q.key_expr, q.payload))
    token = s.liveliness().declare_token("%(root)s/bench/alive")
    threading.Event().wait()
"""
PAYLOAD_BYTES = 2000
"""About an AdvanceReply (joint state, odometry and IMU of the G1) in msgpack."""


def get_info(session: zenoh.Session, keys: Keys) -> RobotInfo:
    codec, found = Codec(RobotInfo), []
    wait_for(lambda: found.extend(codec.decode(*payload_of(r.ok)) for r in session.get(keys.robot_info, timeout=1.0)
                                    if r.ok) or found, 30, "info/robot")
    return found[0]


class Controller:
    """50 Hz scripted PD-style policy: a slow squat and sway around the default pose, fed back by the state."""

    def __init__(self, info: RobotInfo) -> None:
        self.default = np.array(info.default_q[info.mode])
        self.phase = np.arange(len(self.default)) * 0.3
        self.k = 0

    def command(self, q: tuple[float, ...]) -> MotorCommand:
        self.k += 1
        target = self.default + 0.15 * np.sin(0.05 * self.k + self.phase)
        target += 0.05 * (target - np.asarray(q))  # uses the state it got back, as a policy does
        return MotorCommand(q=tuple(target.tolist()))


def bare_pubsub(session: zenoh.Session, root: str, n: int) -> list[float]:
    done, arrived = threading.Event(), [0.0]

    def on_pong(_sample: zenoh.Sample) -> None:
        arrived[0] = time.perf_counter()
        done.set()

    sub = session.declare_subscriber(f"{root}/bench/pong", on_pong)
    pub = session.declare_publisher(f"{root}/bench/ping")
    times = []
    for _ in range(n):
        done.clear()
        start = time.perf_counter()
        pub.put(bytes(PAYLOAD_BYTES))
        if done.wait(2.0):
            times.append(arrived[0] - start)
    sub.undeclare()
    pub.undeclare()
    return times


def bare_get(session: zenoh.Session, root: str, n: int) -> list[float]:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        replies = list(session.get(f"{root}/bench/echo", payload=bytes(PAYLOAD_BYTES), timeout=2.0))
        if replies and replies[0].ok is not None:
            times.append(time.perf_counter() - start)
    return times


def lockstep_get(session: zenoh.Session, keys: Keys, info: RobotInfo, n: int) -> tuple[list[float], float, float]:
    """Returns (per-step round trips, sim s covered, wall s taken)."""
    controller, command_codec, reply_codec = Controller(info), Codec(MotorCommand), Codec(AdvanceReply)
    encoding = zenoh.Encoding("application/msgpack")
    q = tuple(controller.default.tolist())
    times, sim0, t0 = [], None, time.perf_counter()
    reply = None
    for _ in range(n):
        start = time.perf_counter()
        payload = command_codec.encode(controller.command(q))
        replies = list(session.get(keys.ctl("advance"), payload=payload, encoding=encoding, timeout=5.0))
        reply = reply_codec.decode(replies[0].ok.payload.to_bytes(), "application/msgpack")
        times.append(time.perf_counter() - start)
        if not reply.ok:
            raise RuntimeError(f"ctl/advance refused: {reply.error}")
        q = reply.joints.q
        if sim0 is None:
            sim0 = reply.sim_time_s - info.lockstep_steps * info.timestep_s
    wall = time.perf_counter() - t0
    return times, reply.sim_time_s - sim0, wall


def lockstep_pubsub(session: zenoh.Session, keys: Keys, info: RobotInfo, n: int) -> tuple[list[float], float, float]:
    controller, command_codec, state_codec = Controller(info), Codec(MotorCommand), Codec(JointState)
    latest: list[JointState] = []
    arrived = threading.Event()

    def on_state(sample: zenoh.Sample) -> None:
        latest.append(state_codec.decode(*payload_of(sample)))
        arrived.set()

    sub = session.declare_subscriber(keys.joints, on_state)
    pub = session.declare_publisher(keys.motors, encoding=zenoh.Encoding("application/msgpack"))
    time.sleep(0.3)  # the subscription reaches the router
    q = tuple(controller.default.tolist())
    times, sim0, t0 = [], None, time.perf_counter()
    for _ in range(n):
        arrived.clear()
        start = time.perf_counter()
        pub.put(command_codec.encode(controller.command(q)))
        if not arrived.wait(5.0):
            raise RuntimeError("no state/joints after a command")
        times.append(time.perf_counter() - start)
        state = latest[-1]
        q = state.q
        if sim0 is None:
            sim0 = state.sim_time_s - info.lockstep_steps * info.timestep_s
    wall = time.perf_counter() - t0
    sub.undeclare()
    pub.undeclare()
    return times, state.sim_time_s - sim0, wall


def physics_alone(info: RobotInfo, n: int) -> list[float]:
    """Wall time of `lockstep_steps` physics steps in this process, no network (what each round trip must pay)."""
    world = World.alone("bench", robot_files("unitree_g1"), info.mode, Limits(5000.0, 500.0), watchdog_timeout_s=1.0)
    (sim,) = world.robots
    sim.watchdog_enabled = False
    controller = Controller(info)
    q = tuple(controller.default.tolist())
    times = []
    for _ in range(n):
        start = time.perf_counter()
        sim.accept_command(controller.command(q))
        world.step(info.lockstep_steps, held=True)
        q = tuple(world.reader.read(world.data, [0])[0][0].q)
        times.append(time.perf_counter() - start)
    return times


def rtf0_speed(session: zenoh.Session, keys: Keys, seconds: float) -> float:
    codec, rtfs = Codec(SimStatus), []
    sub = session.declare_subscriber(keys.sim_status, lambda s: rtfs.append(codec.decode(*payload_of(s)).rtf))
    time.sleep(seconds)
    sub.undeclare()
    return float(np.median(rtfs[2:])) if len(rtfs) > 3 else float("nan")


def stats_ms(times: list[float]) -> tuple[float, float]:
    ms = np.array(times) * 1e3
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1500, help="lockstep commands per form (1500 = 30 s of sim time)")
    parser.add_argument("--pings", type=int, default=2000, help="bare zenoh round trips per form")
    parser.add_argument("--rtf0-seconds", type=float, default=6.0, help="how long to watch the --rtf 0 sim")
    args = parser.parse_args()

    keys, fast_keys = Keys("bench"), Keys("benchfast")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID="bench", ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    procs = Processes(env, prefix="lockstep-bench-")
    try:
        procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
        with plain_client(endpoint) as session:
            procs.start("echo", [sys.executable, "-c", ECHO % {"endpoint": endpoint, "root": keys.root}])
            procs.zensim("sim", "--clock", "lockstep", "--lockstep-steps", "10")
            wait_for(lambda: is_alive(session, f"{keys.root}/bench/alive"), 30, "the echo process")
            wait_for(lambda: is_alive(session, keys.alive("sim")), 30, "the lockstep sim")
            info = get_info(session, keys)
            assert info.clock == "lockstep", "this sim does not know --clock lockstep"
            bare_pubsub(session, keys.root, 200)  # warm-up
            bare_get(session, keys.root, 200)
            rows = {
                "bare zenoh pub/sub round trip": bare_pubsub(session, keys.root, args.pings),
                "bare zenoh get round trip": bare_get(session, keys.root, args.pings),
            }
            get_times, get_sim, get_wall = lockstep_get(session, keys, info, args.steps)
            list(session.get(keys.ctl("reset"), payload=b"{}", timeout=5.0))
            sub_times, sub_sim, sub_wall = lockstep_pubsub(session, keys, info, args.steps)
            physics = physics_alone(info, args.steps)
            procs.zensim("sim", "--rtf", "0", env={"ZENSIM_ROBOT_ID": fast_keys.robot})
            wait_for(lambda: is_alive(session, fast_keys.alive("sim")), 30, "the --rtf 0 sim")
            rtf0 = rtf0_speed(session, fast_keys, args.rtf0_seconds)
    finally:
        procs.stop_all()

    physics_p50 = stats_ms(physics)[0]
    control_hz = 1.0 / (info.lockstep_steps * info.timestep_s)
    print(f"\nlockstep: floating G1, {info.lockstep_steps} steps x {info.timestep_s * 1e3:.1f} ms per command "
          f"({control_hz:.0f} Hz controller), {args.steps} commands per form, msgpack")
    print(f"{'':<44} {'p50 ms':>8} {'p99 ms':>8}")
    for name, times in rows.items():
        print(f"{name:<44} {stats_ms(times)[0]:>8.3f} {stats_ms(times)[1]:>8.3f}")
    print(f"{'physics alone, 10 steps + command (no net)':<44} {physics_p50:>8.3f} {stats_ms(physics)[1]:>8.3f}")
    for name, times, bare, sim_s, wall_s in (
        ("lockstep ctl/advance (get)", get_times, rows["bare zenoh get round trip"], get_sim, get_wall),
        ("lockstep cmd/motors -> state/joints", sub_times, rows["bare zenoh pub/sub round trip"], sub_sim, sub_wall),
    ):
        p50, p99 = stats_ms(times)
        overhead = p50 - physics_p50
        print(f"{name:<44} {p50:>8.3f} {p99:>8.3f}   {sim_s / wall_s:5.1f}x real time; "
              f"overhead {overhead:.3f} ms = {overhead / stats_ms(bare)[0]:.2f}x the bare round trip")
    print(f"{'zensim sim --rtf 0 (state/sim rtf, median)':<44} {rtf0:>8.1f}x real time")
    print(f"{'physics alone in this process':<44} {info.lockstep_steps * info.timestep_s * 1e3 / physics_p50:>8.1f}x real time")
    print(f"logs: {procs.dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
