"""The viewer's world mode (`zensim viz --world lab`): every robot of a world in one scene.

The world's `world/info` (WorldInfo, served by `zensim sim --world`) names its robots; each robot's
description comes from its own info/robot, info/urdf and meshes (fetch.py), as for a robot alone.
Robots with the same URDF and mesh list (two G1s) share one description: its meshes are fetched once
and sent to the page once, and the page copies the first robot's shapes for the others (viz.js), so a
world of G1s costs the G1's 2.8 MB, not 2.8 MB a robot.

Each robot is drawn under `/robots/{id}` and its ghost under `/ghosts/{id}`, every link at its world
pose from the robot's own state/odom and state/joints: two G1s spawned a metre apart are drawn a
metre apart.

A reply is checked before anything is fetched for it: at most MAX_ROBOTS robots are shown (the rest
are left out, said on the page and in the log), every id must be a robot id, none may come twice and
there must be one (else the reply is refused), and everything fetched for one world is capped at
FETCH_BUDGET_BYTES.
"""

from __future__ import annotations

import hashlib
import math
import logging
from dataclasses import dataclass
from typing import Any, Final

from zensim.robots.description import Description, parse_urdf
from zensim.schemas import Codec, Keys, WorldInfo, WorldRobot, check_robot_id
from zensim.schemas.bounds import INFO_CAP_BYTES

from . import fetch, scene
from .terrain import terrain_commands

logger = logging.getLogger(__name__)

MAX_ROBOTS: Final = 64
"""Robots one viewer shows: each costs subscriptions, a pose per frame and its share of the page."""
FETCH_BUDGET_BYTES: Final = 256 * 1024 * 1024
"""Everything fetched for one world together (descriptions and meshes; shared ones count once)."""
WORLD_CODEC: Final = Codec(WorldInfo)


def roots(robot_id: str) -> tuple[str, str]:
    """Meshcat paths of a world robot's drawing and of its ghost."""
    return f"robots/{robot_id}", f"ghosts/{robot_id}"


@dataclass(frozen=True)
class WorldScene:
    """A world ready to draw: each robot's drawing in world order, the page's commands and its `robot` message."""

    drawings: list[tuple[str, scene.Drawing]]
    commands: list[bytes]
    meta: dict[str, Any]
    left_out: int
    """Robots of the world not shown (past MAX_ROBOTS)."""
    spawns: dict[str, tuple[float, float]]
    """Each robot's spawn place, x, y in m (where ghost_offsets keeps ghosts clear of neighbours)."""


def checked_robots(info: WorldInfo) -> tuple[list[WorldRobot], int]:
    """The robots of `info` to show, and how many are left out past MAX_ROBOTS.

    Raises:
        ValueError: no robot, an id that is not a robot id, or a robot named twice.
    """
    if not info.robots:
        raise ValueError("world/info lists no robot")  # a world file holds at least one
    seen: set[str] = set()
    for robot in info.robots:
        check_robot_id(robot.robot)  # the schema's pattern, and no trailing newline
        if robot.robot in seen:
            raise ValueError(f"world/info names robot {robot.robot!r} twice")
        seen.add(robot.robot)
    return list(info.robots[:MAX_ROBOTS]), max(0, len(info.robots) - MAX_ROBOTS)


def budgeted(get: fetch.Getter, budget_bytes: int) -> fetch.Getter:
    """`get`, refusing a reply past what is left of `budget_bytes` (all gets through it together)."""
    spent = 0

    def counted(key: str, cap_bytes: int) -> bytes:
        nonlocal spent
        left = budget_bytes - spent
        if left <= 0:
            raise ValueError(f"the world's descriptions passed {budget_bytes // 2**20} MB: not drawn")
        data = get(key, min(cap_bytes, left))
        spent += len(data)
        return data

    return counted


def fetch_world(get: fetch.Getter, world_id: str, ghost: bool) -> WorldScene:
    """world/info of `world_id`, then every robot's description (shared ones once), as one scene.

    Raises:
        TimeoutError: world/info or a robot's description did not answer.
        ValueError: a refused reply (malformed, another world's, a bad or repeated id, over a cap).
    """
    keys = Keys(world_id)
    get = budgeted(get, FETCH_BUDGET_BYTES)
    info = WORLD_CODEC.decode(get(keys.world_info, INFO_CAP_BYTES))
    if info.world != world_id:
        raise ValueError(f"{keys.world_info} answered for world {info.world!r}")
    robots, left_out = checked_robots(info)
    if left_out:
        logger.warning("world %s has %d robots: showing the first %d", world_id, len(info.robots), MAX_ROBOTS)
    # Description digest -> the first robot with it, its parsed URDF and its meshes.
    shared: dict[bytes, tuple[str, Description, dict[str, bytes]]] = {}
    drawings: list[tuple[str, scene.Drawing]] = []
    listed: list[dict[str, Any]] = []
    for robot in robots:
        robot_keys = Keys(robot.robot)
        robot_info = fetch.robot_info(get, robot_keys)
        urdf = fetch.urdf(get, robot_keys)
        digest = hashlib.sha256(urdf + b"\0" + "\0".join(robot_info.mesh_paths).encode()).digest()
        if digest not in shared:
            description = parse_urdf(urdf)
            shared[digest] = (robot.robot, description, fetch.meshes(get, robot_keys, description, robot_info))
        first, description, meshes = shared[digest]
        drawing = scene.build_drawing(
            description, meshes, joint_names=robot_info.joint_names, q_min=robot_info.q_min,
            q_max=robot_info.q_max, ghost=ghost, source=f"zenoh {robot_keys.urdf}", roots=roots(robot.robot),
            geometry=first == robot.robot)
        drawings.append((robot.robot, drawing))
        listed.append({"id": robot.robot, "name": drawing.meta["name"], "source": drawing.meta["source"],
                       "joints": drawing.meta["joints"], "roots": drawing.meta["roots"],
                       "copy_of": None if first == robot.robot else first, "xy": list(robot.xy), "mode": robot.mode})
    # The robots and ghosts of an earlier scene (a world that had other robots) go first.
    commands = [scene.pack_command({"type": "delete", "path": f"/{path}"}) for path in ("robots", "ghosts")]
    for _, drawing in drawings:
        commands += drawing.commands
    commands += terrain_commands(info.terrain)
    meta = {
        "name": world_id,
        "source": f"zenoh {keys.world_info}",
        "world": world_id,
        "robots": listed,
        "left_out": left_out,
        "paths": [path for _, drawing in drawings for path in drawing.meta["paths"]],
        "links": sum(len(drawing.kin.links) for _, drawing in drawings),
    }
    logger.info("world %s: %d robots, %d descriptions, %d meshes (%.0f kB)", world_id, len(drawings), len(shared),
                sum(len(m) for _, _, m in shared.values()),
                sum(len(b) for _, _, m in shared.values() for b in m.values()) / 1e3)
    return WorldScene(drawings, commands, meta, left_out, {robot.robot: (robot.xy[0], robot.xy[1]) for robot in robots})


GHOST_CLEARANCE_M: Final = 0.7
"""How far a ghost stands from every other robot's spawn place and every other ghost (a G1 is ~0.45 m wide)."""


def ghost_offsets(spawns: dict[str, tuple[float, float]], wanted: tuple[float, ...]) -> dict[str, tuple[float, float, float]]:
    """Where each robot's ghost stands relative to it: `wanted` (the --ghost-offset-m) where that is clear of
    the other robots and of the ghosts placed before, else the first clear of: `wanted` mirrored, turned a
    quarter either way; else over the robot itself (0, 0, 0), which never lands on a neighbour.

    Judged at the spawn places: robots that walk may meet their neighbours' ghosts later, as they may meet
    the neighbours.
    """
    x, y, z = (tuple(wanted) + (0.0, 0.0, 0.0))[:3]
    candidates = [(x, y, z), (x, -y, z), (y, x, z), (-y, -x, z)]
    placed: dict[str, tuple[float, float, float]] = {}
    ghosts: list[tuple[float, float]] = []
    for robot, (sx, sy) in spawns.items():
        others = [xy for other, xy in spawns.items() if other != robot] + ghosts
        choice = next((c for c in candidates
                       if all(math.hypot(sx + c[0] - ox, sy + c[1] - oy) >= GHOST_CLEARANCE_M for ox, oy in others)),
                      (0.0, 0.0, z))
        placed[robot] = choice
        ghosts.append((sx + choice[0], sy + choice[1]))
    return placed
