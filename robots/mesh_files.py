"""Which mesh files a robot description may name: mesh types inside its own folder tree.

Whatever a URDF names is served to any client (the sim's `info/mesh/...`, the viz's browsers), so a
description must not reach `/etc/passwd`, `file:///etc/hostname` or a symlink out of its folder.
No mujoco import: the viz checks its local meshes with this too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

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
