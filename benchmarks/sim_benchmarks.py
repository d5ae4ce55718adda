"""Benchmarks of the sim service, each measured side by side with its baseline in one run.

    .venv/bin/python benchmarks/sim_benchmarks.py [--seconds 5] [--rounds 3]

1. Throughput: steps per second of `zensim sim --rtf 0` publishing states at
   100 Hz (of wall time, and of sim time) against a bare `mj_step` loop on the
   same model, alternating rounds.
2. Pacing: at --rtf 1 with 500 Hz publishing, the achieved real-time factor and
   the step-start jitter p99 (from state/sim).
3. Latency: a MotorCommand sent by a client -> the first state/joints that
   reflects it (p50, p99), against a bare zenoh query round trip to the same
   sim process (`info/robot`).

Results go to stdout as a small table; docs/benchmarks.md keeps the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time

import mujoco
import numpy as np
import zenoh

from harness import Latest, free_port, plain_client
from zensim.robots import robot_files
from zensim.robots.builder import build
from zensim.sim.mjdata import reset
from zensim.schemas import Codec, JointState, Keys, MotorCommand, SimStatus


def start(command: str, *args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "zensim", command, *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def client(endpoint: str) -> zenoh.Session:
    return plain_client(endpoint)  # waits for the router, which may still be starting


def bare_steps_per_s(seconds: float) -> float:
    robot = build(robot_files("unitree_g1"), "floating")
    data = mujoco.MjData(robot.model)
    reset(robot, data)
    steps, start_t = 0, time.perf_counter()
    while time.perf_counter() - start_t < seconds:
        for _ in range(500):
            mujoco.mj_step(robot.model, data)
        steps += 500
    return steps / (time.perf_counter() - start_t)


def service_steps_per_s(status: Latest, seconds: float) -> float:
    first = status.wait(what="status")
    t0, s0 = time.perf_counter(), first.sim_time_s
    time.sleep(seconds)
    last = status.value
    return (last.sim_time_s - s0) / last.timestep_s / (time.perf_counter() - t0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--samples", type=int, default=500)
    args = parser.parse_args()

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    router = start("router", env={**env, "ZENSIM_ZENOH_LISTEN": endpoint})
    svc_env = {**env, "ZENSIM_ZENOH_MODE": "client", "ZENSIM_ZENOH_CONNECT": endpoint}
    procs = [router]
    try:
        with client(endpoint) as session:
            # 1. throughput, alternating bare and service rounds, for both clocks of the state rate
            for clock in ("wall", "sim"):
                keys = Keys("bench1" + clock)
                status = Latest(session, keys.sim_status, SimStatus)
                sim = start("sim", "--rtf", "0", "--state-rate-hz", "100", "--state-clock", clock,
                            env={**svc_env, "ZENSIM_ROBOT_ID": keys.robot})
                procs.append(sim)
                status.wait(timeout_s=60, what="the sim")
                bare, service = [], []
                for _ in range(args.rounds):
                    # Pause the sim while the bare loop runs so they never share the cores.
                    list(session.get(keys.ctl("pause"), timeout=5))
                    bare.append(bare_steps_per_s(args.seconds))
                    list(session.get(keys.ctl("resume"), timeout=5))
                    time.sleep(0.3)
                    service.append(service_steps_per_s(status, args.seconds))
                sim.terminate()
                sim.wait(10)
                b, s = statistics.median(bare), statistics.median(service)
                print(f"throughput  bare mj_step {b:9.0f} steps/s | service --rtf 0, states at 100 Hz of {clock} time"
                      f" {s:9.0f} steps/s | ratio {s / b:.3f}  (rounds: bare {[round(x) for x in bare]},"
                      f" service {[round(x) for x in service]})")

            # 2. real-time pacing at 500 Hz publishing
            keys = Keys("bench2")
            status = Latest(session, keys.sim_status, SimStatus)
            status.keep_history = True
            sim = start("sim", "--rtf", "1", "--state-rate-hz", "500", env={**svc_env, "ZENSIM_ROBOT_ID": keys.robot})
            procs.append(sim)
            status.wait(timeout_s=60, what="the sim")
            time.sleep(1.0)
            status.history.clear()
            time.sleep(args.seconds * args.rounds)
            hist = list(status.history)
            rtf = (hist[-1].sim_time_s - hist[0].sim_time_s) / ((hist[-1].seq - hist[0].seq) / 10.0)
            jitter = [m.step_jitter_p99_s for m in hist]
            print(f"pacing      rtf 1, 500 Hz publishing: achieved rtf {statistics.median(m.rtf for m in hist):.4f}"
                  f" (over the run {rtf:.4f}); step jitter p99 median {1e3 * statistics.median(jitter):.3f} ms,"
                  f" worst window {1e3 * max(jitter):.3f} ms")
            sim.terminate(); sim.wait(10)

            # 3. latency: command -> first state reflecting it, against a query round trip
            keys = Keys("bench3")
            sim = start("sim", "--rtf", "1", "--mode", "fixed", "--state-rate-hz", "500",
                        env={**svc_env, "ZENSIM_ROBOT_ID": keys.robot})
            procs.append(sim)
            joints = Latest(session, keys.joints, JointState)
            joints.wait(timeout_s=60, what="the sim")
            info = json.loads(next(iter(session.get(keys.robot_info + "?format=json", timeout=10))).ok.payload.to_bytes())
            j = info["joint_names"].index("left_elbow_joint")
            codec = Codec(MotorCommand)
            publisher = session.declare_publisher(keys.motors)
            seen = threading.Event()
            wanted = [0.0]

            def on_state(sample: zenoh.Sample) -> None:
                state = joints._codec.decode(sample.payload.to_bytes())
                if abs(state.tau[j] - wanted[0]) < 1e-6:
                    seen.set()

            sub = session.declare_subscriber(keys.joints, on_state)
            command_lat, query_lat = [], []
            for i in range(args.samples):
                # Pure feed-forward torque (kp = kd = 0): the state's tau shows it at the very next step.
                wanted[0] = 1.0 + (i % 7)
                seen.clear()
                msg = MotorCommand(names=("left_elbow_joint",), q=(0.0,), kp=(0.0,), kd=(0.0,), tau=(wanted[0],))
                t0 = time.perf_counter()
                publisher.put(codec.encode(msg))
                if seen.wait(1.0):
                    command_lat.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                list(session.get(keys.robot_info, timeout=1.0))
                query_lat.append(time.perf_counter() - t0)
            sub.undeclare()

            def pct(xs: list[float], p: float) -> float:
                return 1e3 * float(np.percentile(xs, p))

            print(f"latency     command -> first state (500 Hz states): p50 {pct(command_lat, 50):.2f} ms,"
                  f" p99 {pct(command_lat, 99):.2f} ms ({len(command_lat)}/{args.samples} seen) | bare query round trip"
                  f" to the sim: p50 {pct(query_lat, 50):.2f} ms, p99 {pct(query_lat, 99):.2f} ms")
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
    return 0



if __name__ == "__main__":
    sys.exit(main())
