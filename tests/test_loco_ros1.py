"""ROS 1's classic /cmd_vel walks the G1: `rostopic pub` (Debian's ROS 1) -> `zensim ros1` -> cmd/velocity ->
`zensim loco`, all real processes on a private roscore and router. Under `clock: lockstep`, so the walk
is the same on a loaded machine (the walking controller is the clock)."""

from __future__ import annotations

import math
import os
import subprocess

import pytest

from ros_graph import Roscore
from support import Latest, wait_for
from zensim.schemas import Keys, LocoStatus, Odometry, Ros1Status, SimStatus

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_rostopic_pub_cmd_vel_walks_the_g1_and_a_nan_twist_is_refused(start_service, zsession, robot_id, tmp_path):
    keys = Keys(robot_id)
    core = Roscore(tmp_path / "ros")
    try:
        start_service("sim", "--clock", "lockstep")
        odom = Latest(zsession, keys.odom, Odometry)
        status = Latest(zsession, keys.sim_status, SimStatus)
        status.keep_history = True
        loco_status = Latest(zsession, keys.loco_status, LocoStatus)
        ros1_status = Latest(zsession, keys.ros1_status, Ros1Status)
        odom.wait(timeout_s=60, what="the sim's first state")
        # A ROS user only sends velocities: the controller stands up by itself (--start walk).
        loco = start_service("loco", "--start", "walk")
        gateway = start_service("ros1", "--mesh-urls", "keep", env=core.env)
        wait_for(lambda: core.subscribers("/cmd_vel"), 60, "the gateway to subscribe to /cmd_vel")
        stood = odom.wait(lambda m: m.sim_time_s > 3.0, 60, "the stand-up")
        assert stood.pos[2] > 0.72 and loco_status.wait(lambda s: s.walking, 30, "walking").fsm_id == 500
        start = odom.value
        env = core.env
        pub = subprocess.Popen(["rostopic", "pub", "-r", "20", "/cmd_vel", "geometry_msgs/Twist",
                                "{linear: {x: 0.4, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: 0.0}}"],
                               env={**os.environ, **env}, stdout=subprocess.DEVNULL,
                               stderr=subprocess.STDOUT)
        try:
            walked = odom.wait(lambda m: m.pos[0] - start.pos[0] > 1.5, 120, "the G1 to walk 1.5 m on /cmd_vel")
        finally:
            pub.terminate()
            pub.wait(10)
        assert abs(walked.pos[1] - start.pos[1]) < 0.5 and walked.pos[2] > 0.6
        assert not any(s.fallen for s in status.history)
        # The publisher is gone: the last Twist lapses and the robot stops stepping.
        loco_status.wait(lambda s: not s.stepping and s.commanded == (0.0, 0.0, 0.0), 60, "the robot to stop")
        before = ros1_status.wait(what="the gateway's status")
        subprocess.run(["rostopic", "pub", "-1", "/cmd_vel", "geometry_msgs/Twist",
                        "{linear: {x: .nan, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: 0.0}}"],
                       env={**os.environ, **env}, timeout=60, capture_output=True)
        refused = ros1_status.wait(lambda s: s.rejected > before.rejected, 30, "the NaN Twist refused")
        assert refused.last_error and "finite" in refused.last_error
        assert loco.alive() and gateway.alive()
        assert math.isfinite(odom.value.pos[0])
    finally:
        core.stop()
