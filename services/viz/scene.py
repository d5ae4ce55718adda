"""A URDF as meshcat geometry, and its forward kinematics: pure logic, no zenoh, no web server.

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
import posixpath
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import meshcat.commands as mc
import meshcat.geometry as mg
import numpy as np
import umsgpack

logger = logging.getLogger(__name__)

MOVABLE = ("revolute", "continuous", "prismatic")
DEFAULT_RGBA = (0.7, 0.7, 0.7, 1.0)


class UrdfError(ValueError):
    """A URDF the viewer cannot draw; the message names the element."""


@dataclass(frozen=True)
class Visual:
    """One `<visual>` of a link."""

    kind: str
    """box, cylinder, sphere or mesh."""
    T_link_visual: np.ndarray
    """The visual's origin in its link frame (4x4)."""
    rgba: tuple[float, float, float, float]
    """Colour from the URDF material (inline or by name)."""
    size: tuple[float, ...] = ()
    """box: (x, y, z); cylinder: (radius, length); sphere: (radius,)."""
    filename: str = ""
    """Mesh file as the URDF names it."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Mesh scale."""


@dataclass(frozen=True)
class Joint:
    name: str
    type: str
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float
    mimic: tuple[str, float, float] | None = None
    """(joint, multiplier, offset) for a mimic joint."""


@dataclass
class RobotDescription:
    """The parts of a URDF the viewer needs."""

    name: str
    root: str
    links: list[str]
    joints: list[Joint]
    """Every joint, parents before children."""
    visuals: dict[str, list[Visual]] = field(default_factory=dict)

    @property
    def movable_joints(self) -> list[Joint]:
        return [j for j in self.joints if j.type in MOVABLE and j.mimic is None]

    def mesh_filenames(self) -> list[str]:
        return sorted({v.filename for vs in self.visuals.values() for v in vs if v.kind == "mesh"})


def _floats(text: str | None, n: int, default: tuple[float, ...]) -> tuple[float, ...]:
    if text is None:
        return default
    values = tuple(float(x) for x in text.split())
    if len(values) != n:
        raise UrdfError(f"expected {n} numbers, got {text!r}")
    return values


def rpy_matrix(rpy: Sequence[float]) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _origin(element: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if element is not None:
        T[:3, :3] = rpy_matrix(_floats(element.get("rpy"), 3, (0.0, 0.0, 0.0)))
        T[:3, 3] = _floats(element.get("xyz"), 3, (0.0, 0.0, 0.0))
    return T


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


def parse_urdf(text: str) -> RobotDescription:
    """Parse URDF text.

    Raises:
        UrdfError: not XML, no links, or a joint that names a missing link.
    """
    try:
        robot = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f"URDF is not valid XML: {exc}") from None
    if robot.tag != "robot":
        raise UrdfError(f"root element is <{robot.tag}>, expected <robot>")
    materials: dict[str, tuple[float, float, float, float]] = {}
    for mat in robot.findall("material"):
        color = mat.find("color")
        if color is not None and mat.get("name"):
            materials[mat.get("name", "")] = _floats(color.get("rgba"), 4, DEFAULT_RGBA)  # type: ignore[assignment]

    links = [link.get("name", "") for link in robot.findall("link")]
    if not links:
        raise UrdfError("URDF has no <link>")
    visuals: dict[str, list[Visual]] = {}
    for link in robot.findall("link"):
        name = link.get("name", "")
        for vis in link.findall("visual"):
            visual = _visual(vis, materials, name)
            if visual is not None:
                visuals.setdefault(name, []).append(visual)

    raw_joints = []
    for j in robot.findall("joint"):
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            raise UrdfError(f"joint {j.get('name')!r} lacks <parent> or <child>")
        limit = j.find("limit")
        jtype = j.get("type", "fixed")
        lower = float(limit.get("lower", "0")) if limit is not None else 0.0
        upper = float(limit.get("upper", "0")) if limit is not None else 0.0
        if jtype == "continuous":
            lower, upper = -math.pi, math.pi
        axis = np.array(_floats(j.find("axis").get("xyz") if j.find("axis") is not None else None, 3, (1.0, 0.0, 0.0)))
        norm = np.linalg.norm(axis)
        mimic_el = j.find("mimic")
        mimic = None
        if mimic_el is not None:
            mimic = (mimic_el.get("joint", ""), float(mimic_el.get("multiplier", "1")), float(mimic_el.get("offset", "0")))
        raw_joints.append(Joint(
            name=j.get("name", ""), type=jtype, parent=parent.get("link", ""), child=child.get("link", ""),
            T_parent_joint=_origin(j.find("origin")), axis=axis / norm if norm > 0 else axis,
            lower=lower, upper=upper, mimic=mimic,
        ))
    known = set(links)
    for j in raw_joints:
        if j.parent not in known or j.child not in known:
            raise UrdfError(f"joint {j.name!r} names a link that does not exist")
    children = {j.child for j in raw_joints}
    roots = [link for link in links if link not in children]
    if len(roots) != 1:
        raise UrdfError(f"URDF must have one root link, found {roots}")
    # Order joints parents-first so forward kinematics is one pass.
    by_parent: dict[str, list[Joint]] = {}
    for j in raw_joints:
        by_parent.setdefault(j.parent, []).append(j)
    ordered: list[Joint] = []
    stack = [roots[0]]
    while stack:
        link = stack.pop()
        for j in by_parent.get(link, []):
            ordered.append(j)
            stack.append(j.child)
    return RobotDescription(name=robot.get("name", "robot"), root=roots[0], links=links, joints=ordered, visuals=visuals)


def _visual(vis: ET.Element, materials: Mapping[str, tuple[float, ...]], link: str) -> Visual | None:
    geom = vis.find("geometry")
    if geom is None or len(geom) == 0:
        return None
    shape = geom[0]
    rgba = DEFAULT_RGBA
    mat = vis.find("material")
    if mat is not None:
        color = mat.find("color")
        if color is not None:
            rgba = _floats(color.get("rgba"), 4, DEFAULT_RGBA)  # type: ignore[assignment]
        elif mat.get("name") in materials:
            rgba = materials[mat.get("name", "")]  # type: ignore[assignment]
    T = _origin(vis.find("origin"))
    if shape.tag == "box":
        return Visual("box", T, rgba, size=_floats(shape.get("size"), 3, (0.1, 0.1, 0.1)))
    if shape.tag == "cylinder":
        return Visual("cylinder", T, rgba, size=(float(shape.get("radius", "0.05")), float(shape.get("length", "0.1"))))
    if shape.tag == "sphere":
        return Visual("sphere", T, rgba, size=(float(shape.get("radius", "0.05")),))
    if shape.tag == "mesh":
        return Visual("mesh", T, rgba, filename=shape.get("filename", ""),
                      scale=_floats(shape.get("scale"), 3, (1.0, 1.0, 1.0)))  # type: ignore[arg-type]
    logger.warning("link %s: unsupported visual <%s> skipped", link, shape.tag)
    return None


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


def local_mesh_path(urdf_dir: str, filename: str) -> str:
    """A mesh filename resolved on disk, relative to the URDF's own folder (never the working directory).

    `package://pkg/a/b.stl` is tried as `a/b.stl` under the URDF folder and its parent.
    """
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    if filename.startswith("package://"):
        rest = filename[len("package://"):].split("/", 1)[-1]
        for base in (urdf_dir, posixpath.dirname(urdf_dir)):
            candidate = posixpath.join(base, rest)
            if posixpath.exists(candidate):
                return candidate
        return posixpath.join(urdf_dir, rest)
    return filename if posixpath.isabs(filename) else posixpath.join(urdf_dir, filename)


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
    robot: RobotDescription, root: str, meshes: Mapping[str, bytes], style: Style
) -> list[dict]:
    """The meshcat commands (lowered dicts) that draw `robot` under the path `/root`.

    Args:
        robot: the parsed URDF.
        root: top-level meshcat path for this drawing (`robot`, `ghost`).
        meshes: mesh bytes by URDF filename; a visual whose mesh is missing is skipped with a warning.
        style: colours.

    Returns:
        set_object and set_transform commands, links at the identity until the first frame.
    """
    commands: list[dict] = [mc.Delete(_path(root)).lower()]
    for link in robot.links:
        for i, vis in enumerate(robot.visuals.get(link, [])):
            geometry = _geometry(vis, meshes)
            if geometry is None:
                continue
            path = _path(root, link, f"v{i}")
            commands.append(mc.SetObject(geometry, style.material(vis.rgba), path).lower())
            T = vis.T_link_visual
            if vis.kind == "cylinder":
                T = T @ _CYLINDER_Z
            elif vis.kind == "mesh":
                T = T @ np.diag([*vis.scale, 1.0])
            commands.append({"type": "set_transform", "path": path.lower(), "matrix": _column_major(T)})
    return commands


def _path(*parts: str) -> mc.Path:
    return mc.Path(tuple(p.replace("/", "_") for p in parts))


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

    def __init__(self, robot: RobotDescription, joint_order: Sequence[str]) -> None:
        self.robot = robot
        self.links = [robot.root] + [j.child for j in robot.joints]
        self.joint_order = list(joint_order)
        index = {name: i for i, name in enumerate(self.joint_order)}
        self._steps = []
        for j in robot.joints:
            source = j.mimic[0] if j.mimic else j.name
            mult, offset = (j.mimic[1], j.mimic[2]) if j.mimic else (1.0, 0.0)
            self._steps.append((j, index.get(source, -1), mult, offset))

    def transforms(self, q: Sequence[float] | None, T_world_base: np.ndarray) -> np.ndarray:
        """World transforms of every link in `self.links` order, shape (n_links, 4, 4).

        Joints absent from `q` (or `q` None) sit at 0.
        """
        out = np.empty((len(self.links), 4, 4))
        out[0] = T_world_base
        frames = {self.robot.root: T_world_base}
        for k, (j, idx, mult, offset) in enumerate(self._steps, start=1):
            T = frames[j.parent] @ j.T_parent_joint
            if j.type in MOVABLE:
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
ROOTS_WITH_GHOST = ("robot", "ghost")


@dataclass
class Drawing:
    """One robot ready to draw: its meshcat commands, kinematics and what the panel shows."""

    robot: RobotDescription
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
    urdf_text: str,
    meshes: Mapping[str, bytes],
    joint_names: Sequence[str] | None = None,
    q_min: Sequence[float] | None = None,
    q_max: Sequence[float] | None = None,
    ghost: bool = True,
    source: str = "",
) -> Drawing:
    """Everything the viewer needs from a description.

    Args:
        urdf_text: the URDF.
        meshes: mesh bytes by URDF filename.
        joint_names: the canonical joint order of JointState (RobotInfo.joint_names);
            None: the URDF's movable joints in file order.
        q_min: lower limits in `joint_names` order (RobotInfo); None: from the URDF.
        q_max: upper limits likewise.
        ghost: also draw the translucent commanded pose.
        source: where the description came from, shown on the page.

    Raises:
        UrdfError: the URDF cannot be drawn, or the limits do not match the joints.
    """
    robot = parse_urdf(urdf_text)
    by_name = {j.name: j for j in robot.joints}
    names = tuple(joint_names) if joint_names is not None else tuple(j.name for j in robot.movable_joints)
    lower = tuple(q_min) if q_min is not None else tuple(by_name[n].lower if n in by_name else -math.pi for n in names)
    upper = tuple(q_max) if q_max is not None else tuple(by_name[n].upper if n in by_name else math.pi for n in names)
    if not len(lower) == len(upper) == len(names):
        raise UrdfError(f"{len(names)} joints but {len(lower)} lower and {len(upper)} upper limits")
    missing = [n for n in names if n not in by_name]
    if missing:
        logger.warning("joints not in the URDF (not drawn): %s", ", ".join(missing))
    kin = Kinematics(robot, names)
    roots = ROOTS_WITH_GHOST if ghost else ("robot",)
    commands = [pack_command(c) for c in scene_commands(robot, "robot", meshes, Style())]
    if ghost:
        commands += [pack_command(c) for c in scene_commands(robot, "ghost", meshes, Style(GHOST_COLOR, GHOST_OPACITY))]
        # Hidden until the first commanded pose arrives.
        commands.append(pack_command({"type": "set_property", "path": "/ghost", "property": "visible", "value": False}))
    meta = {
        "name": robot.name,
        "source": source,
        "joints": [{"name": n, "lower": lo, "upper": hi} for n, lo, hi in zip(names, lower, upper)],
        "paths": layout_paths(kin, roots),
        "roots": list(roots),
        "links": len(kin.links),
    }
    return Drawing(robot, kin, names, lower, upper, roots, commands, meta)
