"""Settings of `zensim ros2` (defaults < `ZENSIM_*` environment < `--flags`).

Topic names without a leading `/` are resolved in `namespace` (the root by default, as a ROS 2 robot
driver names them: `/joint_states`).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import msgspec

from zensim.common.settings import CommonSettings


class Ros2Settings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim ros2`: ROS 2 topics on rmw_zenoh's keys and on DDS, zensim's keys on the other side."""

    env_prefix: ClassVar[str] = "ROS2"
    transports: Literal["zenoh,dds", "zenoh", "dds"] = "zenoh,dds"
    """Which ROS 2 middlewares see the robot: `zenoh` (rmw_zenoh's keys on zensim's own Zenoh session and
    router), `dds` (Cyclone DDS, for Fast DDS and Cyclone DDS nodes), or both."""
    domain_id: Annotated[int, msgspec.Meta(ge=0, le=232)] = 0
    """ROS domain id (what ROS 2 nodes set in ROS_DOMAIN_ID), for both transports."""
    world: str = ""
    """A world's id (`zensim sim --world`): serve every robot it lists (world/info), each as a node
    `zensim_{robot}` under the namespace of its id (`/g1a/joint_states`) with its frames prefixed
    (`g1a/pelvis`); /tf and /clock stay shared. Empty: the one robot of --robot-id."""
    namespace: str = ""
    """ROS namespace of the robot's topics; empty: the root (`/joint_states`). With --world, the robots'
    namespaces go under it."""
    node_name: str = ""
    """ROS node name; empty: `zensim_{robot_id}`."""
    robot_description_topic: str = "robot_description"
    """std_msgs/String out, the sim's URDF, latched (transient local, depth 1)."""
    joint_states_topic: str = "joint_states"
    """sensor_msgs/JointState out, the robot's joints in its own order, header stamp = sim time."""
    tf_topic: str = "/tf"
    """tf2_msgs/TFMessage out: world_frame -> base_frame from the odometry (links: robot_state_publisher)."""
    odom_topic: str = "odom"
    """nav_msgs/Odometry out, the base's ground truth, pose and twist in world_frame."""
    imu_topic: str = "imu"
    """sensor_msgs/Imu out."""
    clock_topic: str = "/clock"
    """rosgraph_msgs/Clock out: sim time, for nodes with use_sim_time."""
    forward_command_topic: str = "forward_position_controller/commands"
    """std_msgs/Float64MultiArray in: a position for every joint, in /joint_states order."""
    trajectory_topic: str = "joint_trajectory_controller/joint_trajectory"
    """trajectory_msgs/JointTrajectory in: its last point's positions for its named joints."""
    cmd_vel_topic: str = "cmd_vel"
    """geometry_msgs/Twist in: linear x, y and angular z to the walking controller (cmd/velocity, `zensim loco`);
    refused (counted) while none is up."""
    cmd_vel_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=60)] = 0.5
    """Sim time each /cmd_vel holds: the robot stops this long after the last one (`ros2 topic pub -r 10`)."""
    world_frame: str = "world"
    """Fixed frame of the odometry and the TF."""
    base_frame: str = "pelvis"
    """The robot's base link: the odometry's child frame."""
    imu_frame: str = "imu_in_pelvis"
    """frame_id of the Imu messages (a link of the URDF)."""
    state_rate_hz: Annotated[float, msgspec.Meta(gt=0, le=1000)] = 100.0
    """Most joint states, odometry, IMU, TF and clock messages per second of sim time, Hz
    (the sim's state_rate_hz when lower)."""
    status_rate_hz: Annotated[float, msgspec.Meta(gt=0, le=100)] = 2.0
    """Rate of the status on state/ros2, Hz."""
    dds_interface: str = "lo"
    """Network interface of the DDS side (`lo`: this machine only; a name such as eth0 for other hosts)."""
    humble: bool = False
    """Name types on Zenoh as Humble's rmw_zenoh does (`TypeHashNotSupported`) instead of by type hash."""
    info_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """How long each query of the sim's info/robot and info/urdf waits, s."""
