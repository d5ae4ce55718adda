"""Latency through `zensim ros2` on both transports, beside zensim's own state/joints, and the face's CPU.

    .venv-ros2/bin/python benchmarks/ros2_latency.py [--seconds 10] [--rates 100,500]

It runs in .venv-ros2 (ROS 2's rclpy wheels and zensim, scripts/test makes it: the wheels' message packages
would shadow Debian's ROS 1 ones in .venv); the services run as users run them, from .venv.

For each sim state rate, starts a router, a sim (the G1 standing, rtf 1), the bridge and `zensim ros2`
(both transports, `--state-rate-hz 1000` so it passes every state on) as real processes on loopback, in
a DDS domain of its own. This process is at once a plain zenoh client and an rclpy node (ROS 2 Kilted's
wheels, Fast DDS), so every time below is read on one monotonic clock:

- zensim:  state/joints arriving at a zenoh subscriber here (the reference: the sim's own stream);
- DDS:     the JointState with the same stamp arriving at an rclpy subscription callback here;
- Zenoh:   the same JointState on rmw_zenoh's key arriving at a zenoh subscriber here and decoded with
           rclpy's `deserialize_message` (no rmw_zenoh_cpp wheel exists: this is what an rmw_zenoh
           subscription receives, decoded by ROS 2's own code);

and `zensim ros2`'s CPU over the same window (its process's user + system time / wall time).
"""

from __future__ import annotations

import argparse
import os
import threading
import time

import msgspec
import numpy as np
import rclpy
import zenoh
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState as RosJointState

from harness import REPO, Processes, cpu_s, free_port, plain_client, wait_for
from zensim.schemas import JointState, Keys

KEYS = Keys("g1")
DOMAIN = 30 + os.getpid() % 150
RMW_ZENOH_KEY = f"{DOMAIN}/joint_states/sensor_msgs::msg::dds_::JointState_/*"
ZENSIM_PYTHON = os.environ.get("ZENSIM_PYTHON", str(REPO / ".venv" / "bin" / "python"))
"""The project's venv, which runs the services (mujoco and the rest are there, not in .venv-ros2)."""


def zensim(procs: Processes, command: str, *args: str, env: dict[str, str]):  # noqa: ANN201 - a harness Child
    return procs.start(command, [ZENSIM_PYTHON, "-m", "zensim", command, *args], env)


def percentiles(values_s: list[float]) -> str:
    if not values_s:
        return "no pairs"
    ms = np.array(values_s) * 1e3
    return f"p50 {np.percentile(ms, 50):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms  (n={len(ms)})"


class Arrivals:
    """Arrival time here per sim time (rounded to the microsecond), thread-safe."""

    def __init__(self) -> None:
        self.at: dict[float, float] = {}
        self._lock = threading.Lock()

    def add(self, sim_time_s: float) -> None:
        now = time.monotonic()
        with self._lock:
            self.at.setdefault(round(sim_time_s, 6), now)

    def clear(self) -> None:
        with self._lock:
            self.at.clear()

    def after(self, reference: Arrivals) -> list[float]:
        with self._lock, reference._lock:
            return [t - reference.at[s] for s, t in self.at.items() if s in reference.at]


def run_rate(rate_hz: int, seconds: float, node) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID="g1", ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1",
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    procs = Processes(env, prefix="zensim-bench-ros2-")
    client_env = {"ZENSIM_ZENOH_MODE": "client", "ZENSIM_ZENOH_CONNECT": endpoint}
    try:
        zensim(procs, "router", env={"ZENSIM_ZENOH_LISTEN": endpoint})
        zensim(procs, "sim", "--rtf", "1", "--state-rate-hz", str(rate_hz), env=client_env)
        zensim(procs, "bridge", env=client_env)
        face = zensim(procs, "ros2", "--domain-id", str(DOMAIN), "--state-rate-hz", "1000", env=client_env)
        wait_for(lambda: "ros2 face up" in face.log(), 90, "zensim ros2", 0.2)
        zensim_at, dds_at, zenoh_at = Arrivals(), Arrivals(), Arrivals()
        decoder = msgspec.msgpack.Decoder(JointState)

        def on_state(sample: zenoh.Sample) -> None:
            zensim_at.add(decoder.decode(sample.payload.to_bytes()).sim_time_s)

        def on_rmw_zenoh(sample: zenoh.Sample) -> None:
            stamp = deserialize_message(sample.payload.to_bytes(), RosJointState).header.stamp
            zenoh_at.add(stamp.sec + stamp.nanosec * 1e-9)

        subscription = node.create_subscription(
            RosJointState, "/joint_states",
            lambda m: dds_at.add(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9), 100)
        with plain_client(endpoint) as session:
            subs = [session.declare_subscriber(KEYS.joints, on_state),
                    session.declare_subscriber(RMW_ZENOH_KEY, on_rmw_zenoh)]
            wait_for(lambda: len(dds_at.at) > 10 and len(zenoh_at.at) > 10, 30, "both ROS 2 paths", 0.1)
            time.sleep(1.0)
            for arrivals in (zensim_at, dds_at, zenoh_at):
                arrivals.clear()
            cpu0, t0 = cpu_s(face.pid), time.monotonic()
            time.sleep(seconds)
            cpu = (cpu_s(face.pid) - cpu0) / (time.monotonic() - t0)
            for sub in subs:
                sub.undeclare()
        node.destroy_subscription(subscription)
        print(f"--- sim states at {rate_hz} Hz, {seconds:g} s")
        print(f"  zensim state/joints here: {len(zensim_at.at)} states ({len(zensim_at.at) / seconds:.0f} Hz)")
        print(f"  DDS  (rclpy on Fast DDS) after state/joints:     {percentiles(dds_at.after(zensim_at))}")
        print(f"  Zenoh (rmw_zenoh's key, rclpy's decoder) after:  {percentiles(zenoh_at.after(zensim_at))}")
        print(f"  zensim ros2 CPU: {100 * cpu:.1f} % of one core (both transports)")
    finally:
        procs.stop_all()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rates", default="100,500", help="sim state rates to measure, Hz")
    args = parser.parse_args()
    os.environ.update(ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    rclpy.init()
    node = rclpy.create_node("bench_ros2")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        for rate in (int(r) for r in args.rates.split(",")):
            run_rate(rate, args.seconds, node)
    finally:
        executor.shutdown()
        spinner.join(timeout=5)
        node.destroy_node()
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
