"""The topic registry: every key of the wire contract, what travels on it, who writes and who reads it.

One table, `TOPICS`, and everything else is read from it: `Keys` builds the
paths, the sim serves it in `RobotInfo.keys`, services take their codecs'
message types from it (`topic.message`), and the protocol table in
docs/protocol.md is generated from it (`python -m zensim.schemas.generate`)
and checked by a test, so a topic added here without the docs fails CI.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

from .messages import (
    AdvanceReply,
    AppliedCommand,
    BridgeReport,
    CtlReply,
    Imu,
    JointState,
    JointTargets,
    KeyInfo,
    Message,
    ModeRequest,
    MotorCommand,
    Odometry,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    SimStatus,
    StepRequest,
    UnitreeStatus,
)

Kind = Literal["publication", "queryable", "liveliness"]
Scope = Literal["robot", "router"]

ROUTER_ROOT: Final = "zensim/@router"
"""Root of the keys that belong to a router, not to one robot: every robot's clients on that router see
them. `@router` is a verbatim chunk (zenoh matches it only by itself, never by `*` or `**`), and no
robot id can start with `@`, so these keys never mix with a robot's (`zensim/*/alive/*` does not see them)."""


@dataclass(frozen=True)
class Topic:
    """One key of the protocol.

    Args:
        key: the key under `zensim/{robot}/`; a `{placeholder}` chunk stands for one chunk.
        kind: publication, queryable or liveliness token.
        writer: who writes (or serves) it.
        reader: who reads it.
        rate: nominal rate, or `on demand`.
        message: the Struct on the wire (a queryable's request), or None for a payload that is not one.
        reply: a queryable's reply Struct.
        payload: what travels when it is not a Struct (`float`, `URDF text (application/xml)`).
        note: a few words the docs add after the message name.
        scope: `robot` (the key is under `zensim/{robot}/`) or `router` (under ROUTER_ROOT).
    """

    key: str
    kind: Kind
    writer: str
    reader: str
    rate: str
    message: type[Message] | None = None
    reply: type[Message] | None = None
    payload: str = ""
    note: str = ""
    scope: Scope = "robot"

    def full_key(self, root: str | None = None) -> str:
        """The whole key: under `root` (`zensim/g1`) for a robot's topic, under ROUTER_ROOT for the router's."""
        if self.scope == "router":
            return f"{ROUTER_ROOT}/{self.key}"
        if root is None:
            raise ValueError(f"{self.key!r} is a robot's key: name the robot's root")
        return f"{root}/{self.key}"

    def doc_key(self) -> str:
        """The key as the protocol table shows it (relative to `zensim/{robot}/`, or whole for the router's)."""
        return f"{ROUTER_ROOT}/{self.key}" if self.scope == "router" else self.key

    def wire_name(self) -> str:
        """The message as `RobotInfo.keys` names it: struct tags (`reset_request -> ctl_reply`) or the payload."""
        if self.message is None:
            return self.payload
        names = [_tag(self.message)] + ([_tag(self.reply)] if self.reply else [])
        return " -> ".join(names)

    def doc_name(self) -> str:
        """The message as the docs name it: class names (`ResetRequest -> CtlReply`) and the note."""
        if self.message is None:
            name = self.payload
        else:
            name = " -> ".join([self.message.__name__] + ([self.reply.__name__] if self.reply else []))
        return f"{name} {self.note}".strip()

    def info(self, root: str) -> KeyInfo:
        """This topic's row for `RobotInfo.keys`, with the full key under `root` (`zensim/g1`)."""
        return KeyInfo(key=self.full_key(root), kind=self.kind, message=self.wire_name(), writer=self.writer,
                       reader=self.reader, rate=self.rate)


def _tag(message: type[Message]) -> str:
    return message.__struct_config__.tag  # type: ignore[return-value]


# --- state: sim (and other services) -> anyone ------------------------------------
JOINTS: Final = Topic("state/joints", "publication", "sim", "anyone", "100 Hz default (`state_rate_hz`), sim time",
                      JointState)
ODOM: Final = Topic("state/odom", "publication", "sim", "anyone", "with `state/joints`", Odometry)
IMU: Final = Topic("state/imu", "publication", "sim", "anyone", "with `state/joints`", Imu)
SIM_STATUS: Final = Topic("state/sim", "publication", "sim", "anyone", "~10 Hz wall time (`status_rate_hz`)", SimStatus)
BRIDGE_TARGETS: Final = Topic("state/targets", "publication", "bridge", "viz (ghost), anyone",
                              "`targets_rate_hz`, default 30 Hz", JointTargets,
                              note="(all joints, as commanded after clamping and slew)")
UNITREE_STATUS: Final = Topic("state/unitree", "publication", "unitree (the Unitree DDS adapter, docs/unitree.md)",
                              "anyone", "`status_rate_hz`, default 2 Hz", UnitreeStatus)
# --- commands -------------------------------------------------------------------
MOTORS: Final = Topic("cmd/motors", "publication", "bridge, unitree, or any client (a policy)", "sim",
                      "any; latest wins at each physics step", MotorCommand)
JOINT_TARGETS: Final = Topic("cmd/joints", "publication", "sliders, any client", "bridge", "any; latest wins",
                             JointTargets)
JOINT_TARGET: Final = Topic("cmd/joint/{joint}", "publication", "any client", "bridge", "any; latest wins",
                            payload="float", note="(a bare number: JSON/text or msgpack)")
BRIDGE_REPORT: Final = Topic("report/bridge", "publication", "bridge", "anyone", "one per rejected or clamped input",
                             BridgeReport)
# --- control: queries the sim answers --------------------------------------------
CTL_RESET: Final = Topic("ctl/reset", "queryable", "any client", "sim", "on demand", ResetRequest, CtlReply)
CTL_PAUSE: Final = Topic("ctl/pause", "queryable", "any client", "sim", "on demand", PauseRequest, CtlReply)
CTL_RESUME: Final = Topic("ctl/resume", "queryable", "any client", "sim", "on demand", ResumeRequest, CtlReply)
CTL_STEP: Final = Topic("ctl/step", "queryable", "any client", "sim", "on demand, while paused", StepRequest, CtlReply,
                        note="(after the steps ran)")
CTL_MODE: Final = Topic("ctl/mode", "queryable", "any client", "sim", "on demand", ModeRequest, CtlReply)
CTL_ADVANCE: Final = Topic("ctl/advance", "queryable", "any client (a controller)", "sim",
                           "on demand, under `clock: lockstep`", MotorCommand, AdvanceReply,
                           note="(after the steps ran)")
APPLIED: Final = Topic("state/applied", "publication", "sim", "anyone (the recorder, resim)",
                       "one per lockstep advance", AppliedCommand)
# --- description ------------------------------------------------------------------
ROBOT_INFO: Final = Topic("info/robot", "queryable", "sim", "anyone", "on demand", RobotInfo,
                          note="(JSON for `?format=json` or a JSON query payload)")
URDF: Final = Topic("info/urdf", "queryable", "sim", "anyone", "on demand", payload="URDF text (application/xml)")
MESH: Final = Topic("info/mesh/{path}", "queryable", "sim", "anyone", "on demand",
                    payload="mesh bytes (application/octet-stream)")
ALIVE: Final = Topic("alive/{service}", "liveliness", "each service: sim, bridge, viz, router, unitree", "anyone",
                     "while running", payload="token")
ROUTER_ALIVE: Final = Topic("alive", "liveliness", "router (one token whatever its `--robot-id`)",
                            "viz (the router badge of every robot), anyone", "while running", payload="token",
                            note="(the router serves every robot: its `alive/router` names only its own robot id)",
                            scope="router")

TOPICS: Final[tuple[Topic, ...]] = (
    JOINTS, ODOM, IMU, SIM_STATUS, BRIDGE_TARGETS, UNITREE_STATUS,
    MOTORS, JOINT_TARGETS, JOINT_TARGET, BRIDGE_REPORT,
    CTL_RESET, CTL_PAUSE, CTL_RESUME, CTL_STEP, CTL_MODE, CTL_ADVANCE, APPLIED,
    ROBOT_INFO, URDF, MESH, ALIVE, ROUTER_ALIVE,
)
"""Every topic, in the order the docs list them."""


def protocol_table() -> str:
    """The Markdown protocol table of docs/protocol.md, rendered from `TOPICS`."""
    rows = ["| key (under `zensim/{robot}/` unless whole) | kind | message | writer | reader | rate |",
            "|---|---|---|---|---|---|"]
    for topic in TOPICS:
        rows.append(f"| `{topic.doc_key()}` | {topic.kind} | {topic.doc_name()} | {topic.writer} | {topic.reader} | {topic.rate} |")
    return "\n".join(rows) + "\n"
