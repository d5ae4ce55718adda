"""What `zensim ros2` maps, as pure rules: its ROS 2 names, and the commands ROS 2 sends checked whole.

The rules it shares with the ROS 1 gateway (joint checks, the odometry's frames, the output rate) are
in zensim.common.ros_rules; here is what is ROS 2's own:

- names: every topic resolved in the robot's namespace (root by default: `/joint_states`);
- a forward position controller's std_msgs/Float64MultiArray: one position per joint, in the robot's
  joint order (the order of /joint_states), all of them or none;
- a trajectory_msgs/JointTrajectory: its last point is where the joints go (the bridge's slew limit
  then takes them there; zensim does not interpolate the points in between);
- geometry_msgs/Twist on /cmd_vel: the rule the ROS 1 gateway applies too (ros_rules.velocity_command:
  every component finite and within MAX_TWIST, linear x, y and angular z become the walking controller's
  VelocityCommand on cmd/velocity); while no walking controller is up (no `alive/loco` token for the
  robot) a Twist is refused with NO_WALKING, so the user reads why nothing moves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from zensim.common.ros_rules import MAX_TWIST, InputError, RobotJoints, resolve, velocity_command  # noqa: F401 - re-exported
from zensim.schemas import JointTargets

from .messages import TrajectoryPoint

NO_WALKING: Final = ("no walking controller is up for this robot (start `zensim loco --start walk`, or "
                     "`zensim up --loco`): /cmd_vel moves nothing (docs/ros.md)")


def namespace_of(namespace: str) -> str:
    """A namespace as ROS 2 writes it: `/` for the root, else `/a/b` (no trailing slash)."""
    stripped = namespace.strip("/")
    return f"/{stripped}" if stripped else "/"


@dataclass(frozen=True)
class Ros2Names:
    """The resolved ROS 2 names of one robot's topics."""

    namespace: str
    robot_description: str
    joint_states: str
    tf: str
    odom: str
    imu: str
    clock: str
    forward_command: str
    trajectory: str
    cmd_vel: str

    @classmethod
    def of(cls, namespace: str, *, robot_description: str, joint_states: str, tf: str, odom: str, imu: str,
           clock: str, forward_command: str, trajectory: str, cmd_vel: str) -> Ros2Names:
        ns = namespace_of(namespace)
        names = [resolve(ns, n) for n in (robot_description, joint_states, tf, odom, imu, clock, forward_command,
                                          trajectory, cmd_vel)]
        for name in names:
            check_name(name)
        return cls(ns, *names)


def check_name(name: str) -> None:
    """ValueError unless `name` is a ROS 2 topic name that fits in a Zenoh key."""
    chunks = name.strip("/").split("/")
    if not name.startswith("/") or not all(chunks) or any(
            not (c[0].isalpha() or c[0] == "_") or not all(ch.isalnum() or ch == "_" for ch in c) for c in chunks):
        raise ValueError(f"{name!r} is not a ROS 2 topic name (letters, digits and _ between slashes)")


def forward_command(robot: RobotJoints, data: Sequence[float]) -> JointTargets:
    """A forward position controller's command: every joint, in the robot's order."""
    if len(data) != len(robot.names):
        raise InputError(f"{len(data)} positions for the robot's {len(robot.names)} joints (in /joint_states order)")
    return robot.joint_targets(robot.names, data)


def trajectory_goal(robot: RobotJoints, names: Sequence[str], points: Sequence[TrajectoryPoint]) -> JointTargets:
    """Where a JointTrajectory ends: its last point's positions for its joints."""
    if not points:
        raise InputError("a JointTrajectory with no points moves nothing")
    last = points[-1]
    if len(last.positions) != len(names):
        raise InputError(f"the last point has {len(last.positions)} positions for {len(names)} joint names")
    return robot.joint_targets(names, last.positions)
