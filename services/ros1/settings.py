"""Settings of `zensim ros1` (defaults < `ZENSIM_*` environment < `--flags`).

The ROS master itself is ROS's own business: rospy reads `ROS_MASTER_URI`, `ROS_IP` /
`ROS_HOSTNAME` and `ROS_HOME` from the environment, as every ROS node does. With neither `ROS_IP`
nor `ROS_HOSTNAME` set the gateway binds loopback (ROS's own default would be every interface).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import msgspec

from zensim.common.settings import CommonSettings, zero_or_at_least


class Ros1Settings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim ros1`: ROS 1 topics on one side, zensim's keys on the other.

    Topic names without a leading `/` are resolved in `namespace`.
    """

    env_prefix: ClassVar[str] = "ROS1"
    namespace: str = ""
    """ROS namespace of the robot's topics; empty: `/{robot_id}_description` (`/g1_description`)."""
    joint_states_topic: str = "joint_states"
    """sensor_msgs/JointState out, the robot's joints in its own order, header stamp = sim time."""
    command_topic: str = "{joint}_controller/command"
    """std_msgs/Float64 in, one topic per movable joint (`{joint}` is the joint's name)."""
    gui_topic: str = "/gui_commands"
    """sensor_msgs/JointState in (joint_state_publisher_gui remapped): the named joints' positions."""
    cmd_vel_topic: str = "/cmd_vel"
    """geometry_msgs/Twist in: linear x, y and angular z to the walking controller (cmd/velocity, `zensim loco`)."""
    cmd_vel_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=60)] = 0.5
    """Sim time each /cmd_vel holds: the robot stops this long after the last one (`rostopic pub -r 10`)."""
    odom_topic: str = "/ground_truth_odom"
    """nav_msgs/Odometry out, the base's ground truth (like Gazebo's p3d plugin)."""
    imu_topic: str = "imu"
    """sensor_msgs/Imu out."""
    clock_topic: str = "/clock"
    """rosgraph_msgs/Clock out: sim time, for nodes with use_sim_time."""
    tf_topic: str = "/tf"
    """tf2_msgs/TFMessage out: world_frame -> base_frame from the odometry."""
    description_param: str = "/robot_description"
    """Parameter that gets the sim's URDF (mesh references rewritten per `mesh_urls`)."""
    set_use_sim_time: bool = True
    """Set the `/use_sim_time` parameter to true at start, as Gazebo's launch files do."""
    world_frame: str = "world"
    """Fixed frame of the odometry and the TF."""
    base_frame: str = "pelvis"
    """The robot's base link: the odometry's child frame."""
    imu_frame: str = "imu_in_pelvis"
    """frame_id of the Imu messages (a link of the URDF)."""
    state_rate_hz: Annotated[float, msgspec.Meta(gt=0, le=1000)] = 100.0
    """Most joint states, odometry, IMU, TF and clock messages per second of sim time, Hz
    (the sim's state_rate_hz when lower)."""
    command_rate_hz: Annotated[float, msgspec.Meta(ge=0, le=10000)] = 100.0
    """Most commands passed on per second per ROS command topic (each joint's Float64 topic, the GUI's);
    faster ones are shed, the newest kept and passed on in its turn; 0: no limit. The bridge sends
    motor commands at 100 Hz: more targets per joint than that change nothing but the CPU load."""
    status_rate_hz: Annotated[float, msgspec.Meta(gt=0, le=100)] = 2.0
    """Rate of the gateway's status on state/ros1, Hz."""
    mesh_urls: Literal["http", "keep"] = "http"
    """`http`: serve the sim's meshes over http and point robot_description there; `keep`: leave the
    URDF's references as they are (for a RViz host with a local copy of the meshes)."""
    mesh_http_bind: str = "127.0.0.1"
    """Address the mesh http server listens on (0.0.0.0 for RViz on another host)."""
    mesh_http_port: Annotated[int, msgspec.Meta(ge=0, le=65535)] = 7011
    """Port of the mesh http server; 0 picks a free one."""
    mesh_http_host: str = ""
    """Host name RViz reaches the mesh server by, in the URLs; empty: the bind address (or this
    machine's name when it binds 0.0.0.0)."""
    node_name: str = ""
    """ROS node name; empty: `zensim_ros1_{robot_id}`."""
    info_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """How long each query of the sim's info/robot, info/urdf and info/mesh waits, s."""
    open_edge: bool = False
    """With --secure-dir, let the gateway's ROS side listen beyond loopback anyway (ROS_IP / ROS_HOSTNAME
    another address): ROS 1 has no authentication, so anyone who reaches it drives the robot."""
    ros_python_path: str = "/usr/lib/python3/dist-packages"
    """Where rospy is found when the Python running zensim cannot import it (Debian's ROS packages
    install there); searched after everything else, so the project's own packages win."""

    def __post_init__(self) -> None:
        zero_or_at_least(self.command_rate_hz, 1.0, "command_rate_hz")
