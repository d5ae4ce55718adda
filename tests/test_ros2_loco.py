"""ROS 2's /cmd_vel walks the G1: a real rclpy node (the Kilted wheels, Fast DDS, tests/ros2_node.py) publishes
geometry_msgs/Twist over DDS -> `zensim ros2` -> cmd/velocity -> `zensim loco`, all real processes on a
private router. Under `clock: lockstep`, so the walk is the same on a loaded machine (the walking
controller is the clock), and the distance is judged in sim time."""

from __future__ import annotations

import math
import os
import subprocess

import ros2_client  # real rclpy (tests/ros2_node.py), in its own process and venv
from support import Latest, wait_for
from zensim.schemas import Keys, LocoStatus, Odometry, Ros2Status, SimStatus

DOMAIN = 20 + (os.getpid() + 101) % 200
"""A DDS and ROS domain of this run's own (other test runs on the machine use DDS too)."""


def rclpy_twist(seconds: float, vx: str, wz: str = "0.0") -> subprocess.Popen:
    """An rclpy node publishing Twist(vx, wz) on /cmd_vel at 50 Hz for `seconds` of wall time, in the background."""
    return subprocess.Popen([ros2_client.ros2_python(), str(ros2_client.NODE), "twist", str(seconds), vx, wz],
                            env=ros2_client.ros_env(DOMAIN), stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)


def test_an_rclpy_twist_on_cmd_vel_walks_the_g1_and_bad_twists_are_refused_and_counted(start_service, zsession,
                                                                                     robot_id):
    keys = Keys(robot_id)
    start_service("sim", "--clock", "lockstep")
    odom = Latest(zsession, keys.odom, Odometry)
    status = Latest(zsession, keys.sim_status, SimStatus)
    status.keep_history = True
    loco_status = Latest(zsession, keys.loco_status, LocoStatus)
    ros2_status = Latest(zsession, keys.ros2_status, Ros2Status)
    odom.wait(timeout_s=60, what="the sim's first state")
    # A ROS user only sends velocities: the controller stands up by itself (--start walk).
    loco = start_service("loco", "--start", "walk")
    # Lockstep runs as fast as the controller (several times real time here): a Twist holds 2 s of sim
    # time, so the 50 Hz of wall time the publisher keeps never leaves a gap in the walk.
    gateway = start_service("ros2", "--transports", "dds", "--domain-id", str(DOMAIN), "--status-rate-hz", "10",
                            "--cmd-vel-timeout-s", "2")
    wait_for(lambda: "a walking controller is up" in gateway.log() or not gateway.alive(), 90,
             "zensim ros2 to find the walking controller")
    assert gateway.alive(), gateway.log()
    stood = odom.wait(lambda m: m.sim_time_s > 3.0, 90, "the stand-up")
    assert stood.pos[2] > 0.72 and loco_status.wait(lambda s: s.walking, 30, "walking").fsm_id == 500
    start = odom.value
    publisher = rclpy_twist(300, "0.5")
    try:
        # The first Twist that arrives starts the clock: DDS discovery takes wall time, not sim time.
        moving = loco_status.wait(lambda s: s.commanded[0] > 0.4, 90, "the Twist to reach the walking controller")
        walked = odom.wait(lambda m: m.pos[0] - start.pos[0] > 0.5 or m.sim_time_s > moving.sim_time_s + 5.0, 120,
                           "5 s of sim time on /cmd_vel")
    finally:
        publisher.terminate()
        publisher.wait(30)
    assert walked.pos[0] - start.pos[0] > 0.5, f"walked {walked.pos[0] - start.pos[0]:.2f} m in 5 s of sim time"
    assert abs(walked.pos[1] - start.pos[1]) < 0.5 and walked.pos[2] > 0.6
    # The publisher is gone: the last Twist lapses and the robot stops stepping, still up.
    stopped = loco_status.wait(lambda s: not s.stepping and s.commanded == (0.0, 0.0, 0.0), 60, "the robot to stop")
    assert not any(s.fallen for s in status.history) and odom.value.pos[2] > 0.6
    forwarded = ros2_status.wait(lambda s: s.commands_forwarded > 0, 10, "the Twists counted as forwarded")
    # Bad Twists: refused whole, counted, with the reason; nothing reaches the walking controller.
    for vx, reason in (("nan", "not finite"), ("1e9", "at most 10")):
        before = ros2_status.wait(lambda s: s.seq > forwarded.seq, 10, "a newer state/ros2")
        sent = ros2_client.run_json("twist", "2", vx, "0.0", domain=DOMAIN, timeout_s=90)[-1]
        assert sent["matched"] >= 1, "zensim ros2 subscribes /cmd_vel over DDS"
        refused = ros2_status.wait(lambda s: s.rejected > before.rejected and reason in (s.last_error or ""), 30,
                                   f"the {vx} Twists refused")
        forwarded = refused
        assert refused.commands_forwarded == before.commands_forwarded
    after = loco_status.wait(lambda s: s.seq > stopped.seq, 10, "a newer state/loco")
    assert after.velocity_received == stopped.velocity_received and after.commanded == (0.0, 0.0, 0.0)
    assert loco.alive() and gateway.alive()
    assert math.isfinite(odom.value.pos[0]) and not any(s.fallen for s in status.history)
