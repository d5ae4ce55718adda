"""Latency through `zensim ros1`, both ways, beside a bare rospy round trip measured in the same run.

    .venv/bin/python benchmarks/ros1_latency.py [--trials 100] [--seconds 10]

Starts a private roscore, a router, a sim (the G1 standing, rtf 1, 100 Hz states), the bridge and the
gateway as real processes on loopback; this process is both a rospy node and a plain zenoh client,
so every time below is read on one monotonic clock:

- sim -> ROS:  a state/joints sample arriving at a zenoh subscriber here -> the JointState with the same
               stamp arriving at a rospy subscriber here (what the gateway adds to the sim's own stream);
- ROS -> sim:  a Float64 published on /g1_description/left_elbow_joint_controller/command -> the first
               state/joints whose left-elbow torque shows the new target (|tau - tau before| > 0.5 N m):
               gateway, bridge (100 Hz ticks, 2 rad/s slew), sim (100 Hz states) and back;
- zenoh -> sim: the same step sent as cmd/joint/left_elbow_joint straight from zenoh (no gateway), the
               same detection: the difference to the line above is the gateway's share;
- bare rospy:  Float64 ping -> an echo node (Debian's rospy, its own process) -> pong: the round trip
               two ROS 1 nodes cost each other on this machine.

Steps alternate between two elbow targets 0.1 rad apart, 250-400 ms apart at random.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import threading
import time
import xmlrpc.client

import msgspec
import numpy as np
import zenoh

from harness import Latest, Processes, free_port, plain_client, wait_for
from zensim.schemas import JointState, JointTargets, Keys, Ros1Status

DEBIAN_ROS_PYTHON = "/usr/lib/python3/dist-packages"
try:
    import rospy
except ImportError:
    sys.path.append(DEBIAN_ROS_PYTHON)
    import rospy
from sensor_msgs.msg import JointState as RosJointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

KEYS = Keys("g1")
ELBOW = "left_elbow_joint"
TARGETS = (0.2, 0.3)
TAU_STEP_NM = 0.5
ECHO_NODE = """
import rospy
from std_msgs.msg import Float64
rospy.init_node("bench_echo")
pong = rospy.Publisher("/bench/pong", Float64, queue_size=10, tcp_nodelay=True)
rospy.Subscriber("/bench/ping", Float64, pong.publish, queue_size=10, tcp_nodelay=True)
rospy.spin()
"""


def percentiles(values_s: list[float]) -> str:
    ms = np.array(values_s) * 1e3
    return f"p50 {np.percentile(ms, 50):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms  (n={len(ms)})"


class StateTimes:
    """state/joints samples as they reach this process: arrival time per sim time, and the newest elbow torque."""

    def __init__(self, session: zenoh.Session, elbow_index: int) -> None:
        self._decoder = msgspec.msgpack.Decoder(JointState)
        self._elbow = elbow_index
        self.arrived: dict[float, float] = {}
        self.torques: list[tuple[float, float]] = []  # (arrival, elbow tau)
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(KEYS.joints, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        state = self._decoder.decode(sample.payload.to_bytes())
        with self._lock:
            self.arrived[round(state.sim_time_s, 6)] = now
            self.torques.append((now, state.tau[self._elbow]))

    def first_torque_change(self, since: float, baseline: float) -> float | None:
        with self._lock:
            for arrival, tau in self.torques:
                if arrival >= since and abs(tau - baseline) > TAU_STEP_NM:
                    return arrival
        return None

    def newest_torque(self) -> float:
        with self._lock:
            return self.torques[-1][1]


def step_latencies(trials: int, send, states: StateTimes, lost: list[int]) -> list[float]:
    """Send alternating elbow targets with `send(value)`; time to the first state that shows each.

    A step no state shows within 2 s is counted in `lost[0]` and left out.
    """
    latencies = []
    for i in range(trials):
        time.sleep(random.uniform(0.25, 0.4))  # the previous step has settled
        baseline = states.newest_torque()
        t0 = time.monotonic()
        send(TARGETS[i % 2])
        try:
            arrival = wait_for(lambda: states.first_torque_change(t0, baseline), 2, "the step in state/joints", 0.001)
        except TimeoutError:
            lost[0] += 1
            continue
        latencies.append(arrival - t0)
    return latencies


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to collect sim -> ROS pairs")
    args = parser.parse_args()

    ros_port = free_port()
    ros_env = {"ROS_MASTER_URI": f"http://127.0.0.1:{ros_port}", "ROS_IP": "127.0.0.1",
               "ROS_HOME": tempfile.mkdtemp(prefix="zensim-bench-ros-")}
    os.environ.update(ros_env)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID="g1", ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    procs = Processes(env, prefix="zensim-bench-ros1-")
    client_env = {"ZENSIM_ZENOH_MODE": "client", "ZENSIM_ZENOH_CONNECT": endpoint}
    try:
        procs.start("roscore", ["roscore", "-p", str(ros_port)])

        def master_up() -> bool:
            try:
                with xmlrpc.client.ServerProxy(ros_env["ROS_MASTER_URI"]) as master:
                    return master.getPid("/bench")[0] == 1
            except OSError:
                return False

        wait_for(master_up, 30, "roscore", 0.1)
        procs.zensim("router", env={"ZENSIM_ZENOH_LISTEN": endpoint})
        procs.zensim("sim", "--rtf", "1", env=client_env)  # floating: the elbow holds with kp 300
        procs.zensim("bridge", env=client_env)
        gateway = procs.zensim("ros1", "--mesh-http-port", "0", env=client_env)
        procs.start("echo", ["/usr/bin/python3", "-c", ECHO_NODE])
        wait_for(lambda: "ros1 gateway up" in gateway.log(), 60, "the gateway", 0.2)
        rospy.init_node("bench_ros1", anonymous=True, disable_signals=True)
        with plain_client(endpoint) as session:
            names = list(Latest(session, KEYS.bridge_targets, JointTargets).wait(timeout_s=20).names)
            states = StateTimes(session, names.index(ELBOW))

            # sim -> ROS: the same instant, as zenoh and as ROS deliver it here.
            ros_arrived: dict[float, float] = {}

            def on_joint_state(message: RosJointState) -> None:
                ros_arrived[round(message.header.stamp.to_sec(), 6)] = time.monotonic()

            rospy.Subscriber("/g1_description/joint_states", RosJointState, on_joint_state, queue_size=100,
                             tcp_nodelay=True)
            time.sleep(1.0)
            ros_arrived.clear()
            time.sleep(args.seconds)
            pairs = [ros_arrived[t] - states.arrived[t] for t in list(ros_arrived) if t in states.arrived]

            # ROS -> sim, and the same step straight from zenoh.
            command = rospy.Publisher(f"/g1_description/{ELBOW}_controller/command", Float64, queue_size=10,
                                      tcp_nodelay=True)
            wait_for(lambda: command.get_num_connections() > 0, 10, "the gateway's subscription")
            lost_ros, lost_zenoh = [0], [0]
            via_ros = step_latencies(args.trials, lambda q: command.publish(Float64(data=q)), states, lost_ros)
            via_zenoh = step_latencies(args.trials, lambda q: session.put(KEYS.joint_target(ELBOW), str(q)), states,
                                       lost_zenoh)
            status = Latest(session, KEYS.ros1_status, Ros1Status).wait(timeout_s=5)

            # bare rospy: ping -> echo node -> pong.
            pong_at: list[float] = []
            rospy.Subscriber("/bench/pong", Float64, lambda m: pong_at.append(time.monotonic()), queue_size=10,
                             tcp_nodelay=True)
            ping = rospy.Publisher("/bench/ping", Float64, queue_size=10, tcp_nodelay=True)
            wait_for(lambda: ping.get_num_connections() > 0, 10, "the echo node")
            time.sleep(1.0)
            round_trips = []
            for i in range(args.trials):
                count = len(pong_at)
                t0 = time.monotonic()
                ping.publish(Float64(data=float(i)))
                wait_for(lambda: len(pong_at) > count, 5, "the pong", 0.0002)
                round_trips.append(pong_at[-1] - t0)
                time.sleep(random.uniform(0.01, 0.03))

        print(f"sim -> ROS  (state/joints here -> JointState here):       {percentiles(pairs)}")
        print(f"ROS -> sim  (Float64 publish -> first state/joints showing it): {percentiles(via_ros)}"
              f"  lost {lost_ros[0]}")
        print(f"zenoh -> sim (cmd/joint put -> first state/joints showing it):  {percentiles(via_zenoh)}"
              f"  lost {lost_zenoh[0]}")
        print(f"gateway: {status.commands_received} Float64 read, {status.commands_forwarded} forwarded, "
              f"{status.rejected} rejected")
        print(f"bare rospy round trip (ping -> echo node -> pong):        {percentiles(round_trips)}")
        return 0
    finally:
        rospy.signal_shutdown("benchmark done")
        procs.stop_all()


if __name__ == "__main__":
    sys.exit(main())
