"""A robot description (URDF) read once, for everyone: the model builder, the viewer and derive.py.

yourdfpy parses the URDF (no scene graph, no meshes); this module turns its result into the few
frozen facts zensim uses, with one set of rules:

- joints keep the URDF's document order, which is the canonical joint order on the wire;
- a joint limit the URDF leaves out is infinite: position limits of a `continuous` joint or of a
  joint without `<limit>`, and an effort or velocity limit given as 0 or not given (URDF files use
  0 for "no limit" in practice);
- a visual's colour is its inline `<color>`, else the robot-level `<material>` it names.

The viewer parses URDF text it receives over the network, so the XML is first read by a parser that
loads no DTD, expands no entities and reaches no network: a document declaring a DTD (the way to an
entity-expansion bomb) is refused before yourdfpy, whose own parser would expand it, sees it.
No mujoco import here: the viewer uses this module too.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import yourdfpy
from lxml import etree

ACTUATED_TYPES: Final = frozenset({"revolute", "continuous", "prismatic"})
DEFAULT_RGBA: Final = (0.7, 0.7, 0.7, 1.0)

_SAFE_XML: Final = etree.XMLParser(resolve_entities=False, load_dtd=False, no_network=True, huge_tree=False)


class RobotModelError(ValueError):
    """A robot description or control file that cannot be used; the message names what is wrong."""


@dataclass(frozen=True)
class Visual:
    """One `<visual>` of a link."""

    kind: str
    """box, cylinder, sphere or mesh."""
    origin: np.ndarray
    """The visual's pose in its link frame (4x4)."""
    rgba: tuple[float, float, float, float]
    size: tuple[float, ...] = ()
    """box: (x, y, z); cylinder: (radius, length); sphere: (radius,)."""
    filename: str = ""
    """Mesh file as the URDF names it."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    material: str = ""
    """The material's name, if the URDF gives one."""


@dataclass(frozen=True)
class Joint:
    """One joint, limits in SI units (infinite where the URDF gives none, see the module docstring)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    """The joint frame in the parent link frame (4x4)."""
    axis: np.ndarray
    """Unit axis in the joint frame."""
    lower: float = -math.inf
    upper: float = math.inf
    effort: float = math.inf
    velocity: float = math.inf
    mimic: tuple[str, float, float] | None = None
    """(joint, multiplier, offset) for a mimic joint."""

    @property
    def actuated(self) -> bool:
        return self.type in ACTUATED_TYPES


@dataclass(frozen=True)
class Description:
    """What zensim reads from a URDF."""

    name: str
    root_link: str
    links: tuple[str, ...]
    joints: tuple[Joint, ...]
    """Every joint, in document order."""
    visuals: dict[str, tuple[Visual, ...]] = field(default_factory=dict)
    """Visuals per link name (links without any are absent)."""
    mesh_filenames: tuple[str, ...] = ()
    """Every mesh the URDF names, visual and collision, once each, in document order."""

    @property
    def actuated_joints(self) -> tuple[Joint, ...]:
        """The joints that get a motor, in canonical (document) order."""
        return tuple(j for j in self.joints if j.actuated)

    def joints_from_root(self) -> Iterator[Joint]:
        """Every joint, each after the joint that moves its parent link (one pass of forward kinematics)."""
        children: dict[str, list[Joint]] = {}
        for joint in self.joints:
            children.setdefault(joint.parent, []).append(joint)
        stack = [self.root_link]
        while stack:
            for joint in children.get(stack.pop(), []):
                yield joint
                stack.append(joint.child)


def load_description(path: Path) -> Description:
    """Read and parse a URDF file (see `parse_urdf`)."""
    return parse_urdf(Path(path).read_bytes())


def parse_urdf(text: str | bytes) -> Description:
    """Parse URDF text.

    Raises:
        RobotModelError: not XML, a DTD, not a `<robot>`, no links, not exactly one root link, a joint
            naming a missing link, or an element yourdfpy cannot read (the message says which).
    """
    data = text.encode() if isinstance(text, str) else text
    try:
        root = etree.fromstring(data, parser=_SAFE_XML)
    except etree.XMLSyntaxError as exc:
        raise RobotModelError(f"URDF is not valid XML: {exc}") from None
    if root.getroottree().docinfo.doctype:
        raise RobotModelError("URDF declares a DTD; a robot description has no use for one (entities are refused)")
    if root.tag != "robot":
        raise RobotModelError(f"not a URDF: root element is <{root.tag}>, expected <robot>")
    try:
        robot = yourdfpy.URDF.load(io.BytesIO(data), build_scene_graph=False, load_meshes=False).robot
        return _description(robot)
    except RobotModelError:
        raise
    except (KeyError, AttributeError, IndexError, TypeError, ValueError) as exc:
        # yourdfpy reads attributes without checking them: a missing `name` is a KeyError, a joint
        # without <parent> an AttributeError, `<geometry/>` an IndexError, "abc" a ValueError.
        raise RobotModelError(f"URDF element cannot be read: {type(exc).__name__}: {exc}") from None


def _description(robot: yourdfpy.Robot) -> Description:
    links = tuple(link.name for link in robot.links)
    if not links:
        raise RobotModelError("URDF has no <link>")
    joints = tuple(_joint(j) for j in robot.joints)
    known = set(links)
    for j in joints:
        if j.parent not in known or j.child not in known:
            raise RobotModelError(f"joint {j.name!r} names a link that does not exist")
    children = {j.child for j in joints}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise RobotModelError(f"URDF must have exactly one root link, found {roots}")
    materials = {m.name: _rgba(m.color) for m in robot.materials if m.name and m.color is not None}
    visuals = {}
    for link in robot.links:
        drawn = tuple(_visual(v, materials) for v in link.visuals if v.geometry is not None)
        if drawn:
            visuals[link.name] = drawn
    geometries = [g.geometry for link in robot.links for g in (*link.visuals, *link.collisions)]
    meshes = tuple(dict.fromkeys(g.mesh.filename for g in geometries if g is not None and g.mesh is not None))
    return Description(name=robot.name, root_link=roots[0], links=links, joints=joints, visuals=visuals,
                       mesh_filenames=meshes)


def _no_limit_if_not_positive(value: float | None) -> float:
    return value if value is not None and value > 0 else math.inf


def _joint(j: yourdfpy.Joint) -> Joint:
    limit = j.limit or yourdfpy.Limit()
    bounded = j.type != "continuous"
    axis = np.asarray(j.axis, float)
    norm = float(np.linalg.norm(axis))
    mimic = None
    if j.mimic is not None:
        mimic = (j.mimic.joint, float(j.mimic.multiplier), float(j.mimic.offset))
    return Joint(
        name=j.name, type=j.type or "", parent=j.parent, child=j.child,
        origin=np.eye(4) if j.origin is None else np.asarray(j.origin, float),
        axis=axis / norm if norm > 0 else axis,
        lower=limit.lower if bounded and limit.lower is not None else -math.inf,
        upper=limit.upper if bounded and limit.upper is not None else math.inf,
        effort=_no_limit_if_not_positive(limit.effort),
        velocity=_no_limit_if_not_positive(limit.velocity),
        mimic=mimic,
    )


def _rgba(color: yourdfpy.Color) -> tuple[float, float, float, float]:
    values = [float(c) for c in color.rgba]
    if len(values) != 4:
        raise RobotModelError(f"a colour needs 4 numbers (rgba), got {len(values)}")
    rgba = (values[0], values[1], values[2], values[3])
    return rgba


def _visual(v: yourdfpy.Visual, materials: dict[str, tuple[float, float, float, float]]) -> Visual:
    rgba = DEFAULT_RGBA
    if v.material is not None:
        if v.material.color is not None:
            rgba = _rgba(v.material.color)
        elif v.material.name in materials:
            rgba = materials[v.material.name]
    origin = np.eye(4) if v.origin is None else np.asarray(v.origin, float)
    material = (v.material.name if v.material is not None else None) or ""
    g = v.geometry
    if g.box is not None:
        return Visual("box", origin, rgba, size=tuple(float(x) for x in g.box.size), material=material)
    if g.cylinder is not None:
        return Visual("cylinder", origin, rgba, size=(float(g.cylinder.radius), float(g.cylinder.length)),
                      material=material)
    if g.sphere is not None:
        return Visual("sphere", origin, rgba, size=(float(g.sphere.radius),), material=material)
    scale = g.mesh.scale
    scale3 = (1.0, 1.0, 1.0) if scale is None else tuple(float(s) for s in np.broadcast_to(scale, 3))
    return Visual("mesh", origin, rgba, filename=g.mesh.filename or "", scale=scale3,  # type: ignore[arg-type]
                  material=material)
