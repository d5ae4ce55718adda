"""The topic registry: every key of the wire contract, what travels on it, who writes and who reads it.

Two tables, and everything else is read from them:

- `TOPICS`, what travels: `Keys` builds its key attributes from it, the sim serves it in
  `RobotInfo.keys`, services take their codecs' message types from it (`topic.message`).
- `ROLES`, who may write and read which keys: one line per role (a service's own
  credentials, or a client's). The router's access rules (services/common/secure.py), the
  role table of docs/security.md and the key table of each service's README are generated
  from it, and tests/test_roles.py fails when a service declares anything its role lacks.

The docs' tables are generated (`python -m zensim.schemas.generate`) and checked by a test,
so a topic or role added here without the docs fails CI.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Generic, Literal, TypeVar

from .messages import (
    AdvanceReply,
    BandRequest,
    PushRequest,
    FaultsRequest,
    WorldAdvanceReply,
    WorldAdvanceRequest,
    WorldInfo,
    AppliedCommand,
    BridgeReport,
    Contacts,
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
    Ros1Status,
    Ros2Status,
    SimStatus,
    StepRequest,
    UnitreeStatus,
    VelocityCommand,
    ArmCommand,
    LocoRequest,
    LocoStatus,
    RemoteState,
)

Kind = Literal["publication", "queryable", "liveliness"]
M = TypeVar("M", bound=Message)
RoleKind = Literal["service", "client"]
Scope = Literal["robot", "router"]

ROUTER_ROOT: Final = "zensim/@router"
"""Root of the keys that belong to a router, not to one robot: every robot's clients on that router see
them. `@router` is a verbatim chunk (zenoh matches it only by itself, never by `*` or `**`), and no
robot id can start with `@`, so these keys never mix with a robot's (`zensim/*/alive/*` does not see them)."""


@dataclass(frozen=True)
class Topic(Generic[M]):
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
        name: the attribute of `Keys` that holds this topic's key expression (a placeholder becomes a
            wildcard: `cmd/joint/{joint}` -> `joint_target_any` = `.../cmd/joint/*`); empty: no
            attribute (use `Keys.of(topic)`).
        wildcard: what a placeholder becomes in that key expression: `*` (one chunk) or `**` (a path).
        scope: `robot` (the key is under `zensim/{robot}/`) or `router` (under ROUTER_ROOT).
    """

    key: str
    kind: Kind
    writer: str
    reader: str
    rate: str
    message: type[M] | None = None
    reply: type[Message] | None = None
    payload: str = ""
    note: str = ""
    name: str = ""
    wildcard: Literal["*", "**"] = "*"

    def pattern(self) -> str:
        """The key under `zensim/{robot}/` as a key expression: each placeholder made the wildcard."""
        return "/".join(self.wildcard if chunk.startswith("{") else chunk for chunk in self.key.split("/"))

    def message_type(self) -> type[M]:
        """The Struct on the wire; ValueError for a topic that carries none (a bare number, bytes, a token)."""
        if self.message is None:
            raise ValueError(f"{self.key} carries no message struct ({self.payload})")
        return self.message
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
                      JointState, name="joints")
ODOM: Final = Topic("state/odom", "publication", "sim", "anyone", "with `state/joints`", Odometry, name="odom")
IMU: Final = Topic("state/imu", "publication", "sim", "anyone", "with `state/joints`", Imu, name="imu")
CONTACTS: Final = Topic("state/contacts", "publication", "sim", "anyone (a contact estimator), unitree (foot_force)",
                        "with `state/joints` (the same `seq`)", Contacts,
                        note="(per foot link: in contact, normal force, force in the world frame)", name="contacts")
SIM_STATUS: Final = Topic("state/sim", "publication", "sim", "anyone", "~10 Hz wall time (`status_rate_hz`)", SimStatus, name="sim_status")
BRIDGE_TARGETS: Final = Topic("state/targets", "publication", "bridge", "viz (ghost), anyone",
                              "`targets_rate_hz`, default 30 Hz", JointTargets,
                              note="(all joints, as commanded after clamping and slew)", name="bridge_targets")
UNITREE_STATUS: Final = Topic("state/unitree", "publication", "unitree (the Unitree DDS adapter, docs/unitree.md)",
                              "anyone", "`status_rate_hz`, default 2 Hz", UnitreeStatus, name="unitree_status")
ROS1_STATUS: Final = Topic("state/ros1", "publication", "ros1 (the ROS 1 gateway, docs/ros.md)", "anyone",
                           "`status_rate_hz`, default 2 Hz", Ros1Status, name="ros1_status")
ROS2_STATUS: Final = Topic("state/ros2", "publication", "ros2 (the ROS 2 face, docs/ros.md)", "anyone",
                           "`status_rate_hz`, default 2 Hz", Ros2Status, name="ros2_status")
# --- commands -------------------------------------------------------------------
MOTORS: Final = Topic("cmd/motors", "publication", "bridge, unitree, or any client (a policy)", "sim",
                      "any; latest wins at each physics step", MotorCommand, name="motors")
JOINT_TARGETS: Final = Topic("cmd/joints", "publication", "sliders, any client", "bridge", "any; latest wins",
                             JointTargets, name="joint_targets")
JOINT_TARGET: Final[Topic[Message]] = Topic("cmd/joint/{joint}", "publication", "any client", "bridge", "any; latest wins",
                            payload="float", note="(a bare number: JSON/text or msgpack)", name="joint_target_any")
BRIDGE_REPORT: Final = Topic("report/bridge", "publication", "bridge", "anyone", "one per rejected or clamped input",
                             BridgeReport, name="bridge_report")
# --- control: queries the sim answers --------------------------------------------
CTL_RESET: Final = Topic("ctl/reset", "queryable", "any client", "sim", "on demand", ResetRequest, CtlReply, name="ctl_reset")
CTL_PAUSE: Final = Topic("ctl/pause", "queryable", "any client", "sim", "on demand", PauseRequest, CtlReply, name="ctl_pause")
CTL_RESUME: Final = Topic("ctl/resume", "queryable", "any client", "sim", "on demand", ResumeRequest, CtlReply, name="ctl_resume")
CTL_STEP: Final = Topic("ctl/step", "queryable", "any client", "sim", "on demand, while paused", StepRequest, CtlReply,
                        note="(after the steps ran)", name="ctl_step")
CTL_MODE: Final = Topic("ctl/mode", "queryable", "any client", "sim", "on demand", ModeRequest, CtlReply, name="ctl_mode")
CTL_ADVANCE: Final = Topic("ctl/advance", "queryable", "any client (a controller)", "sim",
                           "on demand, under `clock: lockstep`", MotorCommand, AdvanceReply,
                           note="(after the steps ran)", name="ctl_advance")
CTL_PUSH: Final = Topic("ctl/push", "queryable", "any client (an operator, a test bench)", "sim", "on demand",
                        PushRequest, CtlReply, note="(a force on a body for a while; `push` says what was applied)",
                        name="ctl_push")
CTL_BAND: Final = Topic("ctl/band", "queryable", "any client (an operator, a test bench)", "sim", "on demand",
                        BandRequest, CtlReply, note="(the elastic band: on, off, lower, raise, a length; `band` says "
                                                    "its state)", name="ctl_band")
CTL_FAULTS: Final = Topic("ctl/faults", "queryable", "any client (an operator, a test bench)", "sim", "on demand",
                          FaultsRequest, CtlReply, note="(faults on demand: weak, locked, limp joints, encoder "
                                                        "offsets, sensor noise and bias, command delay and drops; `faults` says "
                                                        "what is active)",
                          name="ctl_faults")
WORLD_NOTE: Final = "(a world of several robots, `zensim sim --world`: `{robot}` is the world's id)"
WORLD_PAUSE: Final = Topic("world/pause", "queryable", "any client", "sim (a world)", "on demand", PauseRequest, CtlReply,
                           note=WORLD_NOTE, name="world_pause")
WORLD_RESUME: Final = Topic("world/resume", "queryable", "any client", "sim (a world)", "on demand", ResumeRequest,
                            CtlReply, note=WORLD_NOTE, name="world_resume")
WORLD_STEP: Final = Topic("world/step", "queryable", "any client", "sim (a world)", "on demand, while paused",
                          StepRequest, CtlReply, note=WORLD_NOTE, name="world_step")
WORLD_ADVANCE: Final = Topic("world/advance", "queryable", "any client (a controller of several robots)",
                             "sim (a world, `--clock lockstep`)", "on demand", WorldAdvanceRequest, WorldAdvanceReply,
                             note="(`{robot}` is the world's id: any of its robots' commands; or one robot's id in "
                                  "a world: that robot's command alone, an entry for another refuses the request, "
                                  "that robot's states back; docs/security.md)", name="world_advance")
WORLD_RESET: Final = Topic("world/reset", "queryable", "any client", "sim (a world)", "on demand", ResetRequest,
                           CtlReply, note="(every robot to its default pose, world time to 0: an empty request)",
                           name="world_reset")
WORLD_INFO: Final = Topic("world/info", "queryable", "sim (a world)", "viz (`--world`), anyone", "on demand", WorldInfo,
                         note="(its robots: ids, models, modes, spawn places; `{robot}` is the world's id; JSON for "
                              "`?format=json` or a JSON query payload)", name="world_info")
APPLIED: Final = Topic("state/applied", "publication", "sim", "anyone (the recorder, resim)",
                       "one per lockstep advance", AppliedCommand, name="applied")
# --- walking: `zensim loco` ---------------------------------------------------------
VELOCITY: Final = Topic("cmd/velocity", "publication", "any client, unitree (LocoClient), ros1 and ros2 (/cmd_vel), viz (keys, gamepad)",
                        "loco", "any; latest wins; lapses after `timeout_s` of sim time", VelocityCommand,
                        note="(vx, vy m/s, wz rad/s in the heading frame)", name="velocity")
ARMS: Final = Topic("cmd/arms", "publication", "unitree (rt/arm_sdk), any client", "loco", "any; the newest holds",
                    ArmCommand, note="(upper-body targets blended over the walking controller's)", name="arms")
CTL_LOCO: Final = Topic("ctl/loco", "queryable", "any client, unitree (the sport service)", "loco", "on demand",
                        LocoRequest, LocoStatus, note="(stand up, sit, damp, walk: the sport service's FSM)",
                        name="ctl_loco")
LOCO_STATUS: Final = Topic("state/loco", "publication", "loco (the walking controller, services/loco/README.md)",
                           "anyone (unitree, viz)", "`status_rate_hz`, default 10 Hz, and at each change",
                           LocoStatus, note="(FSM state, commanded and achieved velocity)", name="loco_status")
REMOTE: Final = Topic("cmd/remote", "publication", "viz (keys, gamepad), any client", "unitree (LowState_.wireless_remote)",
                      "any; the newest holds", RemoteState, note="(Unitree's wireless remote: buttons, sticks)",
                      name="remote")
# --- description ------------------------------------------------------------------
ROBOT_INFO: Final = Topic("info/robot", "queryable", "sim", "anyone", "on demand", RobotInfo,
                          note="(JSON for `?format=json` or a JSON query payload)", name="robot_info")
URDF: Final[Topic[Message]] = Topic("info/urdf", "queryable", "sim", "anyone", "on demand", payload="URDF text (application/xml)", name="urdf")
MESH: Final[Topic[Message]] = Topic("info/mesh/{path}", "queryable", "sim", "anyone", "on demand",
                    payload="mesh bytes (application/octet-stream)", name="mesh_any", wildcard="**")
ALIVE: Final[Topic[Message]] = Topic("alive/{service}", "liveliness", "each service: sim, bridge, viz, router, unitree, ros1, ros2, loco", "anyone",
                     "while running", payload="token", name="alive_any")
CLAIM: Final[Topic[Message]] = Topic("claim/{nonce}", "liveliness", "sim, replay: one per process that serves the id",
                                     "sim, replay (at start: is the id free?)", "while starting and running",
                                     payload="token", name="claim_any",
                                     note="(`{nonce}` is random; two processes that start at once with one id both see "
                                          "each other's claim, and neither serves until it alone holds one)")
ROUTER_ALIVE: Final[Topic[Message]] = Topic("alive", "liveliness", "router (one token whatever its `--robot-id`)",
                                            "viz (the router badge of every robot), anyone", "while running",
                                            payload="token", scope="router",
                                            note="(the router serves every robot: its `alive/router` names only its own robot id)")

TOPICS: Final[tuple[Topic, ...]] = (
    JOINTS, ODOM, IMU, CONTACTS, SIM_STATUS, BRIDGE_TARGETS, UNITREE_STATUS, ROS1_STATUS, ROS2_STATUS,
    MOTORS, JOINT_TARGETS, JOINT_TARGET, BRIDGE_REPORT,
    CTL_RESET, CTL_PAUSE, CTL_RESUME, CTL_STEP, CTL_MODE, CTL_ADVANCE, CTL_PUSH, CTL_BAND, CTL_FAULTS, APPLIED,
    WORLD_PAUSE, WORLD_RESUME, WORLD_STEP, WORLD_RESET, WORLD_ADVANCE, WORLD_INFO,
    ROBOT_INFO, URDF, MESH, ALIVE, CLAIM, ROUTER_ALIVE,
    VELOCITY, ARMS, CTL_LOCO, LOCO_STATUS, REMOTE,
)
"""Every topic, in the order the docs list them."""


# --- roles: who may write and read what ----------------------------------------------------------
@dataclass(frozen=True)
class Role:
    """What one credential may do, as key expressions under `zensim/{robot}/` (`*` one chunk, `**` a path).

    One line per role: adding a role is adding a line here (and `zensim secure init` makes its
    credentials). Every pattern must cover at least one topic of the matching kind (a test checks).

    Args:
        name: the role (the user name and `zensim-<name>` certificate name of its credentials).
        kind: a zensim service (runs with its own credentials) or a client (people and tools).
        summary: a few words for the docs.
        publishes: keys it puts on (publications).
        subscribes: keys it declares subscribers on (publications).
        serves: keys it declares queryables on and replies from.
        queries: keys it sends queries to (`get`, queriers).
        tokens: liveliness tokens it declares.
        ros2: what it may do on rmw_zenoh's keys (`<domain>/**`, `@ros2_lv/<domain>/**`, outside zensim's
            root; services/ros2): `write` (publish, subscribe, serve latched topics, declare ROS 2
            tokens: a ROS 2 node that drives the robot), `read` (everything but publishing and serving),
            or nothing.
    """

    name: str
    kind: RoleKind
    summary: str
    publishes: tuple[str, ...] = ()
    subscribes: tuple[str, ...] = ()
    serves: tuple[str, ...] = ()
    queries: tuple[str, ...] = ()
    tokens: tuple[str, ...] = ()
    ros2: Literal["", "read", "write"] = ""


EVERY_ROLE_WATCHES: Final = ("alive/*", "claim/*")
"""Liveliness every role may watch (liveliness subscribers and queries): who is up is no secret."""

ROLES: Final[tuple[Role, ...]] = (
    Role("sim", "service", "the simulator", publishes=("state/joints", "state/odom", "state/imu", "state/contacts", "state/sim", "state/applied"), subscribes=("cmd/motors",), serves=("ctl/*", "info/**", "world/*"), tokens=("alive/sim", "alive/world", "claim/*")),
    Role("bridge", "service", "joint targets to motor commands", publishes=("cmd/motors", "state/targets", "report/bridge"), subscribes=("state/**", "cmd/joints", "cmd/joint/*"), queries=("info/**",), tokens=("alive/bridge",)),
    Role("viz", "service", "the web viewer (sliders, buttons, plots, keys and gamepad)", publishes=("cmd/joints", "cmd/velocity", "cmd/remote"), subscribes=("state/**", "cmd/motors"), queries=("info/**", "ctl/*", "world/info", "world/pause", "world/resume", "world/step"), tokens=("alive/viz",)),
    Role("unitree", "service", "the Unitree DDS adapter (its sport service forwards to `zensim loco`)", publishes=("cmd/motors", "state/unitree", "cmd/velocity", "cmd/arms"), subscribes=("state/**", "cmd/remote"), queries=("info/**", "ctl/loco"), tokens=("alive/unitree",)),
    Role("loco", "service", "the walking controller", publishes=("cmd/motors", "state/loco"), subscribes=("state/**", "cmd/velocity", "cmd/arms"), serves=("ctl/loco",), queries=("info/**",), tokens=("alive/loco",)),
    Role("ros1", "service", "the ROS 1 gateway (the bridge-facing side)", publishes=("cmd/joints", "cmd/joint/*", "state/ros1", "cmd/velocity"), subscribes=("state/**",), queries=("info/**",), tokens=("alive/ros1",)),
    Role("ros2", "service", "the ROS 2 face (the bridge-facing side; its ROS 2 keys: docs/security.md)", publishes=("cmd/joints", "state/ros2", "cmd/velocity"), subscribes=("state/**",), queries=("info/**", "world/info"), tokens=("alive/ros2",), ros2="write"),
    Role("recorder", "service", "`zensim record`", subscribes=("**",), queries=("info/**",)),
    Role("replay", "service", "`zensim replay`: stands in for the sim", publishes=("state/**",), serves=("info/**",), tokens=("alive/sim", "alive/replay", "claim/*")),
    Role("operator", "client", "people and tools that drive the robot", publishes=("cmd/**",), subscribes=("**",), queries=("ctl/*", "info/**", "world/*"), ros2="write"),
    Role("viewer", "client", "read-only dashboards", subscribes=("state/**",), queries=("info/**", "world/info"), ros2="read"),
)
"""Every role. The router denies everything a role does not list (docs/security.md)."""

ROLE_NAMES: Final = tuple(role.name for role in ROLES)


def role(name: str) -> Role:
    """The role called `name`; KeyError names the known ones."""
    for candidate in ROLES:
        if candidate.name == name:
            return candidate
    raise KeyError(f"no role {name!r}; roles: {', '.join(ROLE_NAMES)}")


def includes(pattern: str, key: str) -> bool:
    """Whether key expression `pattern` covers every key `key` can stand for (zenoh's `includes`).

    Both are chunks joined by `/`; `*` is one chunk, `**` any number of chunks. Pure Python so the
    registry needs no zenoh (a test checks it against zenoh's own).
    """
    return _includes(pattern.split("/"), key.split("/"))


def _includes(pattern: list[str], key: list[str]) -> bool:
    if not pattern:
        return not key
    head, rest = pattern[0], pattern[1:]
    if head == "**":
        return any(_includes(rest, key[i:]) for i in range(len(key) + 1))
    if not key or key[0] == "**":
        return False
    return (head == "*" or head == key[0]) and _includes(rest, key[1:])


def intersects(a: str, b: str) -> bool:
    """Whether some key matches both key expressions (zenoh's `intersects`)."""
    return _intersects(a.split("/"), b.split("/"))


def _intersects(a: list[str], b: list[str]) -> bool:
    if not a or not b:
        return all(chunk == "**" for chunk in a + b)
    if a[0] == "**":
        return _intersects(a[1:], b) or _intersects(a, b[1:])
    if b[0] == "**":
        return _intersects(b, a)
    return (a[0] == "*" or b[0] == "*" or a[0] == b[0]) and _intersects(a[1:], b[1:])


ROLE_USES: Final[tuple[tuple[str, str, Kind], ...]] = (
    ("publishes", "publishes", "publication"), ("subscribes", "subscribes", "publication"),
    ("serves", "serves", "queryable"), ("queries", "queries", "queryable"), ("token", "tokens", "liveliness"))
"""How a role uses a key: (verb for the docs, `Role` field, the kind of topic it applies to)."""


def covered_topics(pattern: str, kind: Kind) -> list[Topic]:
    """The topics of `kind` that key expression `pattern` (under `zensim/{robot}/`) reaches."""
    return [t for t in TOPICS if t.kind == kind and t.scope == "robot" and intersects(pattern, t.pattern())]


def _roles_on(topic: Topic[Message], field: str) -> tuple[str, ...]:
    return tuple(r.name for r in ROLES if any(intersects(p, topic.pattern()) for p in getattr(r, field)))


def writers(topic: Topic) -> tuple[str, ...]:
    """The roles that may write `topic`: publish it, serve it or hold its token (a router's key: the router
    itself, which no access rule governs: it is the one enforcing them)."""
    if topic.scope == "router":
        return ("router",)
    field = {"publication": "publishes", "queryable": "serves", "liveliness": "tokens"}[topic.kind]
    return _roles_on(topic, field)


def readers(topic: Topic) -> tuple[str, ...]:
    """The roles that may read `topic`: subscribe to it, query it or watch its token."""
    if topic.scope == "router":
        return ROLE_NAMES  # the router's token: every role may watch it (secure.py's ROUTER_WATCH rule)
    if topic.kind == "liveliness":
        return ROLE_NAMES if any(intersects(p, topic.pattern()) for p in EVERY_ROLE_WATCHES) else ()
    return _roles_on(topic, "subscribes" if topic.kind == "publication" else "queries")


def protocol_table() -> str:
    """The Markdown protocol table of docs/protocol.md, rendered from `TOPICS`."""
    rows = ["| key (under `zensim/{robot}/` unless whole) | kind | message | writer | reader | rate | roles: write / read |",
            "|---|---|---|---|---|---|---|"]
    for topic in TOPICS:
        roles = f"{', '.join(writers(topic)) or '-'} / {_readers_text(topic)}"
        rows.append(f"| `{topic.doc_key()}` | {topic.kind} | {topic.doc_name()} | {topic.writer} | {topic.reader} "
                    f"| {topic.rate} | {roles} |")
    return "\n".join(rows) + "\n"


def _readers_text(topic: Topic) -> str:
    names = readers(topic)
    return "every role" if names == ROLE_NAMES else ", ".join(names) or "-"


def _keys_text(patterns: tuple[str, ...]) -> str:
    return ", ".join(f"`{p}`" for p in patterns) or "-"


def role_table() -> str:
    """The Markdown role table of docs/security.md, rendered from `ROLES`."""
    rows = ["| role | what | publishes | subscribes | serves | queries | liveliness token |",
            "|---|---|---|---|---|---|---|"]
    for r in ROLES:
        rows.append(f"| {r.name} ({r.kind}) | {r.summary} | {_keys_text(r.publishes)} | {_keys_text(r.subscribes)} "
                    f"| {_keys_text(r.serves)} | {_keys_text(r.queries)} | {_keys_text(r.tokens)} |")
    return "\n".join(rows) + "\n"


def service_key_table(name: str) -> str:
    """The Markdown table of the keys one role writes and reads, for its service's README."""
    r = role(name)
    rows = ["| key (under `zensim/{robot}/`) | as | kind | message |", "|---|---|---|---|"]
    for verb, patterns, kind in ROLE_USES:
        for pattern in getattr(r, patterns):
            covered = covered_topics(pattern, kind)
            message = covered[0].doc_name() if len(covered) == 1 else ", ".join(f"`{t.key}`" for t in covered)
            rows.append(f"| `{pattern}` | {verb} | {kind} | {message} |")
    return "\n".join(rows) + "\n"
