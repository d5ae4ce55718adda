"""Stream motor commands straight to the sim (cmd/motors), Unitree LowCmd style: what a policy does.

Each command holds until the next; the sim's watchdog relaxes the motors when commands stop for
longer than its `watchdog_timeout_s` (0.5 s by default). Here: swing one joint in a sine at 100 Hz.

    python examples/stream_motors.py left_elbow_joint --seconds 3
"""

from __future__ import annotations

import json
import math
import time

import zenoh


def main(conf: zenoh.Config, robot: str, joint: str, seconds: float, rate_hz: float) -> None:
    with zenoh.open(conf) as session:
        # Declare the publisher once; put on it at the command rate.
        motors = session.declare_publisher(f"zensim/{robot}/cmd/motors")
        start = time.monotonic()
        sent = 0
        while (elapsed := time.monotonic() - start) < seconds:
            q = 0.5 * math.sin(2 * math.pi * 0.5 * elapsed)
            # Only the joints named are commanded; kp, kd (and dq, tau) are optional, per joint.
            motors.put(json.dumps({"names": [joint], "q": [q], "kp": [40.0], "kd": [2.0]}))
            sent += 1
            time.sleep(max(0.0, start + sent / rate_hz - time.monotonic()))
        print(f"sent {sent} motor commands in {seconds} s")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="stream_motors", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("joint", help="a joint name (info/robot's joint_names)")
    parser.add_argument("--seconds", type=float, default=5.0, help="how long to stream")
    parser.add_argument("--rate-hz", type=float, default=100.0, help="commands per second")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot, args.joint, args.seconds, args.rate_hz)
