"""The sim serves only mesh files inside the description's own folder tree: a URDF naming anything else
fails at load, naming the file (the builder and the real `zensim sim` process)."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

from zensim.robots import robot_files
from zensim.robots.builder import RobotModelError, build

ARM = """<robot name="mesh_arm">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="{mesh}"/></geometry></visual>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="upper"><inertial><origin xyz="0 0 0.15"/><mass value="0.5"/><inertia ixx="0.004" iyy="0.004" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="20" velocity="5"/></joint>
</robot>
"""


def tetra_stl() -> bytes:
    """A binary STL tetrahedron: a real mesh MuJoCo compiles."""
    v = [(0, 0, 0), (0.05, 0, 0), (0, 0.05, 0), (0, 0, 0.05)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    body = b"".join(struct.pack("<12fH", 0, 0, 0, *v[a], *v[b], *v[c], 0) for a, b, c in faces)
    return b"\0" * 80 + struct.pack("<I", len(faces)) + body


def description(folder: Path, mesh: str) -> Path:
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    (folder / "meshes" / "base.stl").write_bytes(tetra_stl())
    urdf = folder / "arm.urdf"
    urdf.write_text(ARM.format(mesh=mesh))
    return urdf


def test_a_mesh_inside_the_folder_loads(tmp_path: Path) -> None:
    robot = build(robot_files(urdf=description(tmp_path, "meshes/base.stl")), "fixed")
    assert list(robot.mesh_files.values()) == [(tmp_path / "meshes" / "base.stl").resolve()]


def escapes(tmp_path: Path) -> list[tuple[str, str]]:
    """(mesh filename, words the error must hold) for each way out of the folder."""
    up = "../" * len(tmp_path.resolve().parts)
    (tmp_path / "meshes").mkdir(parents=True, exist_ok=True)
    (tmp_path / "meshes" / "out.stl").symlink_to("/etc/hostname")
    (tmp_path / "notes.txt").write_text("not a mesh")
    return [
        (f"{up}etc/passwd", "outside"),
        ("file:///etc/hostname", "outside"),
        ("meshes/out.stl", "outside"),
        ("notes.txt", "not a mesh file type"),
    ]


@pytest.mark.parametrize("case", range(4))
def test_anything_else_fails_at_load_naming_the_file(tmp_path: Path, case: int) -> None:
    mesh, words = escapes(tmp_path)[case]
    urdf = description(tmp_path, mesh)
    with pytest.raises(RobotModelError) as error:
        build(robot_files(urdf=urdf), "fixed")
    assert repr(mesh) in str(error.value) and words in str(error.value)


def test_the_sim_refuses_to_start_with_such_a_urdf(tmp_path: Path) -> None:
    urdf = description(tmp_path, "file:///etc/hostname")
    done = subprocess.run([sys.executable, "-m", "zensim", "sim", "--urdf", str(urdf), "--zenoh-mode", "client",
                           "--zenoh-connect", "tcp/127.0.0.1:1"], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert "file:///etc/hostname" in done.stderr and "outside" in done.stderr, done.stderr[-2000:]


def test_the_viz_does_not_send_such_a_mesh_to_browsers(tmp_path: Path, start_service) -> None:  # noqa: ANN001
    from support import free_port, wait_for

    urdf = description(tmp_path, "file:///etc/hostname")
    viz = start_service("viz", "--urdf", str(urdf), "--port", str(free_port()))
    wait_for(lambda: "description of" in viz.log() or not viz.alive(), 60, "the viz to draw the local URDF")
    assert viz.alive(), viz.log()
    assert "not sent to browsers: mesh 'file:///etc/hostname'" in viz.log()


@pytest.mark.parametrize("swap", ["file-for-symlink", "folder-for-symlink"])
def test_a_mesh_swapped_for_a_symlink_after_load_is_not_read(tmp_path: Path, swap: str) -> None:
    """Bounds are checked at load; read_mesh (what serving a mesh reads through) refuses a listed mesh that
    was replaced afterwards by a symlink, or whose folder was, so it never serves another file."""
    from zensim.robots.mesh_files import read_mesh, resolve_mesh

    urdf = description(tmp_path / "robot", "meshes/base.stl")
    resolved = resolve_mesh("meshes/base.stl", urdf.parent)
    assert read_mesh(resolved) == tetra_stl()
    secret = tmp_path / "secret.stl"
    secret.write_bytes(b"not yours")
    if swap == "file-for-symlink":
        resolved.unlink()
        resolved.symlink_to(secret)
    else:
        moved = resolved.parent.rename(tmp_path / "elsewhere")
        (tmp_path / "elsewhere-link").mkdir()
        (tmp_path / "elsewhere-link" / "base.stl").write_bytes(b"not yours either")  # a plain file, elsewhere
        resolved.parent.symlink_to(tmp_path / "elsewhere-link")
        assert moved.exists()
    with pytest.raises(OSError):
        read_mesh(resolved)
