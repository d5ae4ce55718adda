"""A URDF as meshcat geometry, and its forward kinematics: pure logic, no zenoh, no web server.

The description comes parsed from `zensim.robots.description` (the one URDF reader).
The viewer draws one meshcat node per link (`/<root>/<link>`) with the
link's visuals as fixed children. Only the link transforms change with the
pose, so a pose update is one flat float32 array (`Frame`) that the page
applies to a known list of paths, instead of one meshcat command per link.

Forward kinematics is a chain of 4x4 products in joint order (~0.1 ms for the
G1 in numpy), cheaper than yourdfpy's scene graph (1-4 ms per update, measured)
and with no MuJoCo model to compile from mesh bytes.

Geometry is lowered with meshcat's own Python objects (`meshcat.geometry`,
`meshcat.commands`), so the page feeds them to meshcat's stock viewer as is.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import meshcat.commands as mc
import meshcat.geometry as mg
import numpy as np
import umsgpack

from zensim.robots.description import Description, Joint, RobotModelError, Visual

logger = logging.getLogger(__name__)



def movable_joints(robot: Description) -> list[Joint]:
    """The joints a slider moves: actuated and not mimicking another (document order)."""
    return [j for j in robot.actuated_joints if j.mimic is None]


def visual_mesh_filenames(robot: Description) -> list[str]:
    """The mesh files the drawing needs (collision meshes are not drawn)."""
    return sorted({v.filename for vs in robot.visuals.values() for v in vs if v.kind == "mesh"})


def quat_matrix(wxyz: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a scalar-first quaternion (normalised here: the wire may carry rounding)."""
    w, x, y, z = wxyz
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def match_mesh(filename: str, available: Sequence[str]) -> str | None:
    """The entry of `available` (RobotInfo.mesh_paths, or local paths) that a URDF mesh filename means.

    Exact match first, then the longest path suffix in common, because the
    sim may serve `meshes/pelvis.STL` for `package://g1_description/meshes/pelvis.STL`.
    """
    if filename in available:
        return filename
    stripped = filename.split("://", 1)[-1].lstrip("/")
    parts = stripped.split("/")
    best, best_len = None, 0
    for path in available:
        candidate = path.split("://", 1)[-1].lstrip("/").split("/")
        n = 0
        while n < min(len(parts), len(candidate)) and parts[-1 - n] == candidate[-1 - n]:
            n += 1
        if n > best_len:
            best, best_len = path, n
    return best


def _hex(rgba: Sequence[float]) -> int:
    r, g, b = (max(0, min(255, int(round(c * 255)))) for c in rgba[:3])
    return (r << 16) | (g << 8) | b


def _column_major(T: np.ndarray) -> list[float]:
    return [float(x) for x in T.T.flatten()]


_CYLINDER_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
"""three.js cylinders run along y, URDF cylinders along z: rotate +90 deg about x."""


class Style:
    """How one drawing of the robot looks: URDF colours, or one colour for the ghost."""

    def __init__(self, color: int | None = None, opacity: float = 1.0) -> None:
        self.color = color
        self.opacity = opacity

    def material(self, rgba: Sequence[float]) -> mg.MeshPhongMaterial:
        opacity = self.opacity * rgba[3]
        color = self.color if self.color is not None else _hex(rgba)
        if opacity < 1.0:
            # depthWrite off: a translucent ghost must not hide the robot inside it.
            return mg.MeshPhongMaterial(color=color, opacity=opacity, transparent=True, depthWrite=False)
        return mg.MeshPhongMaterial(color=color)


def scene_commands(
    robot: Description, root: str, meshes: Mapping[str, bytes], style: Style
) -> list[dict]:
    """The meshcat commands (lowered dicts) that draw `robot` under the path `/root`.

    Args:
        robot: the parsed URDF.
        root: meshcat path of this drawing (`robot`, `ghost`; a world's `robots/g1a`).
        meshes: mesh bytes by URDF filename; a visual whose mesh is missing is skipped with a warning.
        style: colours.

    Returns:
        set_object and set_transform commands, links at the identity until the first frame.
    """
    base = tuple(root.split("/"))
    commands: list[dict] = [mc.Delete(mc.Path(base)).lower()]
    for link in robot.links:
        for i, vis in enumerate(robot.visuals.get(link, [])):
            geometry = _geometry(vis, meshes)
            if geometry is None:
                continue
            path = mc.Path(base + (link.replace("/", "_"), f"v{i}"))
            commands.append(mc.SetObject(geometry, style.material(vis.rgba), path).lower())
            T = vis.origin
            if vis.kind == "cylinder":
                T = T @ _CYLINDER_Z
            elif vis.kind == "mesh":
                T = T @ np.diag([*vis.scale, 1.0])
            commands.append({"type": "set_transform", "path": path.lower(), "matrix": _column_major(T)})
    return commands


def _geometry(vis: Visual, meshes: Mapping[str, bytes]) -> mg.Geometry | None:
    if vis.kind == "box":
        return mg.Box(list(vis.size))
    if vis.kind == "cylinder":
        return mg.Cylinder(vis.size[1], vis.size[0])
    if vis.kind == "sphere":
        return mg.Sphere(vis.size[0])
    data = meshes.get(vis.filename)
    if data is None:
        logger.warning("mesh %s not available: not drawn", vis.filename)
        return None
    ext = vis.filename.rsplit(".", 1)[-1].lower()
    if ext == "stl":
        geom = mg.MeshGeometry(umsgpack.Ext(0x12, bytes(data)), "stl")
    elif ext in ("obj", "dae"):
        geom = mg.MeshGeometry(data.decode("utf-8", errors="replace"), ext)
    else:
        logger.warning("mesh %s: format %s not supported by meshcat: not drawn", vis.filename, ext)
        return None
    return geom


def pack_command(command: dict) -> bytes:
    """A lowered meshcat command as msgpack (meshcat's own umsgpack, which knows its typed-array Ext)."""
    return umsgpack.packb(command)


class Kinematics:
    """Forward kinematics of a RobotDescription for a joint vector in a given order."""

    def __init__(self, robot: Description, joint_order: Sequence[str]) -> None:
        self.robot = robot
        joints = list(robot.joints_from_root())
        self.links = [robot.root_link] + [j.child for j in joints]
        self.joint_order = list(joint_order)
        index = {name: i for i, name in enumerate(self.joint_order)}
        self._steps = []
        for j in joints:
            source = j.mimic[0] if j.mimic else j.name
            mult, offset = (j.mimic[1], j.mimic[2]) if j.mimic else (1.0, 0.0)
            self._steps.append((j, index.get(source, -1), mult, offset))

    def transforms(self, q: Sequence[float] | None, T_world_base: np.ndarray) -> np.ndarray:
        """World transforms of every link in `self.links` order, shape (n_links, 4, 4).

        Joints absent from `q` (or `q` None) sit at 0.
        """
        out = np.empty((len(self.links), 4, 4))
        out[0] = T_world_base
        frames = {self.robot.root_link: T_world_base}
        for k, (j, idx, mult, offset) in enumerate(self._steps, start=1):
            T = frames[j.parent] @ j.origin
            if j.actuated:
                value = (q[idx] if q is not None and 0 <= idx < len(q) else 0.0) * mult + offset
                M = np.eye(4)
                if j.type == "prismatic":
                    M[:3, 3] = j.axis * value
                else:
                    M[:3, :3] = _axis_angle(j.axis, value)
                T = T @ M
            frames[j.child] = T
            out[k] = T
        return out


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    C = 1 - c
    return np.array([
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ])


def base_transform(pos: Sequence[float] | None, quat_wxyz: Sequence[float] | None, offset: Sequence[float] = (0, 0, 0)) -> np.ndarray:
    """World transform of the base link from odometry (identity parts where absent), shifted by `offset`."""
    T = np.eye(4)
    if quat_wxyz is not None and len(quat_wxyz) == 4:
        T[:3, :3] = quat_matrix(quat_wxyz)
    if pos is not None and len(pos) == 3:
        T[:3, 3] = pos
    T[:3, 3] += offset
    return T


def frame_payload(*transforms: np.ndarray) -> bytes:
    """Link transforms of one or more drawings as float32, column-major per 4x4 (three.js order)."""
    stacked = np.concatenate(transforms) if len(transforms) > 1 else transforms[0]
    return np.ascontiguousarray(stacked.transpose(0, 2, 1), dtype=np.float32).tobytes()


def layout_paths(kin: Kinematics, roots: Sequence[str]) -> list[str]:
    """Meshcat paths (`/root/link`) in the order `frame_payload` writes the transforms."""
    return [f"/{root}/{link.replace('/', '_')}" for root in roots for link in kin.links]


GHOST_COLOR: int = 0x33CCFF
GHOST_OPACITY: float = 0.35
ROOTS_WITH_GHOST: tuple[str, str] = ("robot", "ghost")
"""Meshcat paths of one robot's drawing and its ghost (a world's robots get their own: viz/world.py)."""


@dataclass
class Drawing:
    """One robot ready to draw: its meshcat commands, kinematics and what the panel shows."""

    robot: Description
    kin: Kinematics
    joint_names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    roots: tuple[str, ...]
    commands: list[bytes]
    """Packed meshcat commands: the robot, then the ghost."""
    meta: dict
    """The `robot` JSON message for the page: joints, limits, frame layout."""


def build_drawing(
    robot: Description,
    meshes: Mapping[str, bytes],
    joint_names: Sequence[str] | None = None,
    q_min: Sequence[float] | None = None,
    q_max: Sequence[float] | None = None,
    ghost: bool = True,
    source: str = "",
    roots: tuple[str, str] = ROOTS_WITH_GHOST,
    geometry: bool = True,
) -> Drawing:
    """Everything the viewer needs from a description.

    Args:
        robot: the parsed URDF.
        meshes: mesh bytes by URDF filename.
        joint_names: the canonical joint order of JointState (RobotInfo.joint_names);
            None: the URDF's movable joints in file order.
        q_min: lower limits in `joint_names` order (RobotInfo); None: from the URDF (a joint
            without position limits, e.g. continuous, gets a slider over one turn).
        q_max: upper limits likewise.
        ghost: also draw the translucent commanded pose.
        source: where the description came from, shown on the page.
        roots: meshcat paths of the robot and of its ghost.
        geometry: False: no meshcat commands, for a robot whose description another robot's drawing
            already carries (the page copies that one's shapes: a world's G1s send their meshes once).

    Raises:
        RobotModelError: the limits do not match the joints.
    """
    by_name = {j.name: j for j in robot.joints}
    names = tuple(joint_names) if joint_names is not None else tuple(j.name for j in movable_joints(robot))

    def urdf_limit(name: str, side: str, turn: float) -> float:
        value = getattr(by_name[name], side) if name in by_name else turn
        return value if math.isfinite(value) else turn

    lower = tuple(q_min) if q_min is not None else tuple(urdf_limit(n, "lower", -math.pi) for n in names)
    upper = tuple(q_max) if q_max is not None else tuple(urdf_limit(n, "upper", math.pi) for n in names)
    if not len(lower) == len(upper) == len(names):
        raise RobotModelError(f"{len(names)} joints but {len(lower)} lower and {len(upper)} upper limits")
    missing = [n for n in names if n not in by_name]
    if missing:
        logger.warning("joints not in the URDF (not drawn): %s", ", ".join(missing))
    kin = Kinematics(robot, names)
    root, ghost_root = roots
    drawn: tuple[str, ...] = roots if ghost else (root,)
    commands = [pack_command(c) for c in scene_commands(robot, root, meshes, Style())] if geometry else []
    if ghost and geometry:
        commands += [pack_command(c) for c in scene_commands(robot, ghost_root, meshes, Style(GHOST_COLOR, GHOST_OPACITY))]
        # Hidden until the first commanded pose arrives.
        commands.append(pack_command({"type": "set_property", "path": f"/{ghost_root}", "property": "visible",
                                      "value": False}))
    meta = {
        "name": robot.name,
        "source": source,
        "joints": [{"name": n, "lower": lo, "upper": hi} for n, lo, hi in zip(names, lower, upper)],
        "paths": layout_paths(kin, drawn),
        "roots": list(drawn),
        "links": len(kin.links),
    }
    return Drawing(robot, kin, names, lower, upper, drawn, commands, meta)
