"""Latency of a joint target through the bridge and the sim, against the direct paths, in one run.

    .venv/bin/python benchmarks/bridge_latency.py [--trials 100] [--state-rate-hz 500]

Starts a router, a sim (floating G1, rtf 1) and, in turn, bridges, all as real processes on
loopback, and measures from the client's `put` to the first state/joints that reflects it:

- bare zenoh:  ping -> an echo process -> pong (the transport's round trip through the router);
- direct:      MotorCommand on cmd/motors -> sim -> state/joints (no bridge running);
- bridge:      JointTargets on cmd/joints -> bridge -> cmd/motors -> sim -> state/joints, with the
               bridge at 100 Hz (default) and at 1 kHz, slew limit off (a slew limit delays on purpose).

"Reflects it": the elbow's reported actuator torque swings past 40 % of what the step asks for,
in the new direction. The step (0.3 rad, kp 300, kd 5 in floating mode) is about critically
damped, so the torque never swings that way by itself; trials are spaced 100-200 ms apart at
random so the joint settles and trials do not lock onto the bridge's or the sim's period.
The sim publishes states every 1/state_rate_hz of sim time, which adds up to that much to
every sim path; 500 Hz (every physics step) keeps that small.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from harness import Processes, client_config, free_port, is_alive, wait_for
from zensim.common.wire import payload_of
from zensim.schemas import Codec, JointState, JointTargets, Keys, MotorCommand, RobotInfo

JOINT = "left_elbow_joint"
STEP_RAD = 0.3
ECHO = """
import sys, threading, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%s"]')
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as s:
    pub = s.declare_publisher("%s/bench/pong")
    sub = s.declare_subscriber("%s/bench/ping", lambda sample: pub.put(sample.payload))
    token = s.liveliness().declare_token("%s/bench/echo")
    threading.Event().wait()
"""


class TorqueProbe:
    """Times a trial from `arm()` to the first state whose torque on the joint swings the new way."""

    def __init__(self, index: int, threshold: float) -> None:
        self._index = index
        self._threshold = threshold
        self._codec = Codec(JointState)
        self._lock = threading.Lock()
        self._direction = 0.0
        self._t0 = 0.0
        self.latency_s = float("nan")
        self.done = threading.Event()

    def arm(self, direction: float) -> None:
        with self._lock:
            self.done.clear()
            self._direction = direction
            self._t0 = time.perf_counter()

    def on_state(self, sample: zenoh.Sample) -> None:
        now = time.perf_counter()
        state = self._codec.decode(*payload_of(sample))
        with self._lock:
            if self._direction and state.tau[self._index] * self._direction > self._threshold:
                self.latency_s = now - self._t0
                self._direction = 0.0
                self.done.set()


def run_trials(probe: TorqueProbe, send: Callable[[float], None], trials: int, low: float, high: float) -> list[float]:
    """Alternate the joint between `low` and `high`; return the latencies, s."""
    latencies = []
    target = high
    for _ in range(trials):
        direction = 1.0 if target == high else -1.0
        probe.arm(direction)
        send(target)
        if probe.done.wait(2.0):
            latencies.append(probe.latency_s)
        time.sleep(random.uniform(0.1, 0.2))
        target = low if target == high else high
    return latencies


def ping_trials(session: zenoh.Session, root: str, trials: int) -> list[float]:
    done = threading.Event()
    arrived = [0.0]

    def on_pong(_sample: zenoh.Sample) -> None:
        arrived[0] = time.perf_counter()
        done.set()

    sub = session.declare_subscriber(f"{root}/bench/pong", on_pong)
    pub = session.declare_publisher(f"{root}/bench/ping")
    latencies = []
    payload = bytes(800)  # about a MotorCommand
    for _ in range(trials):
        done.clear()
        start = time.perf_counter()
        pub.put(payload)
        if done.wait(2.0):
            latencies.append(arrived[0] - start)
        time.sleep(random.uniform(0.002, 0.01))
    sub.undeclare()
    pub.undeclare()
    return latencies


def elbow_trials(session: zenoh.Session, keys: Keys) -> tuple[int, np.ndarray, float, float, TorqueProbe]:
    """Ask the sim for its robot; the elbow's index, the default pose, the step's two targets and the probe."""
    codec = Codec(RobotInfo)
    infos: list[RobotInfo] = []
    wait_for(lambda: infos.extend(codec.decode(*payload_of(r.ok)) for r in session.get(keys.robot_info, timeout=1.0)
                                    if r.ok) or infos, 30, "info/robot")
    info = infos[0]
    i = info.joint_names.index(JOINT)
    default = np.array(info.default_q[info.mode])
    kp = info.gains[info.mode].kp[i]
    threshold = 0.4 * min(info.effort_limit[i], kp * 2 * STEP_RAD)
    return i, default, float(default[i]) - STEP_RAD, float(default[i]) + STEP_RAD, TorqueProbe(i, threshold)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100, help="trials per sim path")
    parser.add_argument("--pings", type=int, default=1000, help="bare zenoh round trips")
    parser.add_argument("--state-rate-hz", default="500", help="the sim's state rate")
    parser.add_argument("--bridge-rates", default="100,1000", help="bridge rates to measure, Hz, comma-separated")
    parser.add_argument("--skip-direct", action="store_true", help="measure only the bridge paths")
    args = parser.parse_args()

    robot_id = "bench"
    keys = Keys(robot_id)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    procs = Processes(env)
    rows: list[tuple[str, list[float], int]] = []
    try:
        procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
        with zenoh.open(client_config(endpoint)) as session:
            procs.start("echo", [sys.executable, "-c", ECHO % (endpoint, keys.root, keys.root, keys.root)])
            wait_for(lambda: is_alive(session, f"{keys.root}/bench/echo"), 30, "the echo process")
            if args.pings:
                rows.append(("bare zenoh round trip (client -> echo -> client)",
                             ping_trials(session, keys.root, args.pings), args.pings))

            procs.zensim("sim", "--mode", "floating", "--rtf", "1", "--state-rate-hz", args.state_rate_hz)
            i, default, low, high, probe = elbow_trials(session, keys)
            states = session.declare_subscriber(keys.joints, probe.on_state)

            motors_codec = Codec(MotorCommand)
            motors = session.declare_publisher(keys.motors, encoding=zenoh.Encoding("application/msgpack"))

            def send_motors(target: float) -> None:
                q = default.copy()
                q[i] = target
                motors.put(motors_codec.encode(MotorCommand(q=tuple(q.tolist()))))

            send_motors(float(default[i]))
            time.sleep(0.5)
            if not args.skip_direct:
                rows.append(("direct: client -> cmd/motors -> sim -> state/joints",
                             run_trials(probe, send_motors, args.trials, low, high), args.trials))
            send_motors(float(default[i]))

            targets_codec = Codec(JointTargets)
            targets = session.declare_publisher(keys.joint_targets, encoding=zenoh.Encoding("application/msgpack"))

            def send_target(target: float) -> None:
                targets.put(targets_codec.encode(JointTargets(names=(JOINT,), q=(target,))))

            for rate in args.bridge_rates.split(","):
                bridge = procs.zensim("bridge", "--rate-hz", rate, "--slew-rad-s", "0")
                wait_for(lambda: is_alive(session, keys.alive("bridge")), 30, "alive/bridge")
                send_target(float(default[i]))
                time.sleep(0.5)
                rows.append((f"bridge {rate} Hz: client -> cmd/joints -> bridge -> sim -> state/joints",
                             run_trials(probe, send_target, args.trials, low, high), args.trials))
                bridge.stop()
                wait_for(lambda: not is_alive(session, keys.alive("bridge")), 10, "the bridge to go")
            states.undeclare()
    finally:
        procs.stop_all()

    print(f"\nfirst state/joints reflecting a target (sim floating G1, rtf 1, state rate {args.state_rate_hz} Hz); ms")
    print(f"{'path':<72} {'n':>5} {'p50':>7} {'p99':>7} {'max':>7}")
    for name, latencies, asked in rows:
        ms = np.array(latencies) * 1e3
        lost = f"  ({asked - len(latencies)} timed out)" if len(latencies) < asked else ""
        print(f"{name:<72} {len(ms):>5} {np.percentile(ms, 50):>7.2f} {np.percentile(ms, 99):>7.2f} {ms.max():>7.2f}{lost}")
        print(f"{'':<72} slowest: {', '.join(f'{v:.1f}' for v in sorted(ms)[-5:])}")
    print(f"logs: {procs.dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
