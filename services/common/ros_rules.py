"""What the ROS gateways (`zensim ros1`, `zensim ros2`) map the same way, as pure rules: no rospy, no rclpy, no zenoh.

- ROS names: a name resolved in the robot's namespace.
- Inputs from ROS: joint positions checked whole against the robot (finite, known joints, within the
  joint's limits, one position per name); they become the JointTargets the bridge gets, or an
  `InputError` saying why, and nothing of a refused message is passed on. A geometry_msgs/Twist on
  /cmd_vel is checked whole the same way (all six components finite and within MAX_TWIST) and becomes
  the VelocityCommand the walking controller (`zensim loco`) gets: linear x, y and angular z.
- Outputs to ROS: at most a rate of sim time, the odometry as Gazebo's p3d plugin gives it, quaternions
  in ROS's x, y, z, w order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from zensim.schemas import JointTargets, Odometry, RobotInfo, VelocityCommand
from zensim.schemas.messages import MAX_VELOCITY

LIMIT_SLACK_RAD = 1e-9
"""A position this far past a limit still counts as inside it (a GUI slider at its end, after rounding)."""


MAX_TWIST = MAX_VELOCITY
"""Largest |linear| (m/s) or |angular| (rad/s) component a Twist may ask for: finite is not sane. The
walking controller clips what it gets to its robot's range (the G1: 1 m/s); beyond this is absurd."""


class InputError(ValueError):
    """A ROS message refused whole; the text says why."""


def resolve(namespace: str, name: str) -> str:
    """A ROS graph name: `name` as is when absolute (`/clock`), else under `namespace`."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


@dataclass(frozen=True)
class RobotJoints:
    """What the gateway knows of the sim's robot: joint order and limits."""

    names: tuple[str, ...]
    """The robot's own joint order (RobotInfo.joint_names), the order of every JointState out."""
    q_min: tuple[float, ...]
    q_max: tuple[float, ...]
    run_id: str
    """The sim run that described it: a new run may be another robot."""
    mesh_paths: tuple[str, ...]
    """Mesh files the URDF names, as the sim serves them on info/mesh/{path}."""

    @classmethod
    def from_info(cls, info: RobotInfo) -> RobotJoints:
        return cls(tuple(info.joint_names), tuple(info.q_min), tuple(info.q_max), info.run_id,
                   tuple(info.mesh_paths))

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {name: i for i, name in enumerate(self.names)})

    def check_position(self, joint: str, value: float) -> float:
        """`value` as a target for `joint`, or InputError: unknown joint, not finite, outside the limits."""
        index = self._index.get(joint)  # type: ignore[attr-defined]
        if index is None:
            raise InputError(f"unknown joint {joint!r}")
        if not math.isfinite(value):
            raise InputError(f"{joint}: position must be a finite number, got {value}")
        low, high = self.q_min[index], self.q_max[index]
        if not low - LIMIT_SLACK_RAD <= value <= high + LIMIT_SLACK_RAD:
            raise InputError(f"{joint}: position {value:.6g} is outside the joint's limits [{low:.6g}, {high:.6g}]")
        return float(value)

    def joint_targets(self, names: Sequence[str], positions: Sequence[float]) -> JointTargets:
        """A JointState's names and positions as JointTargets for the bridge, or InputError for the whole message."""
        if not names:
            raise InputError("a JointState with no names moves nothing")
        if len(positions) != len(names):
            raise InputError(f"{len(names)} names but {len(positions)} positions")
        if len(set(names)) != len(names):
            raise InputError("a joint is named more than once")
        unknown = [name for name in names if name not in self._index]  # type: ignore[attr-defined]
        if unknown:
            shown = ", ".join(repr(n) for n in unknown[:5]) + (" ..." if len(unknown) > 5 else "")
            raise InputError(f"unknown joint(s): {shown}")
        q = tuple(self.check_position(name, value) for name, value in zip(names, positions))
        return JointTargets(names=tuple(names), q=q)


def velocity_command(linear: Sequence[float], angular: Sequence[float], timeout_s: float) -> VelocityCommand:
    """A /cmd_vel Twist (its linear and angular x, y, z) as the walking controller's VelocityCommand.

    Every component is checked, the ones the walk ignores (linear z, angular x and y) too: a Twist with a
    NaN anywhere is a broken sender, and none of it is passed on. Held `timeout_s` of sim time.
    """
    for value in (*linear, *angular):
        if not math.isfinite(value):
            raise InputError(f"a Twist with a value that is not finite ({value})")
        if abs(value) > MAX_TWIST:
            raise InputError(f"a Twist component of {value:.6g} (at most {MAX_TWIST:g} m/s or rad/s)")
    try:
        return VelocityCommand(vx=float(linear[0]), vy=float(linear[1]), wz=float(angular[2]), timeout_s=timeout_s)
    except ValueError as exc:  # the schema's own checks (a bad timeout setting cannot pass the settings')
        raise InputError(str(exc)) from None


class RateGate:
    """At most `rate_hz` outputs per second of sim time; a step back in sim time starts over."""

    def __init__(self, rate_hz: float) -> None:
        # A hair under the period, so a sim publishing exactly at `rate_hz` is never thinned by rounding.
        self._period = (1.0 - 1e-6) / rate_hz
        self._last: float | None = None

    def due(self, sim_time_s: float) -> bool:
        last = self._last
        if last is None or sim_time_s < last or sim_time_s - last >= self._period:
            self._last = sim_time_s
            return True
        return False


def xyzw(quat_wxyz: Sequence[float]) -> tuple[float, float, float, float]:
    """zensim's scalar-first quaternion in ROS's order (x, y, z, w)."""
    w, x, y, z = quat_wxyz
    return (x, y, z, w)


def rotate(quat_wxyz: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """`v` rotated by the unit quaternion (w, x, y, z): a body-frame vector in the world frame."""
    w, x, y, z = quat_wxyz
    vx, vy, vz = v
    # t = 2 q_vec x v; v' = v + w t + q_vec x t
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


@dataclass(frozen=True)
class P3dOdometry:
    """The base's ground truth as Gazebo's p3d plugin publishes it: pose and twist both in the world frame."""

    position: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float]
    linear: tuple[float, float, float]
    angular: tuple[float, float, float]

    @classmethod
    def of(cls, odom: Odometry) -> P3dOdometry:
        px, py, pz = odom.pos
        lx, ly, lz = odom.lin_vel_world
        return cls((px, py, pz), xyzw(odom.quat_wxyz), (lx, ly, lz), rotate(odom.quat_wxyz, odom.ang_vel_body))
