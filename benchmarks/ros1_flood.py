"""A valid Float64 flood through the ROS 1 gateway (issue 27, finding 4), with and without its shedding:

    .venv/bin/python benchmarks/ros1_flood.py [--seconds 5] [--rate-hz 10000] [--gate-hz 0 100]

Starts a private ROS master, a router, a sim (the floating G1 standing, rtf 1), the bridge and
`zensim ros1` as real processes on loopback. For each `--gate-hz` (the gateway's --command-rate-hz;
0 passes every command on, as the gateway did before) it restarts the gateway and runs, one after
another: quiet (no commands) for --seconds; flood: one rospy publisher (Debian's python3, its own
process) writes valid std_msgs/Float64 to the left elbow's command topic as fast as --rate-hz allows;
after: quiet again.

Per phase: Float64/s written, the sim's real-time factor (sim time over wall time) and its worst
status `rtf`, commands forwarded and shed per second (state/ros1), and the CPU the gateway, the bridge,
the sim and the flooder itself used (% of one core; the flooder's over its whole life, connection
included).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

from harness import Latest, Processes, cpu_s, free_port, plain_client, wait_for
from zensim.schemas import Keys, Ros1Status, SimStatus

FLOODER = """
import sys, time, rospy
from std_msgs.msg import Float64
topic, rate_hz, seconds = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
rospy.init_node("flooder", anonymous=True, disable_signals=True)
pub = rospy.Publisher(topic, Float64, queue_size=1000)
deadline = time.monotonic() + 20
while pub.get_num_connections() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
sent, t0 = 0, time.monotonic()
next_send = t0
message = Float64(data=0.5)
while (now := time.monotonic()) - t0 < seconds:
    if now >= next_send:
        pub.publish(message)
        sent += 1
        next_send += 1.0 / rate_hz
print(sent / (time.monotonic() - t0), time.process_time() / (time.monotonic() - t0), flush=True)
rospy.signal_shutdown("done")
"""


def master_answers(uri: str) -> bool:
    try:
        with xmlrpc.client.ServerProxy(uri) as master:
            return master.getPid("/bench")[0] == 1
    except OSError:
        return False


def main() -> None:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each phase, s")
    parser.add_argument("--rate-hz", type=float, default=10_000.0, help="the flood's Float64 rate")
    parser.add_argument("--gate-hz", type=float, nargs="+", default=[0.0, 100.0],
                        help="the gateway's --command-rate-hz values to compare (0: no shedding)")
    args = parser.parse_args()

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = "bench" + str(random.randint(0, 10**6))
    port = free_port()
    ros = {"ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1",
           "ROS_HOME": tempfile.mkdtemp(prefix="ros1-flood-")}
    base = dict(os.environ, ZENSIM_ROBOT_ID=robot, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1", **ros)
    procs = Processes(dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint), prefix="ros1-flood-")
    procs.start("rosmaster", ["rosmaster", "--core", "-p", str(port)], env=base)
    procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
    sim = procs.zensim("sim", "--rtf", "1")
    bridge = procs.zensim("bridge")
    keys = Keys(robot)
    topic = f"/{robot}_description/left_elbow_joint_controller/command"
    try:
        wait_for(lambda: master_answers(ros["ROS_MASTER_URI"]), 30, "the ROS master")
        with plain_client(endpoint) as session:
            sim_status = Latest(session, keys.sim_status, SimStatus, keep_history=True)
            sim_status.wait(timeout_s=60, what="the sim's status")
            print(f"{'gate Hz':>7} {'phase':6} {'Float64/s':>9} {'sim RTF':>7} {'worst rtf':>9} {'fwd/s':>6} "
                  f"{'shed/s':>7} {'gateway CPU':>11} {'bridge CPU':>10} {'sim CPU':>7} {'flooder CPU':>12}")
            for gate_hz in args.gate_hz:
                gateway = procs.zensim("ros1", "--command-rate-hz", str(gate_hz), "--mesh-urls", "keep",
                                       "--status-rate-hz", "10")
                wait_for(lambda: "ros1 gateway up" in gateway.log() or not gateway.alive(), 60, "the gateway")
                status = Latest(session, keys.ros1_status, Ros1Status)
                status.wait(timeout_s=10, what="the gateway's status")
                for phase in ("quiet", "flood", "after"):
                    s0, g0 = sim_status.value, status.value
                    c0 = [cpu_s(p.pid) for p in (gateway, bridge, sim)]
                    history_from = len(sim_status.history)
                    t0 = time.monotonic()
                    rate, flooder_cpu = 0.0, 0.0
                    if phase == "flood":
                        done = subprocess.run(["/usr/bin/python3", "-c", FLOODER, topic, str(args.rate_hz),
                                               str(args.seconds)], env=base, capture_output=True, text=True,
                                              timeout=args.seconds + 60)
                        if done.returncode == 0:
                            rate, flooder_cpu = map(float, done.stdout.strip().splitlines()[-1].split())
                    else:
                        time.sleep(args.seconds)
                    seq = status.value.seq
                    status.wait(lambda m: m.seq > seq + 2, what="a status")  # counts up to date
                    wall = time.monotonic() - t0
                    s1, g1 = sim_status.value, status.value
                    c1 = [cpu_s(p.pid) for p in (gateway, bridge, sim)]
                    worst = min((m.rtf for m in sim_status.history[history_from:]), default=float("nan"))
                    cpu = [100 * (b - a) / wall for a, b in zip(c0, c1)]
                    print(f"{gate_hz:7.0f} {phase:6} {rate:9.0f} {(s1.sim_time_s - s0.sim_time_s) / wall:7.2f} "
                          f"{worst:9.2f} {(g1.commands_forwarded - g0.commands_forwarded) / wall:6.0f} "
                          f"{(g1.commands_shed - g0.commands_shed) / wall:7.0f} {cpu[0]:10.0f}% {cpu[1]:9.0f}% "
                          f"{cpu[2]:6.0f}% {100 * flooder_cpu:11.0f}%", flush=True)
                gateway.stop()
    finally:
        procs.stop_all()


if __name__ == "__main__":
    main()
