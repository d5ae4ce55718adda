"""Zenoh key expressions of the wire contract, and the protocol table.

Every key lives under `zensim/{robot}`. Services build keys only through
`Keys`, never as string literals. What travels on each key, who writes and who
reads it, is the topic registry in topics.py.
"""

from __future__ import annotations

import re
from typing import Final

from .messages import KeyInfo
from .topics import TOPICS, Topic

ROOT: Final = "zensim"
DEFAULT_ROBOT_ID: Final = "g1"
ROBOT_ID_PATTERN: Final = re.compile(r"[a-z0-9_-]+")
MAX_ROBOT_ID_CHARS: Final = 64
"""Longest robot id: it is a chunk of every key, written into every sample's key and every ACL rule (a
100 000-character id made zenoh itself panic, with a traceback, instead of a clear error)."""
SERVICES: Final = ("router", "sim", "bridge", "viz", "unitree", "ros1", "ros2", "loco")
"""Every service that declares `alive/{service}`, each a `zensim {service}` command with a role of its own;
`zensim up` and compose.yaml start those not optional, in this order. The one list of services: the rest
is derived from it or checked against it (tests/test_facts.py)."""
OPTIONAL_SERVICES: Final = ("unitree", "ros1", "ros2", "loco")
"""Started only when asked: `zensim up --unitree` (the adapter, with the walking controller in place of
the bridge), `--loco` (the walking controller in place of the bridge), `--ros1` (the ROS 1 gateway) or
`--ros2` (the ROS 2 face); compose profiles of the same names."""

CTL_VERBS: Final = tuple(t.key.split("/", 1)[1] for t in TOPICS if t.key.startswith("ctl/"))
"""The control queryables' verbs (`ctl/{verb}`), from the registry."""


def check_robot_id(robot: str) -> str:
    """Return `robot` if it is a valid `{robot}` chunk, else raise ValueError (its text bounded)."""
    if len(robot) > MAX_ROBOT_ID_CHARS:
        raise ValueError(f"robot id {robot[:20]!r}... has {len(robot)} characters: at most {MAX_ROBOT_ID_CHARS}")
    if not ROBOT_ID_PATTERN.fullmatch(robot):
        raise ValueError(f"robot id {robot!r} must match [a-z0-9_-]+")
    return robot


class Keys:
    """The key expressions of one robot.

    Args:
        robot: the robot id, the `{robot}` chunk (default `g1`).
    """

    # One attribute per topic of the registry, named by `Topic.name` and set from it in __init__: the
    # key is never written here (a placeholder becomes its wildcard). Declared for type checkers; a
    # check below this class fails at import when these names and the registry's disagree.
    joints: str
    odom: str
    imu: str
    contacts: str
    sim_status: str
    bridge_targets: str
    unitree_status: str
    ros1_status: str
    ros2_status: str
    motors: str
    joint_targets: str
    joint_target_any: str
    bridge_report: str
    ctl_reset: str
    ctl_pause: str
    ctl_resume: str
    ctl_step: str
    ctl_mode: str
    ctl_advance: str
    ctl_push: str
    ctl_band: str
    ctl_faults: str
    applied: str
    world_pause: str
    world_resume: str
    world_step: str
    world_reset: str
    world_advance: str
    world_info: str
    robot_info: str
    urdf: str
    mesh_any: str
    alive_any: str
    velocity: str
    arms: str
    ctl_loco: str
    loco_status: str
    remote: str
    claim_any: str

    def __init__(self, robot: str = DEFAULT_ROBOT_ID) -> None:
        self.robot = check_robot_id(robot)
        self.root = f"{ROOT}/{robot}"
        for topic in TOPICS:
            if topic.name:
                setattr(self, topic.name, f"{self.root}/{topic.pattern()}")
        self.everything = f"{self.root}/**"

    def of(self, topic: Topic) -> str:
        """The full key of a topic without placeholders (`state/joints` -> `zensim/g1/state/joints`)."""
        if "{" in topic.key:
            raise ValueError(f"{topic.key!r} has a placeholder: use the key's own builder")
        return f"{self.root}/{topic.key}"

    def joint_target(self, joint: str) -> str:
        """Key for one joint's bare-number target."""
        return f"{self.root}/cmd/joint/{joint}"

    def joint_from_target_key(self, key: str) -> str:
        """The joint name in a `cmd/joint/{joint}` key."""
        prefix = f"{self.root}/cmd/joint/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not a per-joint target key")
        return key[len(prefix) :]

    def ctl(self, verb: str) -> str:
        """Key of a control queryable (`reset`, `pause`, `resume`, `step`, `mode`)."""
        if verb not in CTL_VERBS:
            raise ValueError(f"unknown ctl verb {verb!r}; expected one of {CTL_VERBS}")
        return getattr(self, f"ctl_{verb}")

    def mesh(self, path: str) -> str:
        """Key serving the bytes of the mesh file `path`, written as the URDF names it.

        A `package://` or `file://` scheme and leading slashes are dropped: a
        key may not hold empty chunks (`//`).
        """
        return f"{self.root}/info/mesh/{mesh_key_path(path)}"

    def mesh_path(self, key: str) -> str:
        """The mesh path in an `info/mesh/{path}` key."""
        prefix = f"{self.root}/info/mesh/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not a mesh key")
        return key[len(prefix) :]

    def alive(self, service: str) -> str:
        """Liveliness token key of a service."""
        return f"{self.root}/alive/{service}"

    def claim(self, nonce: str) -> str:
        """Liveliness token key of one process's claim on this robot id (services/common/claim.py)."""
        return f"{self.root}/claim/{nonce}"

    def table(self) -> tuple[KeyInfo, ...]:
        """The protocol table for this robot (served in RobotInfo.keys), from the topic registry."""
        return tuple(topic.info(self.root) for topic in TOPICS)


_KEY_NAMES = {name for name, kind in Keys.__annotations__.items() if kind == "str"}
if _KEY_NAMES != {t.name for t in TOPICS if t.name}:
    raise RuntimeError(f"Keys' attributes and the topic registry's names differ (a named topic needs its "
                       f"annotation in Keys): {sorted(_KEY_NAMES ^ {t.name for t in TOPICS if t.name})}")


def mesh_key_path(filename: str) -> str:
    """The part of a URDF mesh filename that goes into an `info/mesh/{path}` key."""
    path = filename.split("://", 1)[-1].lstrip("/")
    return "/".join(chunk for chunk in path.split("/") if chunk)
