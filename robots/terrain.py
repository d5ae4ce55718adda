"""Terrain: a terrain file read and checked, its shapes worked out, and those shapes put into a MuJoCo model.

A terrain (schemas.messages.Terrain) lists features on the flat floor: slopes, stairs, rough ground,
stepping stones and boxes. `geometry` turns it into plain shapes (solid blocks, convex prisms, height
fields), the one description of what stands where: `add_to_spec` puts those shapes into the model once,
at build time, and the viewer draws the same shapes (services/viz/terrain.py). Nothing here runs per step.
What it costs per step is MuJoCo's collision pass and solver, so the model gets the cheapest form of the same
ground: each feature a static body of its own (not the world body), a slope two boxes where they make its
prism's solid above the floor (docs/benchmarks.md, "Terrain").

Rough ground is seeded with a hash of the seed and the grid point (splitmix64), not numpy's generators,
whose streams may change between numpy versions: the same seed gives the same ground on every machine.

A terrain file is TOML, `[[features]]` tables each with a `type` (services/sim/README.md). Unknown keys in
a file are refused (a typo must not silently make a feature flat), while the wire struct skips unknown
fields, as every wire struct does, so older readers survive newer writers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import msgspec
import mujoco
import numpy as np

from zensim.schemas.codec import short_repr
from zensim.schemas.messages import (
    MAX_TERRAIN_FEATURES,
    RoughGround,
    Slope,
    Stairs,
    SteppingStones,
    Terrain,
    TerrainBox,
    TerrainFeature,
)

if TYPE_CHECKING:  # builder imports this module; a Robot is only read here
    from zensim.robots.builder import Robot

__all__ = ["TERRAIN_GROUP", "TerrainError", "Block", "HeightField", "Prism", "Shapes", "add_to_spec", "geometry",
           "ground_geoms", "ground_under", "load_terrain", "terrain_from_table"]

TERRAIN_GROUP: Final = 3
"""MuJoCo geom group of the terrain's geoms: ray casts for the ground under a robot see only these."""
TERRAIN_RGBA: Final = (0.78, 0.62, 0.38, 1.0)
"""Sandy, so the terrain stands out from the grey floor and the robot."""
MAX_FILE_BYTES: Final = 1024 * 1024
"""A terrain file larger than this is refused before it is parsed."""
RAY_TOP_M: Final = 1000.0
"""Ground-finding rays start this high, above anything a terrain may hold."""
FOOTPRINT_RAYS: Final = 7
"""Rays per side of the grid cast over a robot's footprint."""
FEET_BAND_M: Final = 0.03
"""Collision geoms whose lowest point is within this of the robot's lowest point are its feet."""


class TerrainError(ValueError):
    """A terrain file or table that cannot be used: unreadable, malformed, an unknown key, an absurd value."""


# ------------------------------------------------------------------------------------------ reading
_TYPES: Final[dict[object, type[TerrainFeature]]] = {
    cls.__struct_config__.tag: cls for cls in (Slope, Stairs, RoughGround, SteppingStones, TerrainBox)}
"""Each feature's struct by its `type` (its msgspec tag)."""


def terrain_from_table(table: Any) -> Terrain:
    """A checked Terrain from a decoded TOML table (`features = [...]`), refused whole on any fault.

    Raises:
        TerrainError: one line naming the first fault (the feature's index and field).
    """
    if not isinstance(table, dict):
        raise TerrainError("a terrain is a table with a `features` list")
    unknown = sorted(set(table) - {"features"})
    if unknown:
        raise TerrainError(f"unknown key(s) {', '.join(map(short_repr, unknown[:3]))}; a terrain has only `features`")
    features = table.get("features", [])
    if not isinstance(features, list):
        raise TerrainError("`features` must be a list of tables ([[features]])")
    if len(features) > MAX_TERRAIN_FEATURES:  # before any feature is looked at
        raise TerrainError(f"{len(features)} features: a terrain has at most {MAX_TERRAIN_FEATURES}")
    for i, feature in enumerate(features):
        if not isinstance(feature, dict):
            raise TerrainError(f"features[{i}] must be a table")
        tag = feature.get("type")
        kind = _TYPES.get(tag) if isinstance(tag, str) else None  # a list or table is no `type` (nor hashable)
        if kind is None:
            known = ", ".join(map(str, _TYPES))
            raise TerrainError(f"features[{i}]: `type` must be one of {known}, got {short_repr(tag)}")
        extra = sorted(set(feature) - {"type", *kind.__struct_fields__})
        if extra:
            raise TerrainError(f"features[{i}] ({feature['type']}): unknown key(s) {', '.join(map(short_repr, extra[:3]))}")
    try:
        return msgspec.convert(table, Terrain)
    except msgspec.ValidationError as exc:
        raise TerrainError(str(exc)) from None


def load_terrain(path: str | Path) -> Terrain:
    """Read and check a terrain file (TOML).

    Raises:
        TerrainError: unreadable, too large, not TOML, or not a valid terrain (one line).
    """
    path = Path(path).expanduser()
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise TerrainError(f"{path} is {size} bytes: a terrain file is at most {MAX_FILE_BYTES}")
        table = msgspec.toml.decode(path.read_bytes())
    except OSError as exc:
        raise TerrainError(f"cannot read {path}: {exc.strerror or exc}") from None
    except msgspec.DecodeError as exc:
        raise TerrainError(f"{path} is not TOML: {exc}") from None
    return terrain_from_table(table)


# ----------------------------------------------------------------------------------------- shapes
@dataclass(frozen=True)
class Block:
    """A solid box: centre (m, world), half sizes (m), orientation (w, x, y, z)."""

    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]


@dataclass(frozen=True)
class Prism:
    """A convex solid (a slope): its vertices (n x 3, m, world) and triangles (m x 3 vertex indices, outward)."""

    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class HeightField:
    """A grid of heights: centre (m, world x, y), half extents (m), heights (rows along y, columns along x, m)."""

    centre: tuple[float, float]
    half: tuple[float, float]
    heights: np.ndarray


@dataclass(frozen=True)
class Shapes:
    """Everything a terrain puts on the floor."""

    blocks: list[Block]
    prisms: list[Prism]
    fields: list[HeightField]


def _yaw_quat(yaw_rad: float) -> tuple[float, float, float, float]:
    return (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))


def _along(at: tuple[float, float], yaw_rad: float, s: float, lateral: float = 0.0) -> tuple[float, float]:
    """The world x, y at `s` along the heading from `at` and `lateral` to its left."""
    c, n = math.cos(yaw_rad), math.sin(yaw_rad)
    return at[0] + s * c - lateral * n, at[1] + s * n + lateral * c


def _run_block(at: tuple[float, float], yaw_rad: float, s0: float, s1: float, width: float, top: float) -> Block:
    """A block from the floor up to `top`, from `s0` to `s1` along the heading, `width` across it."""
    x, y = _along(at, yaw_rad, (s0 + s1) / 2)
    return Block((x, y, top / 2), ((s1 - s0) / 2, width / 2, top / 2), _yaw_quat(yaw_rad))


def _stairs(f: Stairs) -> list[Block]:
    yaw, h, d = math.radians(f.direction_deg), f.step_height_m, f.step_depth_m
    if f.way == "up":  # step k (0-based) is k+1 rises high; the landing follows the last
        runs = [(k * d, (k + 1) * d, (k + 1) * h) for k in range(f.count - 1)]
        runs.append(((f.count - 1) * d, f.count * d + f.landing_m, f.count * h))
    else:  # the landing, then count - 1 steps down; the floor is the last rise's foot
        runs = [(0.0, f.landing_m + d, f.count * h)]
        runs += [(f.landing_m + k * d, f.landing_m + (k + 1) * d, (f.count - k) * h) for k in range(1, f.count)]
    return [_run_block(f.at, yaw, s0, s1, f.width_m, top) for s0, s1, top in runs]


def _stones(f: SteppingStones) -> list[Block]:
    yaw, side, pitch = math.radians(f.direction_deg), f.stone_m, f.stone_m + f.gap_m
    across = f.columns * side + (f.columns - 1) * f.gap_m
    blocks = []
    for row in range(f.rows):
        for col in range(f.columns):
            x, y = _along(f.at, yaw, row * pitch + side / 2, -across / 2 + col * pitch + side / 2)
            blocks.append(Block((x, y, f.height_m / 2), (side / 2, side / 2, f.height_m / 2), _yaw_quat(yaw)))
    return blocks


def _box(f: TerrainBox) -> Block:
    roll, pitch, yaw = (math.radians(a) / 2 for a in f.rpy_deg)
    # R = Rz(yaw) Ry(pitch) Rx(roll): roll first, about the world's axes.
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    quat = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)
    return Block(f.pos, tuple(s / 2 for s in f.size_m), quat)  # type: ignore[arg-type]


def _slope(f: Slope) -> Prism:
    """The incline and its top as one convex prism: foot at s = 0, a vertical wall at its far end."""
    yaw = math.radians(f.direction_deg)
    rise = f.length_m * math.tan(math.radians(f.angle_deg))
    end = f.length_m + f.top_m
    section = [(0.0, 0.0), (end, 0.0), (end, rise), (f.length_m, rise)]  # (s, z), counter-clockwise seen from the left
    if f.top_m == 0:
        section.pop(2)  # the incline's top edge meets the wall: a triangle
    vertices = []
    for lateral in (-f.width_m / 2, f.width_m / 2):
        for s, z in section:
            vertices.append((*_along(f.at, yaw, s, lateral), z))
    n = len(section)
    faces = []
    for i in range(1, n - 1):  # the two ends: the right side (lateral -), then the left, wound the other way
        faces.append((0, i + 1, i))
        faces.append((n, n + i, n + i + 1))
    for i in range(n):  # the sides around the section
        j = (i + 1) % n
        faces += [(i, j, n + j), (i, n + j, n + i)]
    return Prism(np.array(vertices, float), np.array(faces, np.int32))


def _slope_blocks(f: Slope) -> list[Block] | None:
    """The slope as two boxes, when they make the same solid above the floor as its prism; else None.

    The incline is a box tilted by the slope's angle whose top face is the incline, deep enough to reach below
    the floor everywhere; the top is a box from the incline's crest. The tilted box's far end leans outward
    (a wedge rise * tan(angle) long at the floor) and the top box covers it only when top_m is at least that
    long: a shorter top keeps the prism. Why boxes: MuJoCo collides a box with a box analytically, and a box
    with a convex mesh (the prism) by iterating (GJK/EPA, several times over for the several contacts of a flat
    foot): a G1 standing on a slope took 3-4 us a step more on the mesh (benchmarks/terrain.py).
    """
    angle, yaw = math.radians(f.angle_deg), math.radians(f.direction_deg)
    rise = f.length_m * math.tan(angle)
    if f.top_m < rise * math.tan(angle):
        return None
    depth = rise / math.cos(angle) + SLOPE_BASE_M  # the far end's bottom edge below the floor
    s = f.length_m / 2 + depth / 2 * math.sin(angle)  # the box's centre: the incline's middle, down its normal
    x, y = _along(f.at, yaw, s)
    # Yaw about z, then the tilt about the box's lateral axis (y), its x axis rising along the incline.
    cy, sy, ca, sa = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(angle / 2), math.sin(angle / 2)
    incline = Block((x, y, rise / 2 - depth / 2 * math.cos(angle)),
                    (f.length_m / math.cos(angle) / 2, f.width_m / 2, depth / 2), (cy * ca, sy * sa, -cy * sa, sy * ca))
    if f.top_m == 0:
        return [incline]
    return [incline, _run_block(f.at, yaw, f.length_m, f.length_m + f.top_m, f.width_m, rise)]


_MASK64: Final = (1 << 64) - 1


def rough_heights(f: RoughGround) -> np.ndarray:
    """Heights of a rough patch's grid points, m: rows along y, columns along x; the border at 0.

    Each inner point is amplitude_m * u, u in [0, 1) from splitmix64 of (seed, row, column): the same seed
    gives the same heights on every machine and numpy version.
    """
    nx, ny = f.cells()
    rows, cols = np.meshgrid(np.arange(ny + 1, dtype=np.uint64), np.arange(nx + 1, dtype=np.uint64), indexing="ij")
    seed = np.uint64(f.seed & _MASK64)
    with np.errstate(over="ignore"):
        z = seed + (rows << np.uint64(32)) + cols + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    u = (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)
    heights = f.amplitude_m * u
    heights[0, :] = heights[-1, :] = heights[:, 0] = heights[:, -1] = 0.0
    return heights


def geometry(terrain: Terrain) -> Shapes:
    """The shapes a terrain puts on the floor, in the order of its features."""
    shapes = Shapes([], [], [])
    for f in terrain.features:
        if isinstance(f, Stairs):
            shapes.blocks.extend(_stairs(f))
        elif isinstance(f, SteppingStones):
            shapes.blocks.extend(_stones(f))
        elif isinstance(f, TerrainBox):
            shapes.blocks.append(_box(f))
        elif isinstance(f, Slope):
            shapes.prisms.append(_slope(f))
        elif isinstance(f, RoughGround):
            shapes.fields.append(HeightField(f.at, (f.size_m[0] / 2, f.size_m[1] / 2), rough_heights(f)))
    return shapes


# ------------------------------------------------------------------------------------------ model
HFIELD_BASE_M: Final = 0.1
"""Depth of a height field's solid base below the floor, m (MuJoCo needs one)."""
SLOPE_BASE_M: Final = 0.1
"""How far below the floor a slope's tilted box reaches at its deepest edge, m."""


def add_to_spec(spec: mujoco.MjSpec, terrain: Terrain, contype: int, conaffinity: int, friction: list[float]) -> None:
    """Add the terrain's shapes to `spec`, colliding as the floor does (same contact bits and friction). Each
    feature is a static body, terrain_{k} (a child of the world, no joint), holding its shapes' geoms:
    terrain_block_{i}, terrain_slope_{i}, terrain_rough_{i}, numbered over the whole terrain. A slope whose top
    covers its tilted box's far end goes in as two blocks (`_slope_blocks`), the same solid above the floor.

    Not in the world body: MuJoCo's broadphase pairs the world body's geoms with every body of every robot at
    every step, whatever the distance (they are meant for floors), while a body of its own is paired only with
    the bodies whose bounding boxes reach it. In the world body a course beside the robot cost 10-25 % of the
    G1's step for nothing (benchmarks/terrain.py, docs/benchmarks.md); the contacts are the same either way.
    One body per feature, not per shape: a body is one more box to sort in the broadphase at every step, and
    a flight of stairs or a field of stones is one place.
    """
    world = spec.worldbody
    common = dict(contype=contype, conaffinity=conaffinity, friction=friction, rgba=list(TERRAIN_RGBA),
                  group=TERRAIN_GROUP)
    blocks = prisms = fields = 0
    for k, feature in enumerate(terrain.features):
        shapes = geometry(Terrain(features=(feature,)))
        as_blocks = _slope_blocks(feature) if isinstance(feature, Slope) else None
        if as_blocks is not None:  # the same solid above the floor, cheaper to collide with
            shapes = Shapes(as_blocks, [], [])
        body = world.add_body(name=f"terrain_{k}")
        for block in shapes.blocks:
            body.add_geom(name=f"terrain_block_{blocks}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=list(block.centre),
                          size=list(block.half), quat=list(block.quat_wxyz), **common)
            blocks += 1
        for prism in shapes.prisms:
            name = f"terrain_slope_{prisms}"
            spec.add_mesh(name=name, uservert=prism.vertices.flatten().tolist(),
                          userface=prism.faces.flatten().tolist())
            body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, **common)
            prisms += 1
        for field in shapes.fields:
            name = f"terrain_rough_{fields}"
            top = max(float(field.heights.max()), 1e-6)  # never 0: the data is divided by it
            rows, cols = field.heights.shape
            # MuJoCo scales the field's data (0..1) by size[2]: the highest point gives the scale.
            spec.add_hfield(name=name, size=[*field.half, top, HFIELD_BASE_M], nrow=rows, ncol=cols,
                            userdata=(field.heights / top).flatten().tolist())
            body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=name, pos=[*field.centre, 0.0],
                          **common)
            fields += 1


def ground_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Which geoms are the ground (the floor, in the world body, and the terrain's, in their static bodies)."""
    return (model.geom_bodyid == 0) | (model.geom_group == TERRAIN_GROUP)


def ground_at(model: mujoco.MjModel, data: mujoco.MjData, x: float, y: float) -> float:
    """Height of the terrain's top surface at world x, y (a MuJoCo ray cast down); 0 (the floor) where none."""
    geomgroup = np.zeros(6, np.uint8)
    geomgroup[TERRAIN_GROUP] = 1
    geomid = np.array([-1], np.int32)
    distance = mujoco.mj_ray(model, data, np.array([x, y, RAY_TOP_M]), np.array([0.0, 0.0, -1.0]), geomgroup, 1, -1,
                             geomid)
    return max(0.0, RAY_TOP_M - distance) if distance >= 0 else 0.0


def ground_under(robot: Robot) -> float:
    """The highest ground under the robot's feet at its spawn, m (0 on the flat floor).

    The feet are the collision geoms lowest in the default pose (within FEET_BAND_M); their bounding boxes'
    footprint, turned to the spawn heading and moved to the spawn x, y, is covered by a grid of ray casts,
    and the highest hit wins: the robot spawns with its lowest foot clear of everything under it.
    """
    model = robot.model
    if not np.any(model.geom_group == TERRAIN_GROUP):
        return 0.0
    data = mujoco.MjData(model)
    data.qpos[robot.qpos_adr] = robot.default_q
    mujoco.mj_kinematics(model, data)
    # Bounding-box corners of the robot's own geoms, relative to its base, in the default pose.
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    base = data.xpos[robot.base_body_id].copy()
    corners = []
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        if model.body_rootid[body] != robot.base_body_id:  # the floor, the terrain, another robot
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners.append(data.geom_xpos[g] - base + (centre + signs * half) @ data.geom_xmat[g].reshape(3, 3).T)
    if not corners:
        return 0.0
    lowest = min(float(c[:, 2].min()) for c in corners)
    feet = np.concatenate([c for c in corners if float(c[:, 2].min()) <= lowest + FEET_BAND_M])
    lo, hi = feet[:, :2].min(axis=0), feet[:, :2].max(axis=0)
    c, s = math.cos(robot.spawn_yaw_rad), math.sin(robot.spawn_yaw_rad)
    highest = 0.0
    for u in np.linspace(lo[0], hi[0], FOOTPRINT_RAYS):
        for v in np.linspace(lo[1], hi[1], FOOTPRINT_RAYS):
            x = robot.spawn_xy[0] + c * u - s * v
            y = robot.spawn_xy[1] + s * u + c * v
            highest = max(highest, ground_at(model, data, x, y))
    return highest
