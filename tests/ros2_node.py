"""A ROS 2 node written with real rclpy (the Kilted wheels, Fast DDS), run by tests/test_ros2_process.py as
a process of its own (rclpy owns DDS domain state for its whole process).

    ros2_node.py echo SECONDS [--late S]     subscribe the robot's topics; print one JSON line per message
    ros2_node.py forward SECONDS V1,V2,...   publish std_msgs/Float64MultiArray at 50 Hz
    ros2_node.py twist SECONDS VX WZ         publish geometry_msgs/Twist at 50 Hz
    ros2_node.py trajectory SECONDS JOINT POSITION   publish a one-point JointTrajectory at 10 Hz

The domain comes from ROS_DOMAIN_ID; discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE).
`echo` subscribes /robot_description with the latched QoS (transient local), so a node that starts after
the message was published still gets it; `--late S` waits S seconds before subscribing at all.
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint


def stamp(t) -> float:
    return t.sec + t.nanosec * 1e-9


def as_json(topic: str, m) -> dict:
    if isinstance(m, JointState):
        return {"topic": topic, "t": stamp(m.header.stamp), "name": list(m.name), "position": list(m.position),
                "velocity": list(m.velocity)}
    if isinstance(m, Odometry):
        p, o, v = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist.linear
        return {"topic": topic, "t": stamp(m.header.stamp), "frame": m.header.frame_id, "child": m.child_frame_id,
                "pos": [p.x, p.y, p.z], "xyzw": [o.x, o.y, o.z, o.w], "lin": [v.x, v.y, v.z]}
    if isinstance(m, Imu):
        o, g = m.orientation, m.angular_velocity
        return {"topic": topic, "t": stamp(m.header.stamp), "xyzw": [o.x, o.y, o.z, o.w], "gyro": [g.x, g.y, g.z]}
    if isinstance(m, Clock):
        return {"topic": topic, "t": stamp(m.clock)}
    return {"topic": topic, "length": len(m.data), "head": m.data[:200]}


def echo(node, seconds: float, late_s: float) -> None:
    time.sleep(late_s)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    for topic, kind, qos in (("/joint_states", JointState, 10), ("/odom", Odometry, 10), ("/imu", Imu, 10),
                             ("/clock", Clock, 10), ("/robot_description", String, latched)):
        node.create_subscription(kind, topic, lambda m, topic=topic: print(json.dumps(as_json(topic, m)), flush=True),
                                 qos)
    print(json.dumps({"ready": True}), flush=True)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


def publish(node, seconds: float, kind: type, make, rate_hz: float) -> None:
    pub = node.create_publisher(kind, {"Float64MultiArray": "/forward_position_controller/commands",
                                       "Twist": "/cmd_vel",
                                       "JointTrajectory": "/joint_trajectory_controller/joint_trajectory"}[kind.__name__],
                                10)
    end = time.monotonic() + seconds
    sent = 0
    while time.monotonic() < end:
        pub.publish(make())
        sent += 1
        rclpy.spin_once(node, timeout_sec=1.0 / rate_hz)
    print(json.dumps({"sent": sent, "matched": pub.get_subscription_count()}), flush=True)


def main(args: list[str]) -> None:
    rclpy.init()
    node = rclpy.create_node("zensim_test_node")
    command, seconds = args[0], float(args[1])
    if command == "echo":
        echo(node, seconds, float(args[3]) if len(args) > 3 and args[2] == "--late" else 0.0)
    elif command == "forward":
        values = [float(v) for v in args[2].split(",")]
        publish(node, seconds, Float64MultiArray, lambda: Float64MultiArray(data=values), 50)
    elif command == "twist":
        def twist() -> Twist:
            t = Twist()
            t.linear.x, t.angular.z = float(args[2]), float(args[3])
            return t
        publish(node, seconds, Twist, twist, 50)
    elif command == "trajectory":
        def trajectory() -> JointTrajectory:
            point = JointTrajectoryPoint(positions=[float(args[3])])
            point.time_from_start.sec = 1
            return JointTrajectory(joint_names=[args[2]], points=[point])
        publish(node, seconds, JointTrajectory, trajectory, 10)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1:])
