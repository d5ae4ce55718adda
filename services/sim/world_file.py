"""A world file: several robots in one MuJoCo world (`zensim sim --world lab.toml`), read and checked.

The file names the world's id (its own verbs live under zensim/{world}/world/) and, for each robot,
its id (its key root zensim/{id}/), its model (a bundled robot or any URDF), where it spawns and its
mode. World.of_file (world.py) builds them into one model.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import msgspec

from zensim.common.session import StartupError
from zensim.schemas import bounded
from zensim.schemas.keys import check_robot_id
from zensim.robots.terrain import terrain_from_table
from zensim.schemas.messages import Mode, Terrain


class RobotEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One `[[robots]]` table of a world file."""

    id: str
    """The robot's id: its key root is zensim/{id}/."""
    robot: str | None = None
    """A bundled robot (unitree_g1, alias g1); default unitree_g1 unless `urdf` is given."""
    urdf: str | None = None
    """Any URDF instead (meshes resolve beside it); a relative path is relative to the world file."""
    control: str | None = None
    """Its control file (default: the bundled robot's, else control.toml beside the URDF)."""
    xy: tuple[float, float] = (0.0, 0.0)
    """Spawn position of the base in the world, m."""
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360, le=360)] = 0.0
    """Spawn heading, degrees about the world's z (0 faces +x)."""
    mode: Mode | None = None
    """floating or fixed (welded on a stand at its spawn); default: --mode."""


class WorldFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A world file: `id` (the world's key root, default `world`) and its robots."""

    robots: Annotated[list[RobotEntry], msgspec.Meta(min_length=1, max_length=256)]
    id: str = "world"
    terrain: Terrain | None = None
    """The `[terrain]` table: the world's ground (robots/terrain.py); none: the flat floor."""


def read_world_file(path: str) -> WorldFile:
    """Parse and check a world file.

    Raises:
        StartupError: unreadable, malformed, unknown fields, duplicate or bad ids, non-finite spawns.
    """
    try:
        text = Path(path).read_bytes()
        world = msgspec.toml.decode(text, type=WorldFile)
        if world.terrain is not None:  # checked as a terrain file is: an unknown key in it is refused
            terrain_from_table(msgspec.toml.decode(text)["terrain"])
        ids = [world.id, *(entry.id for entry in world.robots)]
        for robot_id in ids:
            check_robot_id(robot_id)
        if len(set(ids)) != len(ids):
            raise ValueError(f"ids must be unique (the world's and its robots'): {ids}")
        for entry in world.robots:
            if not all(math.isfinite(v) and abs(v) <= 1e4 for v in entry.xy):
                raise ValueError(f"robot {entry.id}: xy must be finite and within 10 km")
    except (OSError, ValueError, msgspec.DecodeError, RecursionError) as exc:  # RecursionError: nested too deeply
        raise StartupError(f"world file {path} (--world / ZENSIM_SIM_WORLD): {bounded(str(exc), 400)}") from None
    return world


