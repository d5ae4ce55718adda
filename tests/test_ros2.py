"""`zensim ros2`'s pure rules without a zensim process: the CDR bytes against real rclpy (the Kilted wheels,
run by tests/ros2_node.py in .venv-ros2), the type hashes against the ones the wheels ship, rmw_zenoh's keys,
tokens and attachments, the input checks.
"""

from __future__ import annotations

import math
import struct

import pytest
import zenoh.ext

import ros2_client

from zensim.common.ros_rules import InputError, RobotJoints
from zensim.ros2 import messages as msg
from zensim.ros2.cdr import CdrError, CdrReader
from zensim.ros2.mapping import Ros2Names, forward_command, trajectory_goal, velocity_command
from zensim.ros2.rmw_zenoh import Node, Qos, attachment, data_key, mangle, read_attachment

ROBOT = RobotJoints(names=("hip", "knee", "elbow"), q_min=(-1.0, 0.0, -2.0), q_max=(1.0, 2.5, 2.0), run_id="r",
                    mesh_paths=())


def test_type_hashes_equal_the_ones_the_ros2_wheels_ship_and_rosbags_computes():
    shipped = ros2_client.hashes()
    for ros_type in msg.ALL_TYPES:  # TFMessage has no wheel: rosbags' hash, which agrees with the wheels'
        assert shipped[ros_type.name] == ros_type.type_hash, ros_type.name
    assert shipped["rosbags sensor_msgs/msg/JointState"] == msg.JOINT_STATE.type_hash


def test_every_message_zensim_ros2_writes_decodes_with_rclpy_to_the_values_it_was_given():
    js, odom, imu, clock, text, tf = ros2_client.deserialize(
        ("sensor_msgs/msg/JointState", msg.joint_state(12.3456789, ["a", "bé"], [1.0, -2.5], [0.1, 0.2], [3.0, 4.0],
                                                       "base")),
        ("nav_msgs/msg/Odometry", msg.odometry(1.5, "world", "pelvis",
                                               msg.Pose((1, 2, 3), (0.1, 0.2, 0.3, 0.9), (4, 5, 6), (7, 8, 9)))),
        ("sensor_msgs/msg/Imu", msg.imu(2.0, "imu_link", (0, 0, 0, 1), (1, 2, 3), (4, 5, 6))),
        ("rosgraph_msgs/msg/Clock", msg.clock(7.000000001)),
        ("std_msgs/msg/String", msg.string("<robot name='g1'/>")),
        ("tf2_msgs/msg/TFMessage", msg.tf_message(3.5, [msg.Transform("world", "pelvis", (1, 2, 3), (0, 0, 0, 1))])))
    assert js["header"] == {"stamp": {"sec": 12, "nanosec": 345678900}, "frame_id": "base"}
    assert js["name"] == ["a", "bé"] and js["position"] == [1.0, -2.5] and js["effort"] == [3.0, 4.0]
    assert (odom["header"]["frame_id"], odom["child_frame_id"]) == ("world", "pelvis")
    assert odom["pose"]["pose"]["orientation"] == {"x": 0.1, "y": 0.2, "z": 0.3, "w": 0.9}
    assert odom["twist"]["twist"]["angular"]["z"] == 9
    assert imu["orientation"]["w"] == 1 and imu["angular_velocity"]["y"] == 2 and imu["linear_acceleration"]["z"] == 6
    assert clock["clock"] == {"sec": 7, "nanosec": 1}
    assert text["data"] == "<robot name='g1'/>"
    assert tf["transforms"][0]["child_frame_id"] == "pelvis"
    assert tf["transforms"][0]["transform"]["translation"]["z"] == 3


def test_stamps_never_carry_a_second_of_nanoseconds():
    assert msg.stamp(0.9999999999) == (1, 0)
    assert msg.stamp(3.25) == (3, 250_000_000)


def test_commands_rclpy_encodes_decode_leniently():
    """rclpy's encoder leaves padding uninitialised and appends bytes: never compare bytes, read fields."""
    array, trajectory, twist = ros2_client.serialize(
        {"type": "std_msgs/msg/Float64MultiArray", "data": [0.5, -1.25, 2.0], "dims": [["joints", 3]]},
        {"type": "trajectory_msgs/msg/JointTrajectory", "joint_names": ["knee", "elbow"],
         "points": [{"positions": [0.3, 0.4], "velocities": [1.0, 1.0], "sec": 1},
                    {"positions": [0.1, 0.2], "velocities": [1.0, 1.0], "sec": 2, "nanosec": 500_000_000}]},
        {"type": "geometry_msgs/msg/Twist", "linear": [0.4, 0.0, 0.0], "angular": [0.0, 0.0, -0.3]})
    assert msg.read_float64_multi_array(array) == [0.5, -1.25, 2.0]
    names, points = msg.read_joint_trajectory(trajectory)
    assert names == ["knee", "elbow"] and points[-1].positions == [0.1, 0.2] and points[-1].time_from_start_s == 2.5
    assert msg.read_twist(twist) == ((0.4, 0.0, 0.0), (0.0, 0.0, -0.3))


@pytest.mark.parametrize("data", [
    b"", b"\x00\x01", b"\x7f\x7f\x00\x00" + bytes(16),  # too short, no header, an unknown encapsulation
    b"\x00\x01\x00\x00" + struct.pack("<I", 0xFFFFFFFF),  # a layout of 4 billion dimensions
    b"\x00\x01\x00\x00" + struct.pack("<II", 0, 0) + struct.pack("<I", 2**31),  # 2**31 doubles in 12 bytes
    b"\x00\x01\x00\x00" + struct.pack("<II", 0, 0) + struct.pack("<I", 3) + bytes(8),  # three doubles, one there
    b"\x00\x01\x00\x00" + struct.pack("<I", 1) + struct.pack("<I", 4) + b"\xff\xfe\xfd\x00" + bytes(12),  # not UTF-8
], ids=["empty", "header-only", "encapsulation", "dims", "doubles", "truncated", "utf8"])
def test_bad_cdr_is_a_cdr_error_at_once(data):
    with pytest.raises(CdrError):
        msg.read_float64_multi_array(data)


def test_xcdr2_and_big_endian_read_too():
    # XCDR2 little-endian: 8-byte values aligned on 4.
    xcdr2 = b"\x00\x07\x00\x00" + struct.pack("<II", 0, 0) + struct.pack("<I", 1) + struct.pack("<d", 1.5)
    assert msg.read_float64_multi_array(xcdr2) == [1.5]
    big = b"\x00\x00\x00\x00" + struct.pack(">II", 0, 0) + struct.pack(">I", 1) + bytes(4) + struct.pack(">d", 2.5)
    assert msg.read_float64_multi_array(big) == [2.5]
    assert CdrReader(b"\x00\x01\x00\x00" + struct.pack("<I", 0)).string() == ""


# --- rmw_zenoh's format -------------------------------------------------------------------------------


def test_keys_and_tokens_follow_the_design_documents_templates():
    assert data_key(0, "/joint_states", msg.JOINT_STATE) == (
        "0/joint_states/sensor_msgs::msg::dds_::JointState_/"
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e")
    assert data_key(3, "/g1/joint_states", msg.JOINT_STATE, humble=True) == (
        "3/g1/joint_states/sensor_msgs::msg::dds_::JointState_/TypeHashNotSupported")
    node = Node(0, "aabbcc", 0, "/", "zensim_g1")
    assert node.token() == "@ros2_lv/0/aabbcc/0/0/NN/%/%/zensim_g1"
    assert Node(0, "aabbcc", 0, "/robots/g1", "zensim_g1").token() == "@ros2_lv/0/aabbcc/0/0/NN/%/%robots%g1/zensim_g1"
    assert node.endpoint_token(3, "MP", "/robot_description", msg.STRING, Qos(transient_local=True, depth=1)) == (
        "@ros2_lv/0/aabbcc/0/3/MP/%/%/zensim_g1/%robot_description/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/:1:,1:,:,:,,")
    assert Qos().token() == "::,10:,:,:,,"
    assert Qos(depth=42).token() == "::,:,:,:,,"  # rmw_zenoh's defaults: every field empty
    assert Qos(reliable=False, depth=5).token() == "2::,5:,:,:,,"
    assert mangle("") == "%" and mangle("/a/b") == "%a%b"


def test_the_attachment_is_zenoh_exts_serialisation_of_seq_time_and_gid():
    gid = bytes(range(16))
    ours = attachment(41, 1_700_000_000_123_456_789, gid)
    assert ours == zenoh.ext.z_serialize((zenoh.ext.Int64(41), zenoh.ext.Int64(1_700_000_000_123_456_789), gid)).to_bytes()
    assert len(ours) == 33
    read = read_attachment(ours)
    assert (read.sequence_number, read.source_timestamp_ns, read.gid) == (41, 1_700_000_000_123_456_789, gid)
    for bad in (None, b"", ours[:-1], ours + b"\x00", ours[:16] + b"\x0f" + ours[17:]):
        with pytest.raises(ValueError):
            read_attachment(bad)


# --- names and input checks ---------------------------------------------------------------------------


def test_names_resolve_in_the_namespace_and_bad_names_are_refused():
    topics = dict(robot_description="robot_description", joint_states="joint_states", tf="/tf", odom="odom",
                  imu="imu", clock="/clock", forward_command="forward_position_controller/commands",
                  trajectory="joint_trajectory_controller/joint_trajectory", cmd_vel="cmd_vel")
    root = Ros2Names.of("", **topics)
    assert (root.namespace, root.joint_states, root.tf) == ("/", "/joint_states", "/tf")
    named = Ros2Names.of("g1/", **topics)
    assert (named.namespace, named.joint_states, named.tf, named.cmd_vel) == ("/g1", "/g1/joint_states", "/tf", "/g1/cmd_vel")
    for bad in ("joint states", "a//b", "9lives", "**", "@ros2_lv"):
        with pytest.raises(ValueError):
            Ros2Names.of("", **{**topics, "joint_states": bad})


def test_a_forward_command_names_every_joint_in_order_or_is_refused_whole():
    assert forward_command(ROBOT, [0.1, 1.0, -0.5]).names == ROBOT.names
    for bad in ([0.1, 1.0], [0.1, 1.0, -0.5, 0.0], [math.nan, 1.0, 0.0], [0.1, math.inf, 0.0], [5.0, 1.0, 0.0]):
        with pytest.raises(InputError):
            forward_command(ROBOT, bad)


def test_a_trajectory_goes_to_its_last_point():
    points = [msg.TrajectoryPoint([0.1], 1.0), msg.TrajectoryPoint([0.5], 2.0)]
    goal = trajectory_goal(ROBOT, ["elbow"], points)
    assert (goal.names, goal.q) == (("elbow",), (0.5,))
    for names, pts in ((["elbow"], []), (["elbow", "knee"], points), (["wrist"], points), (["elbow"], [msg.TrajectoryPoint([9.0], 1.0)])):
        with pytest.raises(InputError):
            trajectory_goal(ROBOT, names, pts)


def test_a_twist_becomes_the_walking_controllers_velocity_or_is_refused_whole():
    """linear x, y and angular z are the walk; a NaN or an absurd value anywhere refuses all of it."""
    command = velocity_command((0.5, -0.2, 0.0), (0.0, 0.0, 0.3), 0.5)
    assert (command.vx, command.vy, command.wz, command.timeout_s) == (0.5, -0.2, 0.3, 0.5)
    for linear, angular in (((math.nan, 0, 0), (0, 0, 0)), ((0, 0, 0), (0, 0, math.inf)), ((1e3, 0, 0), (0, 0, 0)),
                            ((0.4, 0, math.nan), (0, 0, 0)), ((0.4, 0, 0), (1e9, 0, 0))):
        with pytest.raises(InputError):
            velocity_command(linear, angular, 0.5)
