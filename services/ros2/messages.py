"""The ROS 2 messages `zensim ros2` speaks, as CDR bytes: their names, type hashes, encoders and decoders.

Pure (no rclpy, no zenoh, no DDS): both transports carry exactly these bytes. Field order and types
follow the message definitions of ROS 2 Kilted's common_interfaces (the same since Humble for these
types); the RIHS01 type hashes are the ones the Kilted wheels ship in `share/<pkg>/msg/<Type>.json`
(tests/test_ros2.py checks each against them, and TFMessage's, which has no wheel, against rosbags').

Out: sensor_msgs/JointState, nav_msgs/Odometry, sensor_msgs/Imu, rosgraph_msgs/Clock,
tf2_msgs/TFMessage, std_msgs/String (robot_description).
In: std_msgs/Float64MultiArray, trajectory_msgs/JointTrajectory, geometry_msgs/Twist; each decoder
returns plain values or raises CdrError.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from .cdr import CdrReader, CdrWriter


@dataclass(frozen=True)
class RosType:
    """One ROS 2 message type as the middlewares name it."""

    name: str
    """`package/msg/Type`, as ROS 2 tools print it."""
    type_hash: str
    """RIHS01 hash of the type description (ROS 2 Iron and later)."""

    @property
    def dds_name(self) -> str:
        """The DDS type name (`sensor_msgs::msg::dds_::JointState_`), also rmw_zenoh's key chunk."""
        package, kind, short = self.name.split("/")
        return f"{package}::{kind}::dds_::{short}_"


JOINT_STATE: Final = RosType("sensor_msgs/msg/JointState",
                             "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e")
ODOMETRY: Final = RosType("nav_msgs/msg/Odometry",
                          "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0")
IMU: Final = RosType("sensor_msgs/msg/Imu", "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b")
CLOCK: Final = RosType("rosgraph_msgs/msg/Clock",
                       "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564")
TF_MESSAGE: Final = RosType("tf2_msgs/msg/TFMessage",
                            "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087")
STRING: Final = RosType("std_msgs/msg/String", "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
FLOAT64_MULTI_ARRAY: Final = RosType("std_msgs/msg/Float64MultiArray",
                                     "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f")
JOINT_TRAJECTORY: Final = RosType("trajectory_msgs/msg/JointTrajectory",
                                  "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e")
TWIST: Final = RosType("geometry_msgs/msg/Twist", "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a")

ALL_TYPES: Final = (JOINT_STATE, ODOMETRY, IMU, CLOCK, TF_MESSAGE, STRING, FLOAT64_MULTI_ARRAY, JOINT_TRAJECTORY, TWIST)

_ZERO_COVARIANCE: Final = (0.0,) * 36
_ZERO_COVARIANCE_3: Final = (0.0,) * 9


def stamp(sim_time_s: float) -> tuple[int, int]:
    """builtin_interfaces/Time (sec, nanosec) of a time in seconds; never a nanosec of 1e9."""
    total_ns = round(sim_time_s * 1e9)
    return total_ns // 1_000_000_000, total_ns % 1_000_000_000


def stamp_s(sec: int, nanosec: int) -> float:
    return sec + nanosec * 1e-9


def _header(w: CdrWriter, sim_time_s: float, frame_id: str) -> None:
    sec, nanosec = stamp(sim_time_s)
    w.int32(sec)
    w.uint32(nanosec)
    w.string(frame_id)


def _vector3(w: CdrWriter, v: Sequence[float]) -> None:
    for value in v:
        w.float64(value)


def _fixed(w: CdrWriter, values: Sequence[float]) -> None:
    for value in values:
        w.float64(value)


def joint_state(sim_time_s: float, names: Sequence[str], q: Sequence[float], dq: Sequence[float],
                tau: Sequence[float], frame_id: str = "") -> bytes:
    w = CdrWriter()
    _header(w, sim_time_s, frame_id)
    w.strings(names)
    w.float64s(q)
    w.float64s(dq)
    w.float64s(tau)
    return w.bytes()


@dataclass(frozen=True)
class Pose:
    """A pose and twist in ROS's conventions (quaternion x, y, z, w)."""

    position: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float]
    linear: tuple[float, float, float]
    angular: tuple[float, float, float]


def odometry(sim_time_s: float, frame_id: str, child_frame_id: str, pose: Pose) -> bytes:
    w = CdrWriter()
    _header(w, sim_time_s, frame_id)
    w.string(child_frame_id)
    _vector3(w, pose.position)
    _fixed(w, pose.orientation_xyzw)
    _fixed(w, _ZERO_COVARIANCE)
    _vector3(w, pose.linear)
    _vector3(w, pose.angular)
    _fixed(w, _ZERO_COVARIANCE)
    return w.bytes()


def imu(sim_time_s: float, frame_id: str, orientation_xyzw: Sequence[float], gyro: Sequence[float],
        accel: Sequence[float]) -> bytes:
    w = CdrWriter()
    _header(w, sim_time_s, frame_id)
    _fixed(w, orientation_xyzw)
    _fixed(w, _ZERO_COVARIANCE_3)
    _vector3(w, gyro)
    _fixed(w, _ZERO_COVARIANCE_3)
    _vector3(w, accel)
    _fixed(w, _ZERO_COVARIANCE_3)
    return w.bytes()


def clock(sim_time_s: float) -> bytes:
    w = CdrWriter()
    sec, nanosec = stamp(sim_time_s)
    w.int32(sec)
    w.uint32(nanosec)
    return w.bytes()


@dataclass(frozen=True)
class Transform:
    """One geometry_msgs/TransformStamped: `child` in `parent`."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation_xyzw: tuple[float, float, float, float]


def tf_message(sim_time_s: float, transforms: Sequence[Transform]) -> bytes:
    w = CdrWriter()
    w.uint32(len(transforms))
    for t in transforms:
        _header(w, sim_time_s, t.parent)
        w.string(t.child)
        _vector3(w, t.translation)
        _fixed(w, t.rotation_xyzw)
    return w.bytes()


def string(text: str) -> bytes:
    w = CdrWriter()
    w.string(text)
    return w.bytes()


# --- in ---------------------------------------------------------------------------------------------


def read_float64_multi_array(data: bytes) -> list[float]:
    """std_msgs/Float64MultiArray's `data` (its layout, which ros2_control ignores too, is skipped)."""
    r = CdrReader(data)
    for _ in range(r.uint32()):  # layout.dim: label, size, stride (each takes at least 12 bytes)
        r.skip_string()
        r.uint32()
        r.uint32()
    r.uint32()  # layout.data_offset
    return r.float64s()


@dataclass(frozen=True)
class TrajectoryPoint:
    positions: list[float]
    time_from_start_s: float


def read_joint_trajectory(data: bytes) -> tuple[list[str], list[TrajectoryPoint]]:
    """trajectory_msgs/JointTrajectory's joint names and points (positions and time from start)."""
    r = CdrReader(data)
    r.int32()
    r.uint32()
    r.skip_string()  # header: a trajectory's stamp and frame do not change where the joints go
    names = r.strings()
    points = []
    for _ in range(r.uint32()):
        positions = r.float64s()
        r.float64s()  # velocities
        r.float64s()  # accelerations
        r.float64s()  # effort
        sec, nanosec = r.int32(), r.uint32()
        points.append(TrajectoryPoint(positions, stamp_s(sec, nanosec)))
    return names, points


def read_twist(data: bytes) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """geometry_msgs/Twist: (linear, angular)."""
    r = CdrReader(data)
    linear = (r.float64(), r.float64(), r.float64())
    angular = (r.float64(), r.float64(), r.float64())
    return linear, angular


def finite(values: Sequence[float]) -> bool:
    return all(math.isfinite(v) for v in values)
