"""What the ROS 1 gateway maps, as pure rules: no rospy, no zenoh (service.py does the wiring).

- ROS names: the settings' topic names resolved in the robot's namespace.
- Inputs from ROS: a per-joint Float64 or the GUI's JointState is checked whole against the robot
  (finite, known joints, within the joint's limits, one position per name) and becomes the value the
  bridge gets, or an `InputError` saying why; nothing of a refused message is passed on.
- Outputs to ROS: the odometry as Gazebo's p3d plugin gives it, quaternions reordered to ROS's x, y, z, w.
- The URDF for robot_description, its mesh references pointed at the gateway's http server.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar
from urllib.parse import quote

from zensim.schemas import JointTargets, Odometry, RobotInfo
from zensim.schemas.keys import mesh_key_path

K = TypeVar("K")
V = TypeVar("V")

LIMIT_SLACK_RAD = 1e-9
"""A position this far past a limit still counts as inside it (a GUI slider at its end, after rounding)."""


class InputError(ValueError):
    """A ROS message refused whole; the text says why."""


# --- names ------------------------------------------------------------------------------


def resolve(namespace: str, name: str) -> str:
    """A ROS graph name: `name` as is when absolute (`/clock`), else under `namespace`."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


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


# --- the robot's joints and the inputs from ROS -------------------------------------------


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


# --- outputs to ROS -------------------------------------------------------------------------


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
