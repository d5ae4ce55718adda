"""Where a robot description's mesh files are, and which it may name: mesh types inside its own folder tree.

Whatever a URDF names is served to any client (the sim's `info/mesh/...`, the viz's browsers), so a
description must not reach `/etc/passwd`, `file:///etc/hostname` or a symlink out of its folder.
The one resolver for mesh filenames: the builder and the viz (for a local --urdf) both use it.
No mujoco import here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from zensim.robots.description import RobotModelError

MESH_SUFFIXES: Final = frozenset({".stl", ".obj", ".dae", ".ply", ".msh", ".glb", ".gltf"})
"""File types a URDF mesh may have."""


def mesh_roots(filename: str, urdf_dir: Path) -> list[Path]:
    """The folders a mesh may come from: the URDF's own folder tree, and for `package://pkg/...` the
    `pkg` folder beside it (a ROS-style checkout)."""
    roots = [urdf_dir.resolve()]
    if filename.startswith("package://"):
        package = filename[len("package://"):].split("/", 1)[0]
        if package not in ("", ".", ".."):
            roots.append((urdf_dir.parent / package).resolve())
    return roots


def mesh_refusal(filename: str, path: Path, urdf_dir: Path) -> str | None:
    """Why the file `path` (found for the URDF's `filename`) must not be served, or None when it may be.

    Symlinks are followed before the check.
    """
    resolved = path.resolve()
    roots = mesh_roots(filename, urdf_dir)
    if not any(resolved.is_relative_to(root) for root in roots):
        return (f"mesh {filename!r} resolves to {resolved}, outside the description's folders "
                f"{[str(r) for r in roots]}; only files inside them are served")
    if resolved.suffix.lower() not in MESH_SUFFIXES:
        return f"mesh {filename!r} ({resolved}) is not a mesh file type ({', '.join(sorted(MESH_SUFFIXES))})"
    return None


def resolve_mesh(filename: str, urdf_dir: Path) -> Path:
    """Find a URDF mesh file relative to the URDF's own folder (never the working directory).

    Handles plain relative paths, `package://<pkg>/...` (the URDF's folder is taken as the package
    root, as in a g1_description checkout, or its parent as a ROS workspace) and `file://`, then
    `meshes/<name>` and `<name>` beside the URDF. The file found must pass `mesh_refusal`.

    Raises:
        FileNotFoundError: No candidate exists; the message lists where it looked.
        RobotModelError: The file is outside the description's folders or not a mesh type.
    """
    candidates: list[Path] = []
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        inner = rest.split("/", 1)[1] if "/" in rest else rest
        candidates += [urdf_dir / inner, urdf_dir.parent / rest]
    elif filename.startswith("file://"):
        candidates.append(Path(filename[len("file://"):]))
    else:
        candidates.append(urdf_dir / filename)
    candidates += [urdf_dir / "meshes" / Path(filename).name, urdf_dir / Path(filename).name]
    for candidate in candidates:
        if candidate.is_file():
            refusal = mesh_refusal(filename, candidate, urdf_dir)
            if refusal is not None:
                raise RobotModelError(refusal)
            return candidate.resolve()
    raise FileNotFoundError(f"mesh {filename!r} not found; looked at {[str(c) for c in candidates]}")


def read_mesh(resolved: Path) -> bytes:
    """The bytes of a mesh `resolve_mesh` found at load time, only if it is still that file.

    Bounds are checked when the description loads; a listed mesh swapped afterwards for a symlink
    (or a folder on its way for a link elsewhere) would otherwise serve any file the process can read.
    So the file is opened without following a final symlink, and the path the kernel actually opened
    must be the one checked at load.

    Raises:
        OSError: the file is gone, is now a symlink, or resolves somewhere else than at load.
    """
    import os

    fd = os.open(resolved, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        opened = Path(os.readlink(f"/proc/self/fd/{fd}")) if Path("/proc/self/fd").is_dir() else resolved.resolve()
        if opened != resolved:
            raise OSError(f"{resolved.name} now resolves to another file than the one checked at load")
        with os.fdopen(fd, "rb") as file:
            fd = -1
            return file.read()
    finally:
        if fd >= 0:
            os.close(fd)
