"""Derive the project's own G1 URDF from Unitree's official g1_29dof.urdf.

A developer tool, run by hand (the product never reads the official files):

    pip install fast-simplification       # build time only: decimates the visual meshes
    python robots/unitree_g1/derive.py /path/to/g1_description/g1_29dof.urdf \
        --meshes robots/unitree_g1/meshes > robots/unitree_g1/g1_29dof.urdf

Why: the official model collides with 19 MB of detailed STL meshes (slow contacts, a slow compile).
This script keeps the real robot's figures verbatim (joints, limits, masses, inertias, sensor frames)
and gives each link two geometries:

- visual: Unitree's own mesh, decimated (fast-simplification's quadric decimation, the strongest
  reduction whose surface stays within DECIMATION_TOLERANCE_M of the original both ways, at the 99th
  percentile of sampled points), so the robot looks like a G1 at a sixth of the bytes;
- collision: one primitive sized from that mesh's bounding box in its link frame, so it stands on the
  same feet and steps fast:

- limb segments ("bones": thigh, shin, upper arm, forearm) become cylinders from the link origin to
  the child joint, with the radius that covers most mesh vertices around that axis;
- the head becomes a sphere; everything else a box equal to the mesh bounding box;
- each foot is the bounding box of the official foot mesh, whose sole (z = -0.035 in the ankle roll
  frame) is also where the official model's foot contact spheres end, so pelvis heights match;
- decorative fixed links of 1 g (pelvis contour, logo, waist support) are dropped: their collision
  boxes are folded into the parent's where they give it its shape (the pelvis), their visual meshes
  become extra visuals of the parent link, placed through the dropped fixed joint.

The official URDF is read through zensim.robots.description (the project's one URDF reader); its
<inertial> and <joint> elements are copied verbatim with the standard library's XML writer. A 30-line
STL reader sizes the primitives (as before the meshes were shipped: the collisions stay exactly the
same); trimesh and fast-simplification decimate the visuals.
"""

from __future__ import annotations

import argparse
import struct
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from zensim.robots.description import Visual, load_description

#: Fixed links that carry only a decorative mesh and 1 g: dropped from our model.
DROPPED_LINKS: frozenset[str] = frozenset({"pelvis_contour_link", "logo_link", "waist_support_link"})
#: Links whose mesh bounding box is merged into another link's primitive (same frame: identity joint).
MERGED_INTO: dict[str, str] = {"pelvis_contour_link": "pelvis"}
#: Links drawn as a cylinder from the link origin to this child joint.
BONES: dict[str, str] = {
    "left_hip_yaw_link": "left_knee_joint",
    "right_hip_yaw_link": "right_knee_joint",
    "left_knee_link": "left_ankle_pitch_joint",
    "right_knee_link": "right_ankle_pitch_joint",
    "left_shoulder_roll_link": "left_shoulder_yaw_joint",
    "right_shoulder_roll_link": "right_shoulder_yaw_joint",
    "left_shoulder_yaw_link": "left_elbow_joint",
    "right_shoulder_yaw_link": "right_elbow_joint",
    "left_elbow_link": "left_wrist_roll_joint",
    "right_elbow_link": "right_wrist_roll_joint",
}
SPHERES: frozenset[str] = frozenset({"head_link"})
DECIMATION_TOLERANCE_M = 0.001
"""Largest deviation (99th percentile, both ways) of a decimated visual mesh from Unitree's original."""
DECIMATION_STEPS = tuple(round(0.5 + 0.05 * i, 2) for i in range(10))
"""Reductions tried (fraction of triangles removed), 0.5 to 0.95."""
DECIMATION_AGGRESSIVENESS = (3, 7)
"""fast-simplification's `agg` values tried: 3 keeps thin parts that 7 (its default) collapses."""
SURFACE_SAMPLES = 3000
"""Points sampled on each surface to measure the deviation."""


def read_stl(path: Path) -> np.ndarray:
    """Return the (N, 3) vertices of a binary or ASCII STL file.

    Binary files may also start with "solid", so the size check decides, not the header.
    """
    data = path.read_bytes()
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        if len(data) == 84 + 50 * count:
            tri = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
            return np.frombuffer(data, tri, count=count, offset=84)["v"].reshape(-1, 3).astype(float)
    rows = [line.split()[1:4] for line in data.decode("ascii").splitlines() if line.strip().startswith("vertex")]
    return np.asarray(rows, dtype=float)


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a rotation matrix (R = Rz(y) Ry(p) Rx(r))."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(m: np.ndarray) -> np.ndarray:
    """Inverse of rpy_to_matrix (away from pitch = +-90 degrees, which bones here never reach)."""
    return np.array([np.arctan2(m[2, 1], m[2, 2]), -np.arcsin(np.clip(m[2, 0], -1, 1)), np.arctan2(m[1, 0], m[0, 0])])


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{v:.5f}".rstrip("0").rstrip(".") if abs(v) >= 5e-6 else "0" for v in values)


def _xml(element: ET.Element, level: int) -> str:
    """Serialise an element copied from the official file with the project's indentation."""
    ET.indent(element, space="  ", level=level)
    element.tail = None
    return "  " * level + ET.tostring(element, encoding="unicode").replace(" />", "/>")


def link_vertices(visuals: tuple[Visual, ...], mesh_root: Path) -> np.ndarray | None:
    """Vertices of a link's visual meshes, expressed in the link frame."""
    chunks = [read_stl(mesh_root / v.filename) @ v.origin[:3, :3].T + v.origin[:3, 3]
              for v in visuals if v.kind == "mesh"]
    return np.vstack(chunks) if chunks else None


def primitive(name: str, verts: np.ndarray, child_joint_xyz: np.ndarray | None) -> tuple[str, np.ndarray, np.ndarray]:
    """Choose a primitive for one link: (geometry element text, origin xyz, origin rpy)."""
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    if child_joint_xyz is not None:
        length = float(np.linalg.norm(child_joint_xyz))
        axis = child_joint_xyz / length
        along = verts @ axis
        inside = verts[(along > 0.0) & (along < length)]
        perp = inside - np.outer(inside @ axis, axis)
        radius = float(np.percentile(np.linalg.norm(perp, axis=1), 70))
        # Build a frame whose z is the bone axis: URDF cylinders extend along their local z.
        helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
        x = np.cross(helper, axis)
        x /= np.linalg.norm(x)
        frame = np.column_stack([x, np.cross(axis, x), axis])
        rpy = matrix_to_rpy(frame)
        if not np.allclose(rpy_to_matrix(rpy)[:, 2], axis, atol=1e-6):
            raise ValueError(f"{name}: bone axis does not round-trip through rpy")
        return f'<cylinder radius="{radius:.4f}" length="{length:.4f}"/>', child_joint_xyz / 2, rpy
    centre, size = (lo + hi) / 2, hi - lo
    if name in SPHERES:
        return f'<sphere radius="{float(np.mean(size)) / 2:.4f}"/>', centre, np.zeros(3)
    return f'<box size="{_fmt(size)}"/>', centre, np.zeros(3)


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray, header: str) -> None:
    """Write a binary STL (float32 vertices, unit face normals, an ASCII header of up to 80 bytes)."""
    tri = vertices[faces].astype("<f4")
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    records = np.zeros(len(faces), np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]))
    records["normal"], records["v"] = normals, tri
    head = header.encode("ascii")[:80].ljust(80, b" ")
    path.write_bytes(head + struct.pack("<I", len(faces)) + records.tobytes())


def decimate(source: Path, target: Path) -> tuple[int, int, float]:
    """Write `source` decimated as far as DECIMATION_TOLERANCE_M allows to `target` (binary STL).

    Deterministic: fixed reductions, fixed sampling seeds. Needs trimesh and fast-simplification
    (build time only; the product reads STL files, never these libraries).

    Returns:
        Triangles before, triangles after, and the deviation reached (m).
    """
    import fast_simplification  # noqa: PLC0415 (a developer's tool, not a dependency of the product)
    import trimesh  # noqa: PLC0415

    mesh = trimesh.load(source, file_type="stl")
    assert isinstance(mesh, trimesh.Trimesh), "an STL file is one mesh, never a scene"
    samples, _ = trimesh.sample.sample_surface(mesh, SURFACE_SAMPLES, seed=0)
    best = (mesh.vertices, mesh.faces, 0.0)
    for agg in DECIMATION_AGGRESSIVENESS:
        for reduction in DECIMATION_STEPS:
            vertices, faces = fast_simplification.simplify(mesh.vertices, mesh.faces, target_reduction=reduction, agg=agg)
            if len(faces) >= len(best[1]):
                continue
            simplified = trimesh.Trimesh(vertices, faces, process=False)
            _, lost, _ = trimesh.proximity.closest_point(simplified, samples)  # original -> simplified
            back, _ = trimesh.sample.sample_surface(simplified, SURFACE_SAMPLES, seed=0)
            _, added, _ = trimesh.proximity.closest_point(mesh, back)  # simplified -> original
            deviation = float(max(np.percentile(lost, 99), np.percentile(added, 99)))
            if deviation <= DECIMATION_TOLERANCE_M:
                best = (vertices, faces, deviation)
    vertices, faces, deviation = best
    write_stl(target, np.asarray(vertices), np.asarray(faces),
              f"unitree_ros d6f13aa {source.name}, decimated by zensim derive.py (BSD-3-Clause, Unitree)")
    return len(mesh.faces), len(faces), deviation


def _child_link(joint: ET.Element) -> str:
    """The link a URDF joint moves; a joint without one is an error, not a joint to drop."""
    child = joint.find("child")
    link = child.get("link") if child is not None else None
    if link is None:
        raise ValueError(f"joint {joint.get('name')!r} names no <child link=...>")
    return link


def _visual_xml(filename: str, origin: np.ndarray, material: str) -> str:
    xyz, rpy = origin[:3, 3], matrix_to_rpy(origin[:3, :3])
    return (f'    <visual><origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>'
            f'<geometry><mesh filename="{filename}"/></geometry><material name="{material}"/></visual>')


def mesh_visuals(official_urdf: Path, meshes_out: Path) -> dict[str, list[str]]:
    """Decimate every visual mesh into `meshes_out`; return the <visual> lines per kept link.

    A dropped link's visuals go to its parent, placed through the fixed joint between them.
    """
    description = load_description(official_urdf)
    joint_of = {j.child: j for j in description.joints}
    meshes_out.mkdir(parents=True, exist_ok=True)
    lines: dict[str, list[str]] = {}
    for link, visuals in description.visuals.items():
        owner, placement = link, np.eye(4)
        if link in DROPPED_LINKS:
            joint = joint_of[link]
            owner, placement = joint.parent, joint.origin
        for visual in visuals:
            if visual.kind != "mesh":
                continue
            name = Path(visual.filename).name
            before, after, deviation = decimate(official_urdf.parent / visual.filename, meshes_out / name)
            print(f"{name}: {before} -> {after} triangles, deviation {deviation * 1e3:.2f} mm", file=sys.stderr)
            lines.setdefault(owner, []).append(
                _visual_xml(f"meshes/{name}", placement @ visual.origin, visual.material or "white"))
    return lines


def derive(official_urdf: Path, meshes_out: Path) -> str:
    """Return the text of the project's G1 URDF derived from the official one; write its visual meshes."""
    description = load_description(official_urdf)
    visual_lines = mesh_visuals(official_urdf, meshes_out)
    joint_xyz = {j.name: j.origin[:3, 3] for j in description.joints}
    verts_by_link: dict[str, np.ndarray] = {}
    for name, visuals in description.visuals.items():
        verts = link_vertices(visuals, official_urdf.parent)
        if verts is not None:
            verts_by_link[name] = verts
    for src, dst in MERGED_INTO.items():
        verts_by_link[dst] = np.vstack([verts_by_link[dst], verts_by_link[src]])

    # The figures are copied element by element from the file itself, so that they stay verbatim.
    root = ET.parse(official_urdf).getroot()
    out = [
        "<?xml version=\"1.0\"?>",
        "<!-- Generated by robots/unitree_g1/derive.py from Unitree's g1_29dof.urdf (unitree_ros d6f13aa,",
        "     robots/g1_description, BSD-3-Clause, see LICENSE). Figures are the official ones; visuals are",
        "     the official meshes, decimated; collisions are the project's own primitives sized from them.",
        "     Do not edit by hand. -->",
        f'<robot name="{root.get("name")}">',
        '  <material name="dark"><color rgba="0.2 0.2 0.2 1"/></material>',
        '  <material name="white"><color rgba="0.7 0.7 0.7 1"/></material>',
    ]
    for element in root:
        name = element.get("name", "")
        if element.tag == "link" and name not in DROPPED_LINKS:
            out.append(f'  <link name="{name}">')
            inertial = element.find("inertial")
            if inertial is not None:
                out.append(_xml(inertial, 2))
            if name in verts_by_link:
                bone_xyz = joint_xyz[BONES[name]] if name in BONES else None
                geom, xyz, rpy = primitive(name, verts_by_link[name], bone_xyz)
                origin = f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>'
                out.extend(visual_lines.get(name, []))
                out.append(f"    <collision>{origin}<geometry>{geom}</geometry></collision>")
            out.append("  </link>")
        elif element.tag == "joint" and _child_link(element) not in DROPPED_LINKS:
            out.append(_xml(element, 1))
    out.append("</robot>")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line: derive.py OFFICIAL_URDF --meshes MESHES_DIR > g1_29dof.urdf."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("official_urdf", type=Path)
    parser.add_argument("--meshes", type=Path, required=True, help="folder for the decimated visual meshes")
    args = parser.parse_args(argv)
    sys.stdout.write(derive(args.official_urdf.resolve(), args.meshes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
