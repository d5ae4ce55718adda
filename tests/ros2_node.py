"""Real ROS 2 code for the `zensim ros2` tests: rclpy from the Kilted wheels (Fast DDS), run in a process of its
own with .venv-ros2's Python (ros2.py finds it): the wheels' Python packages (sensor_msgs, ...) share their
names with Debian's ROS 1 packages, so they never load into the test process or the project's venv.

    ros2_node.py echo SECONDS [NS ...]       subscribe the robot's topics over DDS (in each namespace NS, e.g.
                                             /g1a: /g1a/joint_states; default the root); one JSON line per message
    ros2_node.py forward SECONDS V1,V2,... [TOPIC]   publish std_msgs/Float64MultiArray at 50 Hz (default topic
                                             /forward_position_controller/commands)
    ros2_node.py twist SECONDS VX WZ         publish geometry_msgs/Twist at 50 Hz
    ros2_node.py serialize                   stdin: JSON lines {"type", fields...} -> stdout: the CDR as hex
                                             (rclpy's serialize_message)
    ros2_node.py deserialize                 stdin: JSON lines {"type": "pkg/msg/T" or DDS name, "hex"} ->
                                             stdout: the message as JSON (rclpy's deserialize_message;
                                             tf2_msgs/TFMessage, which has no wheel, with rosbags)
    ros2_node.py hashes                      the RIHS01 type hashes the wheels ship (share/<pkg>/msg/<T>.json)
                                             and rosbags' hash of tf2_msgs/TFMessage, as one JSON object

The domain comes from ROS_DOMAIN_ID; discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE).
`echo` subscribes /robot_description with the latched QoS (transient local), so a node that starts after
the message was published still gets it.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore

TYPES = ("sensor_msgs/msg/JointState", "nav_msgs/msg/Odometry", "sensor_msgs/msg/Imu", "rosgraph_msgs/msg/Clock",
         "std_msgs/msg/String", "std_msgs/msg/Float64MultiArray", "trajectory_msgs/msg/JointTrajectory",
         "geometry_msgs/msg/Twist")


def message_class(name: str) -> type:
    """`pkg/msg/Type` or `pkg::msg::dds_::Type_` -> the rclpy message class."""
    if "::" in name:
        package, _, _, short = name.split("::")
        name = f"{package}/msg/{short[:-1]}"
    package, _, short = name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), short)


def to_json(value):  # noqa: ANN001, ANN201 - a message or a field of one
    """A message as plain JSON values (field names as in the .msg files)."""
    if hasattr(value, "get_fields_and_field_types"):
        return {field: to_json(getattr(value, field)) for field in value.get_fields_and_field_types()}
    if hasattr(value, "__dataclass_fields__"):  # rosbags' messages
        return {field: to_json(getattr(value, field)) for field in value.__dataclass_fields__ if field != "__msgtype__"}
    if isinstance(value, (list, tuple)) or type(value).__name__ in ("ndarray", "array"):
        return [to_json(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


def build(spec: dict):  # noqa: ANN201 - an rclpy message
    """A command message from its JSON spec (the few types the tests send)."""
    kind = spec["type"]
    if kind == "std_msgs/msg/Float64MultiArray":
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        message = Float64MultiArray(data=[float(v) for v in spec["data"]])
        message.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)
                              for label, size in spec.get("dims", [])]
        return message
    if kind == "trajectory_msgs/msg/JointTrajectory":
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

        points = []
        for p in spec["points"]:
            point = JointTrajectoryPoint(positions=[float(v) for v in p["positions"]],
                                         velocities=[float(v) for v in p.get("velocities", [])])
            point.time_from_start.sec, point.time_from_start.nanosec = p.get("sec", 0), p.get("nanosec", 0)
            points.append(point)
        return JointTrajectory(joint_names=spec["joint_names"], points=points)
    if kind == "geometry_msgs/msg/Twist":
        from geometry_msgs.msg import Twist

        message = Twist()
        message.linear.x, message.linear.y, message.linear.z = spec["linear"]
        message.angular.x, message.angular.y, message.angular.z = spec["angular"]
        return message
    raise ValueError(f"cannot build {kind}")


def hashes() -> dict[str, str]:
    found = {}
    for name in TYPES:
        package, _, short = name.split("/")
        description = Path(sys.prefix, "share", package, "msg", f"{short}.json")  # where the wheels put it
        found[name] = {h["type_name"]: h["hash_string"]
                       for h in json.loads(description.read_text())["type_hashes"]}[name]
    found["tf2_msgs/msg/TFMessage"] = get_typestore(Stores.ROS2_KILTED).hash_rihs01("tf2_msgs/msg/TFMessage")
    found["rosbags sensor_msgs/msg/JointState"] = get_typestore(Stores.ROS2_KILTED).hash_rihs01(
        "sensor_msgs/msg/JointState")
    return found


def decode(spec: dict) -> dict:
    data = bytes.fromhex(spec["hex"])
    name = spec["type"]
    if name in ("tf2_msgs/msg/TFMessage", "tf2_msgs::msg::dds_::TFMessage_"):
        return to_json(get_typestore(Stores.ROS2_KILTED).deserialize_cdr(data, "tf2_msgs/msg/TFMessage"))
    return to_json(deserialize_message(data, message_class(name)))


def echo(seconds: float, namespaces: list[str]) -> None:
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node("zensim_test_node")
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    per_robot = (("/joint_states", "sensor_msgs/msg/JointState", 10), ("/odom", "nav_msgs/msg/Odometry", 10),
                 ("/imu", "sensor_msgs/msg/Imu", 10), ("/robot_description", "std_msgs/msg/String", latched))
    topics = [(ns.rstrip("/") + topic, kind, qos) for ns in namespaces or [""] for topic, kind, qos in per_robot]
    for topic, kind, qos in [*topics, ("/clock", "rosgraph_msgs/msg/Clock", 10)]:
        node.create_subscription(message_class(kind), topic,
                                 lambda m, topic=topic: print(json.dumps({"topic": topic, **to_json(m)}), flush=True),
                                 qos)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()


def publish(seconds: float, topic: str, message, rate_hz: float) -> None:  # noqa: ANN001 - an rclpy message
    import rclpy

    rclpy.init()
    node = rclpy.create_node("zensim_test_node")
    pub = node.create_publisher(type(message), topic, 10)
    end = time.monotonic() + seconds
    sent = 0
    while time.monotonic() < end:
        pub.publish(message)
        sent += 1
        rclpy.spin_once(node, timeout_sec=1.0 / rate_hz)
    print(json.dumps({"sent": sent, "matched": pub.get_subscription_count()}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def main(args: list[str]) -> None:
    command = args[0]
    if command == "echo":
        echo(float(args[1]), args[2:])
    elif command == "forward":
        publish(float(args[1]), args[3] if len(args) > 3 else "/forward_position_controller/commands",
                build({"type": "std_msgs/msg/Float64MultiArray", "data": args[2].split(",")}), 50)
    elif command == "twist":
        publish(float(args[1]), "/cmd_vel",
                build({"type": "geometry_msgs/msg/Twist", "linear": [float(args[2]), 0.0, 0.0],
                       "angular": [0.0, 0.0, float(args[3])]}), 50)
    elif command == "serialize":
        for line in sys.stdin:
            print(serialize_message(build(json.loads(line))).hex(), flush=True)
    elif command == "deserialize":
        for line in sys.stdin:
            print(json.dumps(decode(json.loads(line))), flush=True)
    elif command == "hashes":
        print(json.dumps(hashes()))
    else:
        raise SystemExit(f"unknown command {command!r}")


if __name__ == "__main__":
    main(sys.argv[1:])
