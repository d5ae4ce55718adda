"""Zenoh key expressions of the wire contract, and the protocol table.

Every key lives under `zensim/{robot}`. Services build keys only through
`Keys`, never as string literals, so the table below is the one place that
says what travels where. docs/protocol.md renders the same table and a test
keeps the two in step.
"""

from __future__ import annotations

import re
from typing import Final

from .messages import KeyInfo

ROOT: Final = "zensim"
DEFAULT_ROBOT_ID: Final = "g1"
ROBOT_ID_PATTERN: Final = re.compile(r"[a-z0-9_-]+")
SERVICES: Final = ("router", "sim", "bridge", "viz", "unitree")
"""Every service that declares `alive/{service}`; `zensim up` starts the first four in this order (the
unitree adapter in place of the bridge with `--unitree`)."""

CTL_VERBS: Final = ("reset", "pause", "resume", "step", "mode", "advance")


def check_robot_id(robot: str) -> str:
    """Return `robot` if it is a valid `{robot}` chunk, else raise ValueError."""
    if not ROBOT_ID_PATTERN.fullmatch(robot):
        raise ValueError(f"robot id {robot!r} must match [a-z0-9_-]+")
    return robot


class Keys:
    """The key expressions of one robot.

    Args:
        robot: the robot id, the `{robot}` chunk (default `g1`).
    """

    def __init__(self, robot: str = DEFAULT_ROBOT_ID) -> None:
        self.robot = check_robot_id(robot)
        self.root = f"{ROOT}/{robot}"
        self.joints = f"{self.root}/state/joints"
        self.odom = f"{self.root}/state/odom"
        self.imu = f"{self.root}/state/imu"
        self.sim_status = f"{self.root}/state/sim"
        self.motors = f"{self.root}/cmd/motors"
        self.joint_targets = f"{self.root}/cmd/joints"
        self.joint_target_any = f"{self.root}/cmd/joint/*"
        self.bridge_targets = f"{self.root}/state/targets"
        self.bridge_report = f"{self.root}/report/bridge"
        self.robot_info = f"{self.root}/info/robot"
        self.urdf = f"{self.root}/info/urdf"
        self.mesh_any = f"{self.root}/info/mesh/**"
        self.alive_any = f"{self.root}/alive/*"
        self.unitree_status = f"{self.root}/state/unitree"
        self.applied = f"{self.root}/state/applied"
        self.everything = f"{self.root}/**"

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
        return f"{self.root}/ctl/{verb}"

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

    def table(self) -> tuple[KeyInfo, ...]:
        """The protocol table for this robot (served in RobotInfo.keys)."""
        return tuple(
            KeyInfo(key=f"{self.root}/{row.key}", kind=row.kind, message=row.message,
                    writer=row.writer, reader=row.reader, rate=row.rate)
            for row in KEY_TABLE
        )


def mesh_key_path(filename: str) -> str:
    """The part of a URDF mesh filename that goes into an `info/mesh/{path}` key."""
    path = filename.split("://", 1)[-1].lstrip("/")
    return "/".join(chunk for chunk in path.split("/") if chunk)


def _row(key: str, kind: str, message: str, writer: str, reader: str, rate: str) -> KeyInfo:
    return KeyInfo(key=key, kind=kind, message=message, writer=writer, reader=reader, rate=rate)  # type: ignore[arg-type]


KEY_TABLE: Final[tuple[KeyInfo, ...]] = (
    _row("state/joints", "publication", "joint_state", "sim", "anyone", "100 Hz (state_rate_hz)"),
    _row("state/odom", "publication", "odometry", "sim", "anyone", "100 Hz (state_rate_hz)"),
    _row("state/imu", "publication", "imu", "sim", "anyone", "100 Hz (state_rate_hz)"),
    _row("state/sim", "publication", "sim_status", "sim", "anyone", "10 Hz"),
    _row("state/targets", "publication", "joint_targets", "bridge", "viz (ghost), anyone", "targets_rate_hz, default 30 Hz"),
    _row("cmd/motors", "publication", "motor_command", "bridge or any client (a policy)", "sim", "any; latest wins"),
    _row("cmd/joints", "publication", "joint_targets", "sliders, any client", "bridge", "any; latest wins"),
    _row("cmd/joint/{joint}", "publication", "float", "any client", "bridge", "any; latest wins"),
    _row("report/bridge", "publication", "bridge_report", "bridge", "anyone", "per rejected or clamped input"),
    _row("ctl/reset", "queryable", "reset_request -> ctl_reply", "any client", "sim", "on demand"),
    _row("ctl/pause", "queryable", "pause_request -> ctl_reply", "any client", "sim", "on demand"),
    _row("ctl/resume", "queryable", "resume_request -> ctl_reply", "any client", "sim", "on demand"),
    _row("ctl/step", "queryable", "step_request -> ctl_reply", "any client", "sim", "on demand"),
    _row("ctl/mode", "queryable", "mode_request -> ctl_reply", "any client", "sim", "on demand"),
    _row("info/robot", "queryable", "robot_info", "sim", "anyone", "on demand"),
    _row("info/urdf", "queryable", "URDF text (application/xml)", "sim", "anyone", "on demand"),
    _row("info/mesh/{path}", "queryable", "mesh bytes (application/octet-stream)", "sim", "anyone", "on demand"),
    _row("ctl/advance", "queryable", "motor_command -> advance_reply", "any client (a controller)", "sim", "on demand, clock lockstep"),
    _row("state/applied", "publication", "applied_command", "sim", "anyone (recorder, resim)", "one per lockstep advance"),
    _row("alive/{service}", "liveliness", "token", "each service (sim, bridge, viz)", "anyone", "while running"),
    _row("state/unitree", "publication", "unitree_status", "unitree", "anyone", "status_rate_hz, default 2 Hz"),
)
"""Keys relative to `zensim/{robot}`."""
