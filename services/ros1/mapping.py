"""What the ROS 1 gateway maps, as pure rules: no rospy, no zenoh (service.py does the wiring).

- ROS names: the settings' topic names resolved in the robot's namespace.
- Inputs from ROS: a per-joint Float64 or the GUI's JointState is checked whole against the robot
  (finite, known joints, within the joint's limits, one position per name) and becomes the value the
  bridge gets, or an `InputError` saying why; nothing of a refused message is passed on. A /cmd_vel
  Twist becomes the walking controller's VelocityCommand by the rule `zensim ros2` shares
  (common/ros_rules.py `velocity_command`); the CommandGate below then sheds a flood of them.
- Outputs to ROS: the odometry as Gazebo's p3d plugin gives it, quaternions reordered to ROS's x, y, z, w.
- The URDF for robot_description, its mesh references pointed at the gateway's http server.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Generic, TypeVar
from urllib.parse import quote

# The rules both ROS gateways share live in one place; service.py takes them from here.
from zensim.common.ros_rules import (  # noqa: F401 - re-exported
    LIMIT_SLACK_RAD,
    InputError,
    P3dOdometry,
    RateGate,
    RobotJoints,
    resolve,
    rotate,
    velocity_command,
    xyzw,
)
from zensim.schemas import JointTargets
from zensim.schemas.keys import mesh_key_path

K = TypeVar("K")
V = TypeVar("V")


# --- names ------------------------------------------------------------------------------


def default_namespace(robot_id: str) -> str:
    """The classic workspace's namespace for a robot id: `g1` -> `/g1_description`."""
    return f"/{robot_id}_description"


@dataclass(frozen=True)
class RosNames:
    """The resolved ROS names of one robot's topics."""

    namespace: str
    joint_states: str
    command_pattern: str
    gui: str
    odom: str
    imu: str
    clock: str
    tf: str

    @classmethod
    def of(cls, robot_id: str, namespace: str, joint_states: str, command: str, gui: str, odom: str, imu: str,
           clock: str, tf: str) -> RosNames:
        """Names from the settings; an empty namespace is the robot id's default."""
        ns = namespace or default_namespace(robot_id)
        if not ns.startswith("/"):
            ns = "/" + ns
        if "{joint}" not in command:
            raise ValueError(f"the command topic {command!r} must hold `{{joint}}`")
        return cls(ns, resolve(ns, joint_states), resolve(ns, command), resolve(ns, gui), resolve(ns, odom),
                   resolve(ns, imu), resolve(ns, clock), resolve(ns, tf))

    def command(self, joint: str) -> str:
        """The Float64 command topic of one joint (`/g1_description/left_elbow_joint_controller/command`)."""
        return self.command_pattern.replace("{joint}", joint)


# --- the GUI's sliders -----------------------------------------------------------------------


class GuiChanges:
    """Passes on only the GUI joints whose value changed since it last passed them on.

    joint_state_publisher_gui publishes every slider ten times a second whether it moved or not.
    Passing all of them on would undo every reset of the sim (ctl/reset, a mode switch) within 0.1 s
    and keep a joint the user moves elsewhere (a script, the viewer) pinned to its slider. So a
    slider counts once when it is first seen and then only when it moves, like a person's hand.
    """

    def __init__(self) -> None:
        self._last: dict[str, float] = {}

    def changed(self, targets: JointTargets) -> JointTargets | None:
        """The joints of `targets` that moved (all of them the first time), or None."""
        names, q = [], []
        for name, value in zip(targets.names, targets.q):
            if self._last.get(name) != value:
                names.append(name)
                q.append(value)
        self._last.update(zip(targets.names, targets.q))
        return JointTargets(names=tuple(names), q=tuple(q)) if names else None

    def forget(self) -> None:
        """Start over (another robot)."""
        self._last.clear()


class CommandGate(Generic[K, V]):
    """At most one forward per key per `1 / rate_hz` s of wall time; what comes faster is held, newest wins.

    A valid flood on one ROS topic (a script publishing Float64 at 10 kHz) would otherwise become as
    many zenoh puts, each decoded by the bridge, and starve the sim of CPU. The first command after a
    quiet spell goes out at once; the ones that follow within the period wait, each replacing the
    last, and the one left is forwarded when its time comes (`due`), so the newest value always
    arrives. The replaced ones are shed, and counted.

    Args:
        rate_hz: forwards per key per second; 0 forwards everything at once (no shedding).
    """

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self._last: dict[K, float] = {}
        self._held: dict[K, V] = {}

    def offer(self, key: K, value: V, now: float) -> tuple[bool, bool]:
        """(forward it now, a held value was shed): a held one is replaced by `value`."""
        last = self._last.get(key)
        if last is None or now - last >= self.period_s:
            self._last[key] = now
            shed = self._held.pop(key, None) is not None
            return True, shed
        shed = key in self._held
        self._held[key] = value
        return False, shed

    def due(self, now: float) -> list[tuple[K, V]]:
        """The held values whose period has passed, to forward now (and forget)."""
        ready = [(key, value) for key, value in self._held.items() if now - self._last[key] >= self.period_s]
        for key, _ in ready:
            del self._held[key]
            self._last[key] = now
        return ready

    def forget(self) -> None:
        """Drop what is held (a new robot: its joints may differ)."""
        self._held.clear()


# --- robot_description ------------------------------------------------------------------------

_MESH_FILENAME = re.compile(r"""(<mesh\b[^>]*?\bfilename\s*=\s*)(["'])(.*?)\2""", re.DOTALL)


def mesh_url(base_url: str, filename: str) -> str:
    """The http URL the gateway serves a URDF mesh reference at (`meshes/a.STL` -> `{base_url}/meshes/a.STL`)."""
    return f"{base_url.rstrip('/')}/{quote(mesh_key_path(filename))}"


def with_mesh_urls(urdf: str, base_url: str) -> str:
    """`urdf` with every `<mesh filename=...>` pointing at the gateway's http server, the rest untouched."""
    return _MESH_FILENAME.sub(lambda m: f"{m[1]}{m[2]}{mesh_url(base_url, m[3])}{m[2]}", urdf)


def mesh_references(urdf: str) -> list[str]:
    """Every `<mesh filename=...>` of a URDF, in order (what RViz will load)."""
    return [m[3] for m in _MESH_FILENAME.finditer(urdf)]
