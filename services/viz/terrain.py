"""The terrain as meshcat geometry: the shapes the sim built into its model, drawn under `/terrain`.

The sim describes its terrain in info/robot (a world's in world/info) as the terrain file's features;
`zensim.robots.terrain.geometry` turns them into the very shapes the sim's model holds (blocks, slope
prisms, height fields), so the drawing and the physics cannot disagree. Blocks become meshcat boxes,
slopes and rough ground triangle meshes. Pure: no zenoh, no web server.
"""

from __future__ import annotations

from typing import Final

import meshcat.commands as mc
import meshcat.geometry as mg
import numpy as np

from zensim.robots.terrain import TERRAIN_RGBA, HeightField, Prism, geometry
from zensim.schemas.messages import Terrain

from .scene import pack_command, quat_matrix

ROOT: Final = "terrain"
"""Meshcat path of the drawing: the page may hide it with set_property(['terrain'], 'visible', false)."""


def _color() -> int:
    r, g, b = (int(round(c * 255)) for c in TERRAIN_RGBA[:3])
    return (r << 16) | (g << 8) | b


def _matrix(centre: tuple[float, float, float], quat_wxyz: tuple[float, float, float, float]) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = quat_matrix(quat_wxyz)
    T[:3, 3] = centre
    return [float(x) for x in T.T.flatten()]  # column-major, as three.js reads it


def _prism_mesh(prism: Prism) -> mg.TriangularMeshGeometry:
    """A slope with a vertex per face corner, so each face is lit flat (shared vertices would smooth the edges)."""
    corners = prism.vertices[prism.faces].reshape(-1, 3)
    return mg.TriangularMeshGeometry(corners, np.arange(len(corners)).reshape(-1, 3))


def _field_mesh(field: HeightField) -> mg.TriangularMeshGeometry:
    """A height field's top surface: its grid points (rows along y, columns along x), two triangles per cell."""
    rows, cols = field.heights.shape
    ys = np.linspace(field.centre[1] - field.half[1], field.centre[1] + field.half[1], rows)
    xs = np.linspace(field.centre[0] - field.half[0], field.centre[0] + field.half[0], cols)
    gx, gy = np.meshgrid(xs, ys)
    vertices = np.stack([gx.ravel(), gy.ravel(), field.heights.ravel()], axis=1)
    corner = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([corner, corner + 1, corner + cols + 1], axis=1),
                            np.stack([corner, corner + cols + 1, corner + cols], axis=1)])
    return mg.TriangularMeshGeometry(vertices, faces)


def terrain_commands(terrain: Terrain | None) -> list[bytes]:
    """Packed meshcat commands that draw `terrain` under /terrain (only clear it when None: the flat floor)."""
    commands = [pack_command(mc.Delete(mc.Path((ROOT,))).lower())]
    if terrain is None:
        return commands
    shapes = geometry(terrain)
    material = mg.MeshPhongMaterial(color=_color())
    for i, block in enumerate(shapes.blocks):
        path = mc.Path((ROOT, f"block{i}"))
        commands.append(pack_command(mc.SetObject(mg.Box([2 * h for h in block.half]), material, path).lower()))
        commands.append(pack_command({"type": "set_transform", "path": path.lower(),
                                      "matrix": _matrix(block.centre, block.quat_wxyz)}))
    meshes = [(f"slope{i}", _prism_mesh(p)) for i, p in enumerate(shapes.prisms)]
    meshes += [(f"rough{i}", _field_mesh(f)) for i, f in enumerate(shapes.fields)]
    for name, mesh in meshes:
        commands.append(pack_command(mc.SetObject(mesh, material, mc.Path((ROOT, name))).lower()))
    return commands
