"""A robot's description over zenoh, for scene.build_drawing: info/robot, info/urdf and the meshes it names.

Every reply is capped before it is read (the getter's `cap_bytes`, from schemas.bounds). A mesh the
URDF names that RobotInfo.mesh_paths does not list is not drawn: the sim would not serve it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Final

from zensim.robots.description import Description
from zensim.schemas import Codec, Keys, RobotInfo
from zensim.schemas.bounds import DESCRIPTION_CAP_BYTES, INFO_CAP_BYTES

from . import scene

logger = logging.getLogger(__name__)

Getter = Callable[[str, int], bytes]
"""One zenoh get: (key, cap in bytes) -> the first good reply's payload.
Raises TimeoutError (no reply) or ValueError (an error reply, a reply over the cap)."""

INFO_CODEC: Final = Codec(RobotInfo)


def robot_info(get: Getter, keys: Keys) -> RobotInfo:
    """The robot's info/robot."""
    return INFO_CODEC.decode(get(keys.robot_info, INFO_CAP_BYTES))


def urdf(get: Getter, keys: Keys) -> bytes:
    """The robot's info/urdf, as served (parse it with robots.description.parse_urdf)."""
    return get(keys.urdf, DESCRIPTION_CAP_BYTES)


def meshes(get: Getter, keys: Keys, robot: Description, info: RobotInfo) -> dict[str, bytes]:
    """Mesh bytes by URDF filename, for every visual mesh of `robot` the sim serves."""
    found: dict[str, bytes] = {}
    for filename in scene.visual_mesh_filenames(robot):
        served = scene.match_mesh(filename, info.mesh_paths)
        if served is None:
            logger.warning("mesh %s is not among RobotInfo.mesh_paths: not drawn", filename)
            continue
        found[filename] = get(keys.mesh(served), DESCRIPTION_CAP_BYTES)
    return found
