"""Every message that travels between zensim services, as msgspec Structs.

The field names are the public wire contract: clients in Rust, C or the zenoh
command line read them by name, so a field is never renamed or retyped. New
fields go at the end with a default (old readers skip them, new readers fill
them in); a breaking change gets a new key. See docs/protocol.md.

Units are SI, angles radians, quaternions scalar-first (`quat_wxyz`). Joint
vectors are in the robot's canonical joint order (`RobotInfo.joint_names`)
unless a message carries `names`.

Commands and control requests validate themselves on decode
(`__post_init__`): a NaN, an infinity or vectors of mismatched lengths raise
`msgspec.ValidationError` naming the field, so nothing invalid reaches a
service. Checks that need the robot (joint names, vector length against the
joint count, limits) belong to the service that knows the robot.
"""

from __future__ import annotations

import math
from typing import Annotated, Final, Literal, get_args

import msgspec

SCHEMA_VERSION = 1
"""Bumped only for a breaking change, which also gets new keys."""

Mode = Literal["floating", "fixed"]
MODES: Final[tuple[Mode, ...]] = get_args(Mode)
"""Every mode, in the order tools offer them (the first is the default)."""
Vector = tuple[float, ...]

MAX_STEPS_PER_REQUEST = 100_000


class Message(msgspec.Struct, frozen=True, kw_only=True, tag_field="type"):
    """Base of every wire struct.

    `type` carries an explicit, stable tag so renaming a class never changes
    the wire format. Readers do not need it: the key says the type, so a JSON
    input may leave it out. Unknown fields are ignored so old readers survive
    new writers.
    """


def _check_finite(field: str, values: Vector | None) -> None:
    if values is None:
        return
    for i, value in enumerate(values):
        if not math.isfinite(value):
            raise ValueError(f"`{field}[{i}]` must be a finite number, got {value}")


MAX_AT_S: Final = 1e7
"""Latest sim time a request may be scheduled for (`at_s`), s: 116 days, far beyond any run; a later time is a
typo or an attack."""
MAX_SCHEDULED: Final = 1024
"""Requests one robot keeps waiting for their `at_s` (the sim's ctl/push, ctl/band, ctl/faults together; the
walking controller's velocities): one more is refused. A scenario schedules its events ahead, so this bounds
its events of each kind (zensim/scenario_file.py)."""


def _check_at(at_s: float | None) -> None:
    if at_s is not None:
        _check_finite("at_s", (at_s,))
        if not 0.0 <= at_s <= MAX_AT_S:
            raise ValueError(f"`at_s` must be in [0, {MAX_AT_S:g}] s of sim time, got {at_s:g}")


def _check_length(field: str, values: tuple | None, expected: int, against: str) -> None:
    if values is not None and len(values) != expected:
        raise ValueError(
            f"`{field}` has {len(values)} values but `{against}` has {expected}"
        )


def _check_non_negative(field: str, values: Vector | None) -> None:
    if values is None:
        return
    for i, value in enumerate(values):
        if value < 0:
            raise ValueError(f"`{field}[{i}]` must be >= 0, got {value}")


def _check_unique(field: str, names: tuple[str, ...] | None) -> None:
    if names is not None and len(set(names)) != len(names):
        raise ValueError(f"`{field}` names a joint more than once")


# --- state: sim -> anyone -------------------------------------------------


class JointState(Message, frozen=True, tag="joint_state", kw_only=True):
    """Measured joint positions, velocities and torques at one sim instant."""

    sim_time_s: float
    """Simulation time this state describes, s."""
    seq: int
    """Counts up by one per published state; resets only when the sim restarts."""
    q: Vector
    """Joint positions, rad (m for prismatic joints)."""
    dq: Vector
    """Joint velocities, rad/s."""
    tau: Vector
    """Actuator torques applied in the last step, N m."""


class Odometry(Message, frozen=True, tag="odometry", kw_only=True):
    """Ground-truth pose and twist of the base link (the pelvis frame, not its centre of mass)."""

    sim_time_s: float
    """Simulation time this state describes, s."""
    seq: int
    """Counts up by one per published message."""
    pos: Vector
    """Base position [x, y, z] in the world frame, m."""
    quat_wxyz: Vector
    """Base orientation in the world frame, scalar first."""
    lin_vel_world: Vector
    """Base linear velocity in the world frame, m/s."""
    ang_vel_body: Vector
    """Base angular velocity in the base frame, rad/s."""


class Imu(Message, frozen=True, tag="imu", kw_only=True):
    """What the robot's IMU measures (site `imu_in_pelvis` on the G1)."""

    sim_time_s: float
    """Simulation time this state describes, s."""
    seq: int
    """Counts up by one per published message."""
    quat_wxyz: Vector
    """IMU orientation in the world frame, scalar first."""
    gyro: Vector
    """Angular velocity in the IMU frame, rad/s."""
    accel: Vector
    """Specific force in the IMU frame (reads +9.81 on z at rest), m/s^2."""


class Contacts(Message, frozen=True, tag="contacts", kw_only=True):
    """Each foot's contact with the world at one sim instant (the feet are control.toml's `foot_links`).

    What acted during the physics step that ended at `sim_time_s` (as JointState's `tau`), summed over
    every contact of the foot's link: the floor, terrain, another robot. One entry per foot, in the
    order of `links`; a robot without feet has none. `seq` is the JointState's of the same instant.
    """

    sim_time_s: float
    """Simulation time this state describes, s."""
    seq: int
    """The `seq` of the JointState (and Odometry, Imu) of the same instant."""
    links: tuple[str, ...]
    """The foot links, URDF names (the G1: `left_ankle_roll_link`, `right_ankle_roll_link`)."""
    in_contact: tuple[bool, ...]
    """Whether the foot touches anything (at least one contact point)."""
    normal_force_n: Vector
    """Sum of the contact points' normal forces on the foot, N (>= 0; what a sole pressure sensor reads)."""
    force_world: tuple[Vector, ...]
    """Total contact force on the foot [x, y, z] in the world frame, N (normal and friction; +z pushes up)."""
    points: tuple[int, ...]
    """Number of contact points of the foot."""


class SimStatus(Message, frozen=True, tag="sim_status", kw_only=True):
    """The sim's health, about 10 times a second."""

    sim_time_s: float
    """Simulation time, s."""
    rtf: float
    """Real-time factor achieved over the last status period (sim s per wall s)."""
    paused: bool
    """True while the physics is paused (ctl/pause)."""
    mode: Mode
    """`floating` (free base, gravity on) or `fixed` (base welded, gravity off)."""
    fallen: bool
    """True while the base tilts past the robot's fall threshold."""
    rejected_commands: int = 0
    """Commands on cmd/motors rejected since start (malformed, NaN, unknown joint, ...)."""
    clamped_commands: int = 0
    """Accepted commands whose targets were clamped to the joint limits."""
    command_age_s: float | None = None
    """Wall time since the newest accepted command, s; null before the first one."""
    watchdog: bool = False
    """True while no command came within the watchdog timeout and the sim holds its safe pose."""
    last_error: str | None = None
    """Why the most recent command was rejected, if one was."""
    seq: int = 0
    """Counts up by one per published status."""
    steps: int = 0
    """Physics steps taken since the last reset."""
    timestep_s: float = 0.0
    """Physics step, s."""
    target_rtf: float = 1.0
    """Requested real-time factor (0 means as fast as possible)."""
    step_jitter_p99_s: float = 0.0
    """99th percentile of |actual - scheduled| step start over the last status period, s."""
    resets: int = 0
    """Resets since start (ctl/reset, mode switches, automatic fall resets)."""
    run_id: str = ""
    """Random id of this run of the sim process: a new value means the sim restarted (counters and
    held commands start over). Empty from a sim that does not say."""
    physics_resets: int = 0
    """Automatic resets after the physics broke (MuJoCo's bad-state warnings, a non-finite state, a
    base faster or higher than physically possible), since start; each is also counted in `resets`."""
    last_reset_reason: str | None = None
    """Why the sim last reset itself (a broken physics state or a fall), if it did."""
    rejected_requests: int = 0
    """ctl queries refused since start (malformed, unknown fields, wildcard keys, out of bounds)."""
    clock: Literal["realtime", "lockstep"] = "realtime"
    """`realtime` (paced by `target_rtf`) or `lockstep` (each motor command advances the physics)."""
    waiting: bool = False
    """Lockstep: true while the sim stands still waiting for the next motor command."""
    episode: str = ""
    """Names the stretch of simulation since the robot was last put into a pose by the sim itself
    (start, ctl/reset, a mode switch, an automatic reset). A new value tells a client that holds
    targets (the bridge) to hold the default pose of `mode` again; a new `run_id` with it means the
    robot itself may have changed. Opaque: compare it, do not parse it. Empty from a sim that does not say."""
    shed_commands: int = 0
    """Commands on cmd/motors dropped unread since start because a newer one from the same source was
    already waiting (latest wins, so it would never have been applied). Not errors: a flood costs the
    sim one decode per source and take of its command queue. Samples carry their source in zenoh's
    source info (the publisher's id); samples without it count as one source."""
    pushes: tuple[PushState, ...] = ()
    """The pushes acting now (ctl/push), oldest first; empty when none is."""
    pushes_applied: int = 0
    """Pushes accepted since start (each also reported by `last_push`); a push shorter than a status period
    still shows here and in `last_push`."""
    last_push: PushState | None = None
    """The most recent push accepted (acting or finished), null before the first."""
    band: BandState | None = None
    """The elastic band (ctl/band) while it holds the robot; null while it is off."""
    variant: Variant | None = None
    """The variant of the robot drawn at the last reset (ctl/reset `randomize`); null: the nominal robot."""
    faults: FaultsState | None = None
    """The faults injected now (ctl/faults); null while none is."""
    faults_set: int = 0
    """ctl/faults requests that changed the faults (set or clear), since start."""
    dropped_commands: int = 0
    """Commands the sim accepted (checked and sound) and then lost, as the link fault `drop_probability`
    (ctl/faults) asked, since start: never applied (and not counted in `rejected_commands`)."""
    scheduled: int = 0
    """ctl requests (push, band, faults) accepted with an `at_s` and still waiting for it. A reset drops them (a
    new episode); one that no longer fits when its time comes (a 17th push at once) is refused then, counted
    in `rejected_requests` with its reason in `last_error`."""
    withheld_states: int = 0
    """State instants whose state/joints and state/imu were withheld by a sensor dropout (ctl/faults
    `dropout_probability`), since start."""


# --- commands -------------------------------------------------------------


class MotorCommand(Message, frozen=True, tag="motor_command", kw_only=True):
    """Motor targets with Unitree LowCmd semantics, applied at every physics step.

    tau = kp * (q - q_meas) + kd * (dq - dq_meas) + tau_ff. Without `names`
    the vectors cover every joint in canonical order; with `names` only those
    joints change and the rest keep their previous command. Absent `dq` and
    `tau` are 0; absent `kp` and `kd` are the robot's gains for the current mode.
    """

    q: Vector
    """Target positions, rad."""
    names: tuple[str, ...] | None = None
    """Joints the vectors address, in their order; null means all, in canonical order."""
    dq: Vector | None = None
    """Target velocities, rad/s (default 0)."""
    kp: Vector | None = None
    """Position gains, N m/rad (default: configured gains)."""
    kd: Vector | None = None
    """Velocity gains, N m s/rad (default: configured gains)."""
    tau: Vector | None = None
    """Feed-forward torques, N m (default 0)."""

    def __post_init__(self) -> None:
        _check_unique("names", self.names)
        if self.names is not None:
            _check_length("q", self.q, len(self.names), "names")
        for field in ("dq", "kp", "kd", "tau"):
            _check_length(field, getattr(self, field), len(self.q), "q")
        for field in ("q", "dq", "kp", "kd", "tau"):
            _check_finite(field, getattr(self, field))
        _check_non_negative("kp", self.kp)
        _check_non_negative("kd", self.kd)


class JointTargets(Message, frozen=True, tag="joint_targets", kw_only=True):
    """Position targets for some joints (sliders, scripts); the bridge holds the rest."""

    names: tuple[str, ...]
    """Joints to move."""
    q: Vector
    """Target positions for `names`, rad."""
    dq: Vector | None = None
    """Target velocities for `names`, rad/s (default 0)."""

    def __post_init__(self) -> None:
        _check_unique("names", self.names)
        _check_length("q", self.q, len(self.names), "names")
        _check_length("dq", self.dq, len(self.names), "names")
        _check_finite("q", self.q)
        _check_finite("dq", self.dq)


class BridgeReport(Message, frozen=True, tag="bridge_report", kw_only=True):
    """The bridge's verdict on one input it rejected or changed (clamped)."""

    key: str
    """Key expression the input arrived on."""
    accepted: bool
    """False: nothing of the input was applied. True: applied, with `clamped` joints limited."""
    error: str | None = None
    """Why the input was rejected."""
    clamped: tuple[str, ...] = ()
    """Joints whose targets were clamped to their limits."""
    rejected_total: int = 0
    """Inputs rejected since the bridge started."""
    clamped_total: int = 0
    """Inputs clamped since the bridge started."""


# --- control requests (queryables on the sim) -----------------------------


# Requests forbid unknown fields, unlike the other messages: a typo (`{"n_steps": 5}`) must be an
# error, not a request with every field at its default. A newer client's field that this sim does
# not know is refused for the same reason: the sim could not honour it.


class ResetRequest(Message, frozen=True, tag="reset_request", kw_only=True, forbid_unknown_fields=True):
    """Reset the robot. Everything is optional: an empty request resets to the default pose."""

    q: Vector | None = None
    """Joint pose, canonical order (or `names` order); default: the robot's default pose."""
    names: tuple[str, ...] | None = None
    """Joints `q` addresses; the others take their default position."""
    base_height_m: float | None = None
    """Base height, m; default: the mode's spawn height."""
    mode: Mode | None = None
    """Switch to this mode while resetting; default: keep the current mode."""
    randomize: Randomize | None = None
    """Draw a variant of the robot (friction, link masses and centres of mass, motor strength) from the
    nominal one; null: the nominal robot (services/sim/README.md, *Randomisation*)."""

    def __post_init__(self) -> None:
        _check_unique("names", self.names)
        if self.names is not None:
            if self.q is None:
                raise ValueError("`names` given without `q`")
            _check_length("q", self.q, len(self.names), "names")
        _check_finite("q", self.q)
        if self.base_height_m is not None:
            _check_finite("base_height_m", (self.base_height_m,))


# --- randomisation at reset: ctl/reset's `randomize` (services/sim/variants.py) ----------------------

MAX_SEED: Final = (1 << 63) - 1
"""Largest seed: any non-negative signed 64-bit integer (what msgspec bounds and every JSON library carry)."""
FRICTION_SCALE_BOUNDS: Final = (0.1, 10.0)
"""Friction factors a range may reach: ice to glue, nothing a typo like 1e6 makes."""
MASS_SCALE_BOUNDS: Final = (0.2, 5.0)
"""Mass factors a range may reach (each link's mass and inertia together)."""
MOTOR_STRENGTH_BOUNDS: Final = (0.1, 2.0)
"""Motor strength factors a range may reach (torque and torque limit together; 0 is a limp motor, a fault)."""
MAX_COM_OFFSET_M: Final = 0.1
"""Largest centre-of-mass offset along each axis of a link, m."""


def _check_scale_range(field: str, value: tuple[float, float] | None, bounds: tuple[float, float]) -> None:
    if value is None:
        return
    _check_finite(field, value)
    lo, hi = value
    if lo > hi:
        raise ValueError(f"`{field}` [{lo:g}, {hi:g}]: lo is above hi")
    if lo < bounds[0] or hi > bounds[1]:
        raise ValueError(f"`{field}` [{lo:g}, {hi:g}] must lie within [{bounds[0]:g}, {bounds[1]:g}]")


class Randomize(Message, frozen=True, tag="randomize", kw_only=True, forbid_unknown_fields=True):
    """A variant of the robot drawn at reset (ResetRequest.randomize): each factor uniform in its range, by seed.

    Factors scale the robot's nominal values (always from the nominal robot, never compounding); a range
    left out keeps that part nominal. The same seed and ranges give the same variant on every machine.
    """

    seed: Annotated[int, msgspec.Meta(ge=0, le=MAX_SEED)]
    """Seed of the draw, 0..2^63-1."""
    friction: tuple[float, float] | None = None
    """[lo, hi] factor on the sliding friction of the robot's contacts with the ground (one factor per
    robot), within [0.1, 10]."""
    mass: tuple[float, float] | None = None
    """[lo, hi] factor on each link's mass and rotational inertia (one factor per link), within [0.2, 5]."""
    com_offset_m: float | None = None
    """Each link's centre of mass moves by a uniform offset in [-com_offset_m, com_offset_m] along each axis
    of the link's frame, m, in [0, 0.1]."""
    motor_strength: tuple[float, float] | None = None
    """[lo, hi] factor on each motor's torque (the PD's output and the feed-forward) and its torque limit
    (one factor per joint), within [0.1, 2]."""

    def __post_init__(self) -> None:
        _check_scale_range("friction", self.friction, FRICTION_SCALE_BOUNDS)
        _check_scale_range("mass", self.mass, MASS_SCALE_BOUNDS)
        _check_scale_range("motor_strength", self.motor_strength, MOTOR_STRENGTH_BOUNDS)
        if self.com_offset_m is not None:
            _check_finite("com_offset_m", (self.com_offset_m,))
            if not 0.0 <= self.com_offset_m <= MAX_COM_OFFSET_M:
                raise ValueError(f"`com_offset_m` must be in [0, {MAX_COM_OFFSET_M:g}] m, got {self.com_offset_m}")


class Variant(Message, frozen=True, tag="variant", kw_only=True):
    """The variant of the robot in use since the last reset (CtlReply, SimStatus and RobotInfo `variant`)."""

    seed: int
    """The seed it was drawn with."""
    friction_range: tuple[float, float] | None = None
    """The request's `friction` range (null: nominal friction); with the other ranges and the seed, what
    draws this variant again (a plain struct, not the request: readers skip fields it gains later)."""
    mass_range: tuple[float, float] | None = None
    """The request's `mass` range (null: nominal masses and inertias)."""
    com_offset_max_m: float | None = None
    """The request's `com_offset_m` (null: nominal centres of mass)."""
    motor_strength_range: tuple[float, float] | None = None
    """The request's `motor_strength` range (null: nominal motors)."""
    friction_scale: float = 1.0
    """Factor on the sliding friction of the robot's contacts with the ground."""
    bodies: tuple[str, ...] = ()
    """The robot's links (URDF names) that `mass_scale` and `com_offset_m` follow."""
    mass_scale: Vector = ()
    """Factor on each link's mass and inertia, in `bodies` order."""
    com_offset_m: tuple[tuple[float, float, float], ...] = ()
    """Each link's centre-of-mass offset in its own frame, m, in `bodies` order."""
    motor_strength: Vector = ()
    """Factor on each motor's torque and torque limit, canonical joint order."""
    mass_kg: float = 0.0
    """The variant's total mass, kg."""
    nominal_mass_kg: float = 0.0
    """The nominal robot's total mass, kg."""


class PauseRequest(Message, frozen=True, tag="pause_request", kw_only=True, forbid_unknown_fields=True):
    """Stop stepping the physics; states keep being published."""


class ResumeRequest(Message, frozen=True, tag="resume_request", kw_only=True, forbid_unknown_fields=True):
    """Start stepping again after a pause."""


class StepRequest(Message, frozen=True, tag="step_request", kw_only=True, forbid_unknown_fields=True):
    """Advance a paused sim by `n` steps; the reply comes after they ran."""

    n: int = 1
    """Number of physics steps, 1..100000."""

    def __post_init__(self) -> None:
        if not 1 <= self.n <= MAX_STEPS_PER_REQUEST:
            raise ValueError(f"`n` must be in 1..{MAX_STEPS_PER_REQUEST}, got {self.n}")


class ModeRequest(Message, frozen=True, tag="mode_request", kw_only=True, forbid_unknown_fields=True):
    """Switch between floating and fixed base; rebuilds the model and resets."""

    mode: Mode
    """The new mode."""


class CtlReply(Message, frozen=True, tag="ctl_reply", kw_only=True):
    """The answer to every ctl request."""

    ok: bool
    """True when the request was carried out."""
    error: str | None = None
    """Why not, when `ok` is false."""
    sim_time_s: float = 0.0
    """Simulation time after the request, s."""
    paused: bool = False
    """Paused after the request."""
    mode: Mode = "floating"
    """Mode after the request."""
    steps: int = 0
    """Physics steps since the last reset, after the request."""
    episode: str = ""
    """SimStatus.episode after the request: a reset or mode switch starts a new one."""
    push: PushState | None = None
    """ctl/push: the push that was applied (its force, start and whole-step duration)."""
    band: BandState | None = None
    """ctl/band: the band after the request (its `on` false when it is off)."""
    variant: Variant | None = None
    """ctl/reset: the variant of the robot the reset drew (`randomize`); null: the nominal robot."""
    faults: FaultsState | None = None
    """ctl/faults: the faults active after the request (null: none)."""
    scheduled_at_s: float | None = None
    """A request with `at_s`: the sim time it will act at (the start of the first step at or after `at_s`); its
    effect shows in state/sim then. `push`, `band` and `faults` say what is in force now (a push: the one it will
    apply, from `start_s`). Null: it acted now."""


# --- disturbances: ctl/push, ctl/band (services/sim/disturbances.py) ----------

MAX_PUSH_DURATION_S: Final = 10.0
"""Longest push, s of sim time: a shove, not a constant force (a longer one is a scenario's business)."""
MAX_BAND_LENGTH_M: Final = 5.0
"""Longest band, m: longer than the anchor's height above any spawn, so the band can let a robot stand."""
BandVerb = Literal["on", "off", "lower", "raise"]
MAX_BODY_NAME_CHARS: Final = 256


class PushRequest(Message, frozen=True, tag="push_request", kw_only=True, forbid_unknown_fields=True):
    """Push a body of the robot with a constant force for a while (ctl/push).

    The force acts at the body's centre of mass, from the next physics step on, for `duration_s` rounded to
    whole physics steps (at least one). The sim refuses a body the robot lacks and a force beyond 10 times
    the robot's weight (services/sim/README.md, *Disturbances*).
    """

    direction: tuple[float, float, float]
    """Direction of the force in the world frame (any length but zero; the sim normalises it)."""
    magnitude_n: float
    """Size of the force, N (> 0)."""
    duration_s: float
    """How long it acts, s of sim time, in (0, 10]."""
    body: str | None = None
    """The body (URDF link) pushed; null: the robot's base link (the G1's `pelvis`)."""
    at_s: float | None = None
    """Sim time to act at, s (SimStatus.sim_time_s's clock): the request is checked now and carried out right
    before the first physics step that starts at or after it, the same step in every run (a time already past is
    refused); null: at the next step."""

    def __post_init__(self) -> None:
        _check_at(self.at_s)
        _check_finite("direction", self.direction)
        if math.fsum(d * d for d in self.direction) <= 0.0:
            raise ValueError("`direction` must not be zero")
        _check_finite("magnitude_n", (self.magnitude_n,))
        if self.magnitude_n <= 0:
            raise ValueError(f"`magnitude_n` must be > 0, got {self.magnitude_n}")
        _check_finite("duration_s", (self.duration_s,))
        if not 0 < self.duration_s <= MAX_PUSH_DURATION_S:
            raise ValueError(f"`duration_s` must be in (0, {MAX_PUSH_DURATION_S:g}] s, got {self.duration_s}")
        if self.body is not None and not 0 < len(self.body) <= MAX_BODY_NAME_CHARS:
            raise ValueError(f"`body` must be 1..{MAX_BODY_NAME_CHARS} characters")


class PushState(Message, frozen=True, tag="push_state", kw_only=True):
    """One push as the sim applies it (CtlReply.push, SimStatus.pushes and last_push)."""

    body: str
    """The body pushed (URDF link name)."""
    force_n: Vector
    """The force, world frame, N."""
    start_s: float
    """Sim time of the first step it acts on, s."""
    duration_s: float
    """How long it acts: whole physics steps, s."""
    remaining_s: float = 0.0
    """Sim time it still acts for, s (0: finished)."""
    impulse_n_s: Vector = ()
    """force_n x duration_s, world frame, N s."""


class BandRequest(Message, frozen=True, tag="band_request", kw_only=True, forbid_unknown_fields=True):
    """The elastic band (ctl/band); an empty request changes nothing and answers the band's state.

    `verb`: on, off, lower (the band 0.1 m longer: the robot hangs lower), raise (0.1 m shorter).
    `length_m` sets the length (alone, or with `on`), not with lower or raise.
    """

    verb: BandVerb | None = None
    """on, off, lower or raise."""
    length_m: float | None = None
    """The band's rest length, m, in [0, 5]."""
    at_s: float | None = None
    """Sim time to act at, s (SimStatus.sim_time_s's clock): the request is checked now and carried out right
    before the first physics step that starts at or after it, the same step in every run (a time already past is
    refused); null: at the next step."""

    def __post_init__(self) -> None:
        _check_at(self.at_s)
        if self.at_s is not None and self.verb is None and self.length_m is None:
            raise ValueError("`at_s` goes with a verb or a `length_m`: a request without them only asks")
        if self.length_m is not None:
            _check_finite("length_m", (self.length_m,))
            if not 0 <= self.length_m <= MAX_BAND_LENGTH_M:
                raise ValueError(f"`length_m` must be in [0, {MAX_BAND_LENGTH_M:g}] m, got {self.length_m}")
            if self.verb in ("lower", "raise"):
                raise ValueError(f"give `length_m` or `verb: {self.verb}`, not both")


class BandState(Message, frozen=True, tag="band_state", kw_only=True):
    """The elastic band: a spring-damper from a fixed anchor to the base link that only pulls."""

    on: bool
    """True while it holds the robot."""
    anchor: Vector
    """The point it hangs from, world frame, m."""
    length_m: float
    """Rest length, m: the band pulls only when the base is farther than this from the anchor."""
    stiffness_n_m: float
    """Spring rate, N/m."""
    damping_n_s_m: float
    """Damping along the band, N s/m."""
    force_n: Vector = ()
    """The force it put on the base at the last step, world frame, N."""


# --- faults: ctl/faults (services/sim/faults.py) ---------------------------------

FaultVerb = Literal["set", "clear"]
MAX_JOINT_FAULTS: Final = 256
"""Joint faults in one request (more than any robot has joints)."""
MAX_ENCODER_OFFSET_RAD: Final = math.pi
"""Largest encoder offset, rad: half a turn (an offset beyond is the same angle the other way)."""
MAX_GYRO_NOISE_RAD_S: Final = 1.0
"""Largest gyro noise std and bias, rad/s (a real MEMS gyro's is below 0.01)."""
MAX_ACCEL_NOISE_M_S2: Final = 10.0
"""Largest accelerometer noise std and bias, m/s^2 (about 1 g)."""
MAX_Q_NOISE_RAD: Final = 0.5
"""Largest joint position noise std, rad."""
MAX_DQ_NOISE_RAD_S: Final = 10.0
"""Largest joint velocity noise std, rad/s."""
MAX_FAULT_SEED: Final = 2**63 - 1
MAX_DELAY_STEPS: Final = 500
"""Longest command delay, in physics steps: 1 s of the G1's 2 ms steps, beyond any link a controller runs over
(a delay that long is a dead link, which `drop_probability` 1 is); it bounds the commands held in flight.
The longest state delay too: it bounds the past readings kept."""
MAX_DRIFT_RAD_S: Final = 0.1
"""Fastest orientation drift, rad/s (6 deg/s: far beyond a MEMS IMU's fused yaw, which drifts a few deg/min)."""
MAX_DROPOUT_S: Final = 10.0
"""Longest state dropout, s of sim time."""


def _check_in(field: str, value: float, low: float, high: float) -> None:
    _check_finite(field, (value,))
    if not low <= value <= high:
        raise ValueError(f"`{field}` must be in [{low:g}, {high:g}], got {value:g}")


class JointFault(Message, frozen=True, tag="joint_fault", kw_only=True, forbid_unknown_fields=True):
    """One joint's motor and encoder faults (FaultsRequest.joints, FaultsState.joints)."""

    joint: str
    """The joint (RobotInfo.joint_names)."""
    torque_scale: float = 1.0
    """The motor's torque (its PD and feed-forward, and its peak) times this, in [0, 1]: a weak motor."""
    locked: bool = False
    """Held where it is when the fault is set (or the robot reset): a seized gearbox, whatever the load."""
    limp: bool = False
    """No motor torque at all (torque_scale 0): the joint swings free."""
    encoder_offset_rad: float = 0.0
    """Added to the joint's reported q (state/joints), rad, |offset| <= pi; the physics is untouched."""

    def __post_init__(self) -> None:
        if not 0 < len(self.joint) <= MAX_BODY_NAME_CHARS:
            raise ValueError(f"`joint` must be 1..{MAX_BODY_NAME_CHARS} characters")
        _check_in("torque_scale", self.torque_scale, 0.0, 1.0)
        _check_in("encoder_offset_rad", self.encoder_offset_rad, -MAX_ENCODER_OFFSET_RAD, MAX_ENCODER_OFFSET_RAD)
        if self.locked and self.limp:
            raise ValueError(f"joint {self.joint}: `locked` and `limp` together (a joint is held or free, not both)")
        if self.limp and self.torque_scale != 1.0:
            raise ValueError(f"joint {self.joint}: `limp` is torque_scale 0; give one of them")


class SensorFaults(Message, frozen=True, tag="sensor_faults", kw_only=True, forbid_unknown_fields=True):
    """Noise, bias, orientation drift and dropouts on what the robot's sensors report (state/imu,
    state/joints); the physics is untouched, and so are state/odom and state/contacts (the sim's ground truth).

    Noise is Gaussian, drawn afresh for every published state from the request's `seed`; so are dropouts.
    """

    gyro_noise_std_rad_s: float = 0.0
    """Std of the noise on each axis of Imu.gyro, rad/s, in [0, 1]."""
    gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Added to Imu.gyro (IMU frame), rad/s, each in [-1, 1]."""
    accel_noise_std_m_s2: float = 0.0
    """Std of the noise on each axis of Imu.accel, m/s^2, in [0, 10]."""
    accel_bias_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Added to Imu.accel (IMU frame), m/s^2, each in [-10, 10]."""
    q_noise_std_rad: float = 0.0
    """Std of the noise on every joint's reported q, rad, in [0, 0.5]."""
    dq_noise_std_rad_s: float = 0.0
    """Std of the noise on every joint's reported dq, rad/s, in [0, 10]."""
    orientation_drift_rad_s: float = 0.0
    """Imu.quat_wxyz turns away from the truth at this rate about `orientation_drift_axis`, rad/s, in
    [-0.1, 0.1]: after t s of sim time (since the fault was set, or the robot last reset) the reported
    orientation is the true one turned by rate x t about that world axis (the default, z: a yaw drift, what
    integrating a real gyro does). Imu.gyro and every other figure stay as they are."""
    orientation_drift_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """The world-frame axis the drift turns about (normalised by the sim), each in [-1, 1], not all 0:
    (0, 0, 1) a yaw drift, (1, 0, 0) a tilt about world x."""
    dropout_probability: float = 0.0
    """At each state instant outside a dropout, the chance a dropout starts there, in [0, 1], drawn from the
    request's `seed`: the robot's state/joints and state/imu are withheld (not published, null in a
    ctl/advance reply) for `dropout_s`. Counted in SimStatus.withheld_states."""
    dropout_s: float = 0.0
    """How long a dropout lasts, s of sim time, in [0, 10]: the state where it starts and every later one
    less than this after it are withheld; 0: that one state alone."""

    def __post_init__(self) -> None:
        _check_in("gyro_noise_std_rad_s", self.gyro_noise_std_rad_s, 0.0, MAX_GYRO_NOISE_RAD_S)
        _check_in("accel_noise_std_m_s2", self.accel_noise_std_m_s2, 0.0, MAX_ACCEL_NOISE_M_S2)
        _check_in("q_noise_std_rad", self.q_noise_std_rad, 0.0, MAX_Q_NOISE_RAD)
        _check_in("dq_noise_std_rad_s", self.dq_noise_std_rad_s, 0.0, MAX_DQ_NOISE_RAD_S)
        for i, value in enumerate(self.gyro_bias_rad_s):
            _check_in(f"gyro_bias_rad_s[{i}]", value, -MAX_GYRO_NOISE_RAD_S, MAX_GYRO_NOISE_RAD_S)
        for i, value in enumerate(self.accel_bias_m_s2):
            _check_in(f"accel_bias_m_s2[{i}]", value, -MAX_ACCEL_NOISE_M_S2, MAX_ACCEL_NOISE_M_S2)
        _check_in("orientation_drift_rad_s", self.orientation_drift_rad_s, -MAX_DRIFT_RAD_S, MAX_DRIFT_RAD_S)
        for i, value in enumerate(self.orientation_drift_axis):
            _check_in(f"orientation_drift_axis[{i}]", value, -1.0, 1.0)
        if not any(self.orientation_drift_axis):
            raise ValueError("`orientation_drift_axis` must not be (0, 0, 0): give the axis the drift turns about")
        _check_in("dropout_probability", self.dropout_probability, 0.0, 1.0)
        _check_in("dropout_s", self.dropout_s, 0.0, MAX_DROPOUT_S)


class LinkFaults(Message, frozen=True, tag="link_faults", kw_only=True, forbid_unknown_fields=True):
    """What the link between a controller and the robot does to its motor commands (cmd/motors, ctl/advance):
    it delays them by whole physics steps (sim time) and drops some; and to the states it reads: it delays them.

    Delayed and dropped after the sim's checks: a refused command is refused (and counted) as ever; a dropped
    one is counted in SimStatus.dropped_commands. The link keeps the commands' order.
    """

    command_delay_steps: int = 0
    """A command the sim accepts takes effect this many physics steps later (in sim time, real time and lockstep
    alike), in [0, 500]; 0: at the next step, as without the fault."""
    drop_probability: float = 0.0
    """Each command accepted is lost with this probability, in [0, 1], drawn from the request's `seed`."""
    state_delay_steps: int = 0
    """The robot's state/joints and state/imu (and a ctl/advance reply's) describe the instant this many physics
    steps earlier, in [0, 500] (their `sim_time_s` is that instant's, their `seq` the publication's): the newest
    reading at or before it, as states are read only every state period (real time) or advance (lockstep:
    with lockstep_steps L, a delay of ceil(k / L) advances). Until the fault (or the episode, after a reset)
    is that old, the first reading since is repeated. state/odom and state/contacts, the sim's ground truth,
    are not delayed."""

    def __post_init__(self) -> None:
        if not 0 <= self.command_delay_steps <= MAX_DELAY_STEPS:
            raise ValueError(f"`command_delay_steps` must be in [0, {MAX_DELAY_STEPS}], got {self.command_delay_steps}")
        _check_in("drop_probability", self.drop_probability, 0.0, 1.0)
        if not 0 <= self.state_delay_steps <= MAX_DELAY_STEPS:
            raise ValueError(f"`state_delay_steps` must be in [0, {MAX_DELAY_STEPS}], got {self.state_delay_steps}")


class FaultsRequest(Message, frozen=True, tag="faults_request", kw_only=True, forbid_unknown_fields=True):
    """Inject faults (ctl/faults): `set` makes the request's faults the robot's whole fault set (any set
    before is replaced: nothing of it stays), `clear` removes every fault; no verb answers the faults active.

    Checked whole before anything changes: one bad part (an unknown joint, a scale of 2, a NaN) refuses it all.
    """

    verb: FaultVerb | None = None
    """set or clear."""
    joints: tuple[JointFault, ...] = ()
    """set: the joints' faults, at most one per joint."""
    sensors: SensorFaults | None = None
    """set: the sensors' noise, bias, orientation drift and dropouts; null: exact sensors."""
    seed: int = 0
    """set: seeds the sensor noise, the dropouts and the link's drops (the same seed and commands give the same
    states), in [0, 2^63)."""
    link: LinkFaults | None = None
    """set: the link's command delay, drops and state delay; null: a perfect link."""
    at_s: float | None = None
    """Sim time to act at (set or clear), s (SimStatus.sim_time_s's clock): the request is checked now and carried out right
    before the first physics step that starts at or after it, the same step in every run (a time already past is
    refused); null: at the next step."""

    def __post_init__(self) -> None:
        _check_at(self.at_s)
        if self.at_s is not None and self.verb is None:
            raise ValueError("`at_s` goes with a verb (set or clear): a request without one only asks")
        if self.verb != "set" and (self.joints or self.sensors is not None or self.seed or self.link is not None):
            raise ValueError("`joints`, `sensors`, `link` and `seed` go with `verb: set`")
        if len(self.joints) > MAX_JOINT_FAULTS:
            raise ValueError(f"at most {MAX_JOINT_FAULTS} joint faults, got {len(self.joints)}")
        names = [fault.joint for fault in self.joints]
        if len(set(names)) != len(names):
            repeated = next(name for name in names if names.count(name) > 1)
            raise ValueError(f"joint {repeated[:64]!r} has more than one fault entry; give one per joint")
        if not 0 <= self.seed <= MAX_FAULT_SEED:
            raise ValueError(f"`seed` must be in [0, 2^63), got {self.seed}")


class FaultsState(Message, frozen=True, tag="faults_state", kw_only=True):
    """The faults a robot has now (SimStatus.faults, CtlReply.faults): what the last `set` asked for."""

    joints: tuple[JointFault, ...] = ()
    """Each faulty joint's faults."""
    sensors: SensorFaults | None = None
    """The sensors' noise, bias, orientation drift and dropouts; null: exact."""
    seed: int = 0
    """The noise's seed."""
    set_at_s: float = 0.0
    """Sim time the faults were set, s."""
    locked_q: Vector = ()
    """Where each locked joint is held, rad, in the order of `joints`' locked entries."""
    link: LinkFaults | None = None
    """The link's command delay, drops and state delay; null: a perfect link."""


# --- description -----------------------------------------------------------


class Gains(Message, frozen=True, tag="gains", kw_only=True):
    """Per-joint PD gains in canonical order."""

    kp: Vector
    """Position gains, N m/rad."""
    kd: Vector
    """Velocity gains, N m s/rad."""


class KeyInfo(Message, frozen=True, tag="key_info", kw_only=True):
    """One row of the protocol table."""

    key: str
    """Full key expression (may hold a `{placeholder}` chunk)."""
    kind: Literal["publication", "queryable", "liveliness"]
    """How the key is used."""
    message: str
    """Message type name (the struct's tag), or `float` for a bare number."""
    writer: str
    """Who writes (or serves) it."""
    reader: str
    """Who reads it."""
    rate: str
    """Nominal rate or `on demand`."""


class RobotInfo(Message, frozen=True, tag="robot_info", kw_only=True):
    """Everything a client needs to talk to this robot, served on info/robot."""

    robot: str
    """Robot id, the `{robot}` chunk of every key."""
    model: str
    """Name of the robot description (the URDF's robot name)."""
    schema_version: int
    """SCHEMA_VERSION of the serving process."""
    joint_names: tuple[str, ...]
    """Canonical joint order of every vector."""
    q_min: Vector
    """Lower joint limits, rad."""
    q_max: Vector
    """Upper joint limits, rad."""
    effort_limit: Vector
    """Torque limits, N m."""
    velocity_limit: Vector
    """Velocity limits from the description, rad/s (not enforced by the physics)."""
    default_q: dict[str, Vector]
    """Default pose per mode."""
    gains: dict[str, Gains]
    """Configured gains per mode."""
    base_height_m: dict[str, float]
    """Spawn height (floating) and base height (fixed) per mode, m."""
    mode: Mode
    """Current mode."""
    timestep_s: float
    """Physics step, s."""
    state_rate_hz: float
    """Rate of state/joints, state/odom and state/imu, Hz."""
    status_rate_hz: float
    """Rate of state/sim, Hz."""
    watchdog_timeout_s: float
    """Silence on cmd/motors after which the sim holds its safe pose, s."""
    mesh_paths: tuple[str, ...] = ()
    """Mesh files the URDF names, each served on info/mesh/{path}."""
    keys: tuple[KeyInfo, ...] = ()
    """The protocol table."""
    run_id: str = ""
    """Random id of this run of the sim process, as in SimStatus.run_id."""
    clock: Literal["realtime", "lockstep"] = "realtime"
    """The sim's clock, as in SimStatus.clock."""
    lockstep_steps: int = 0
    """Lockstep: physics steps each motor command advances (0 under the realtime clock)."""
    episode: str = ""
    """The episode (SimStatus.episode) this description was given in: a client that learns the robot
    here knows from the first SimStatus whether the sim reset meanwhile."""
    terrain: Terrain | None = None
    """The ground the robot stands on (`zensim sim --terrain`, a world file's `[terrain]`); null: the flat floor."""
    variant: Variant | None = None
    """The variant of the robot drawn at the last reset (ctl/reset `randomize`); null: the nominal robot."""
    fall_tilt_rad: float | None = None
    """The base's tilt from upright, rad, past which SimStatus says `fallen` (the robot's control.toml); null: it
    never falls (the fixed mode). A client that judges falls from state/odom uses the sim's own figure."""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        _check_unique("joint_names", self.joint_names)
        if self.fall_tilt_rad is not None:  # a description is input too (a recording, a hostile sim)
            _check_in("fall_tilt_rad", self.fall_tilt_rad, 0.0, math.pi)
        for field in ("q_min", "q_max", "effort_limit", "velocity_limit"):
            _check_length(field, getattr(self, field), n, "joint_names")
        vectors = [(f"default_q[{mode}]", q) for mode, q in self.default_q.items()]
        vectors += [(f"gains[{mode}].{name}", getattr(g, name)) for mode, g in self.gains.items() for name in ("kp", "kd")]
        for field, values in vectors:
            _check_length(field, values, n, "joint_names")
            _check_finite(field, values)


# --- lockstep (clock = lockstep) ---------------------------------------------


class AppliedCommand(Message, frozen=True, tag="applied_command", kw_only=True):
    """A motor command the lockstep sim advanced on: what it applied, from when, for how long.

    Published right after the states it led to, so a recording holds every
    command (those sent on cmd/motors and those carried by ctl/advance) at its
    exact sim time, which is what re-simulation needs.
    """

    sim_time_s: float
    """Simulation time the command took effect at (before the steps), s."""
    seq: int
    """Counts up by one per applied command; resets only when the sim restarts."""
    steps: int
    """Physics steps run with this command (the sim's `lockstep_steps`)."""
    command: MotorCommand
    """The command as received (before clamping, which the sim repeats deterministically)."""


class AdvanceReply(Message, frozen=True, tag="advance_reply", kw_only=True):
    """The answer to ctl/advance: the states of the new instant, all three together."""

    ok: bool
    """True when the command was accepted and the physics advanced."""
    error: str | None = None
    """Why not, when `ok` is false (nothing was applied then)."""
    sim_time_s: float = 0.0
    """Simulation time after the request, s."""
    steps: int = 0
    """Physics steps since the last reset, after the request."""
    joints: JointState | None = None
    """Joint state of the new instant (as published on state/joints); null while a sensor dropout withholds it
    (ctl/faults `dropout_probability`: the advance still happened)."""
    odom: Odometry | None = None
    """Base odometry of the new instant (as published on state/odom)."""
    imu: Imu | None = None
    """IMU reading of the new instant (as published on state/imu); null while a sensor dropout withholds it."""
    contacts: Contacts | None = None
    """Foot contacts of the new instant (as published on state/contacts); null from a sim that does not say."""


class WorldAdvanceRequest(Message, frozen=True, tag="world_advance_request", kw_only=True,
                          forbid_unknown_fields=True):
    """world/advance (a world under the lockstep clock): several robots' commands, one step of time for all."""

    commands: dict[str, MotorCommand] = {}
    """Robot id -> its new motor command; a robot left out keeps its held command. On a robot's own key
    (`zensim/{robot}/world/advance`) only that robot's id may appear."""


class RobotStates(Message, frozen=True, tag="robot_states", kw_only=True):
    """One robot's states of one instant, as published on its state/joints, state/odom, state/imu and state/contacts."""

    joints: JointState
    odom: Odometry
    imu: Imu
    contacts: Contacts | None = None
    """Null from a sim that does not say."""


class WorldAdvanceReply(Message, frozen=True, tag="world_advance_reply", kw_only=True):
    """The answer to world/advance: every robot's states of the new instant."""

    ok: bool
    """True when every command was accepted and the world advanced; false: nothing was applied."""
    error: str | None = None
    """Why not, when `ok` is false."""
    sim_time_s: float = 0.0
    """World time after the request, s."""
    steps: int = 0
    """Physics steps since the world's last reset."""
    states: dict[str, RobotStates] = {}
    """Robot id -> its states of the new instant (every robot of the world; on a robot's own key, that robot's),
    but those in `withheld`."""
    withheld: tuple[str, ...] = ()
    """The robots whose states of this instant a sensor dropout withholds (ctl/faults): left out of `states`."""


MAX_WORLD_ROBOTS = 256
"""Most robots a world holds (a world file's limit), and so the most world/info lists."""
RobotId = Annotated[str, msgspec.Meta(pattern=r"^[a-z0-9_-]+$", max_length=64)]
"""A robot or world id as it appears in a key (`zensim/{id}/...`): keys.check_robot_id's rule (at most
MAX_ROBOT_ID_CHARS there)."""


class WorldRobot(Message, frozen=True, tag="world_robot", kw_only=True):
    """One robot of a world, as world/info lists it."""

    robot: RobotId
    """Robot id: its keys are under zensim/{robot}/ (its info/robot describes it in full)."""
    model: str
    """Name of its description (the URDF's robot name), as RobotInfo.model."""
    mode: Mode
    """floating, or fixed (welded on a stand at its spawn)."""
    xy: tuple[float, float]
    """Spawn position of its base in the world frame, m (where it stands now: its state/odom)."""
    yaw_deg: float = 0.0
    """Spawn heading, degrees about the world's z (0 faces +x)."""

    def __post_init__(self) -> None:
        _check_finite("xy", self.xy)
        _check_finite("yaw_deg", (self.yaw_deg,))


class WorldInfo(Message, frozen=True, tag="world_info", kw_only=True):
    """A world of several robots (`zensim sim --world`), served on zensim/{world}/world/info."""

    world: RobotId
    """The world's id: its own verbs are under zensim/{world}/world/."""
    robots: Annotated[tuple[WorldRobot, ...], msgspec.Meta(max_length=MAX_WORLD_ROBOTS)]
    """Every robot of the world, in the world file's order."""
    terrain: Terrain | None = None
    """The world's ground (the world file's `[terrain]`, or `--terrain`); null: the flat floor."""


# --- terrain: the ground a robot stands on (zensim sim --terrain, a world file's [terrain]) -------------

MAX_TERRAIN_EXTENT_M = 500.0
"""Every terrain coordinate lies within this of the world's origin, m."""
MAX_FEATURE_SIZE_M = 100.0
"""Largest length, width or height of one terrain feature, m."""
MAX_TERRAIN_FEATURES = 64
"""Most features one terrain lists."""
MAX_TERRAIN_BLOCKS = 4096
"""Most solid blocks (stair steps, stepping stones, boxes) of one terrain together."""
MAX_HEIGHTFIELD_CELLS = 65_536
"""Most height-field cells of one terrain, every rough patch together (256 x 256: 12.8 m square at 5 cm)."""
MAX_STAIRS = 100
"""Most steps of one flight of stairs."""

Coord = Annotated[float, msgspec.Meta(ge=-MAX_TERRAIN_EXTENT_M, le=MAX_TERRAIN_EXTENT_M)]
"""A terrain coordinate, m, world frame."""
Size = Annotated[float, msgspec.Meta(gt=0, le=MAX_FEATURE_SIZE_M)]
"""A positive length, m."""
Heading = Annotated[float, msgspec.Meta(ge=-360, le=360)]
"""A heading, degrees about the world's z (0 faces +x, 90 faces +y)."""


class Slope(Message, frozen=True, tag="slope", kw_only=True):
    """An incline rising `angle_deg` along `direction_deg`, then an optional flat top; a wall at its far end."""

    angle_deg: Annotated[float, msgspec.Meta(gt=0, le=60)]
    """Incline, degrees above the horizontal."""
    length_m: Size
    """Horizontal run of the incline, m: it rises length_m * tan(angle_deg)."""
    width_m: Size = 2.0
    """Width across the incline, m."""
    top_m: Annotated[float, msgspec.Meta(ge=0, le=MAX_FEATURE_SIZE_M)] = 0.0
    """Length of the flat top after the incline, m (0: none)."""
    at: tuple[Coord, Coord] = (0.0, 0.0)
    """Middle of the incline's foot (where it leaves the floor), m, world x, y."""
    direction_deg: Heading = 0.0
    """Uphill heading."""

    def __post_init__(self) -> None:
        _check_finite("slope", (self.angle_deg, self.length_m, self.width_m, self.top_m, *self.at, self.direction_deg))
        rise = self.length_m * math.tan(math.radians(self.angle_deg))
        if rise > MAX_FEATURE_SIZE_M:
            raise ValueError(f"a slope of {self.angle_deg:g} deg over {self.length_m:g} m rises {rise:.4g} m "
                             f"(at most {MAX_FEATURE_SIZE_M:g})")


class Stairs(Message, frozen=True, tag="stairs", kw_only=True):
    """A flight of `count` steps and a landing at the top: going up along `direction_deg`, or (`down`) the
    landing first and the steps going down from it to the floor."""

    step_height_m: Annotated[float, msgspec.Meta(gt=0, le=1)]
    """Rise of each step, m."""
    step_depth_m: Annotated[float, msgspec.Meta(ge=0.01, le=10)]
    """Tread of each step along the direction, m."""
    count: Annotated[int, msgspec.Meta(ge=1, le=MAX_STAIRS)]
    """Number of rises: the landing stands count * step_height_m high."""
    way: Literal["up", "down"] = "up"
    """up: steps first, then the landing; down: the landing first, then the steps down."""
    width_m: Size = 2.0
    """Width across the flight, m."""
    landing_m: Annotated[float, msgspec.Meta(ge=0, le=MAX_FEATURE_SIZE_M)] = 1.0
    """Length of the landing at the top, m."""
    at: tuple[Coord, Coord] = (0.0, 0.0)
    """Middle of the flight's near edge (the first step, or the landing when down), m, world x, y."""
    direction_deg: Heading = 0.0
    """The heading the flight runs along."""

    def __post_init__(self) -> None:
        _check_finite("stairs", (self.step_height_m, self.step_depth_m, self.width_m, self.landing_m, *self.at,
                                 self.direction_deg))


class RoughGround(Message, frozen=True, tag="rough", kw_only=True):
    """A patch of rough ground: a height field with a random height in [0, amplitude_m] at each grid point
    (seeded: the same seed gives the same ground), at floor level along its border."""

    size_m: tuple[Size, Size]
    """Extent along world x and y, m."""
    amplitude_m: Annotated[float, msgspec.Meta(ge=0.001, le=1)]
    """Highest bump, m."""
    cell_m: Annotated[float, msgspec.Meta(ge=0.01, le=10)]
    """Grid spacing, m (rounded so that whole cells fill size_m)."""
    seed: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)] = 0
    """Seed of the heights."""
    at: tuple[Coord, Coord] = (0.0, 0.0)
    """Centre of the patch, m, world x, y."""

    def cells(self) -> tuple[int, int]:
        """Grid cells along x and y (at least 2 each, so the patch has an inner grid point)."""
        return tuple(max(2, round(size / self.cell_m)) for size in self.size_m)  # type: ignore[return-value]

    def __post_init__(self) -> None:
        _check_finite("rough", (*self.size_m, self.amplitude_m, self.cell_m, *self.at))
        nx, ny = self.cells()
        if nx * ny > MAX_HEIGHTFIELD_CELLS:
            raise ValueError(f"rough ground of {nx} x {ny} cells: at most {MAX_HEIGHTFIELD_CELLS} cells "
                             "(make cell_m larger or size_m smaller)")


class SteppingStones(Message, frozen=True, tag="stones", kw_only=True):
    """A grid of square stones standing `height_m` above the floor, `gap_m` apart: rows along
    `direction_deg`, columns across it."""

    rows: Annotated[int, msgspec.Meta(ge=1, le=1000)]
    """Stones along the direction."""
    columns: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 1
    """Stones across it."""
    stone_m: Annotated[float, msgspec.Meta(ge=0.01, le=10)] = 0.3
    """Side of each (square) stone, m."""
    gap_m: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.1
    """Gap between neighbouring stones, m."""
    height_m: Annotated[float, msgspec.Meta(gt=0, le=10)] = 0.1
    """Height of the stones' tops above the floor, m."""
    at: tuple[Coord, Coord] = (0.0, 0.0)
    """Middle of the grid's near edge, m, world x, y."""
    direction_deg: Heading = 0.0
    """The heading the rows run along."""

    def __post_init__(self) -> None:
        _check_finite("stones", (self.stone_m, self.gap_m, self.height_m, *self.at, self.direction_deg))


class TerrainBox(Message, frozen=True, tag="box", kw_only=True):
    """A solid box at a given pose."""

    size_m: tuple[Size, Size, Size]
    """Edge lengths along the box's own x, y, z, m."""
    pos: tuple[Coord, Coord, Coord]
    """Centre, m, world frame."""
    rpy_deg: tuple[Heading, Heading, Heading] = (0.0, 0.0, 0.0)
    """Orientation: roll about x, pitch about y, yaw about z (applied in that order, world axes), degrees."""

    def __post_init__(self) -> None:
        _check_finite("box", (*self.size_m, *self.pos, *self.rpy_deg))


TerrainFeature = Slope | Stairs | RoughGround | SteppingStones | TerrainBox
"""One feature of a terrain, told apart by its `type`."""


class Terrain(Message, frozen=True, tag="terrain", kw_only=True):
    """The ground around the robot: the flat floor (z = 0) and the features on it. No feature: flat."""

    features: Annotated[tuple[TerrainFeature, ...], msgspec.Meta(max_length=MAX_TERRAIN_FEATURES)] = ()
    """The features, each on the floor; they may overlap (the higher surface is the ground)."""

    def __post_init__(self) -> None:
        blocks = cells = 0
        for feature in self.features:
            if isinstance(feature, Stairs):
                blocks += feature.count
            elif isinstance(feature, SteppingStones):
                blocks += feature.rows * feature.columns
            elif isinstance(feature, TerrainBox):
                blocks += 1
            elif isinstance(feature, RoughGround):
                nx, ny = feature.cells()
                cells += nx * ny
        if blocks > MAX_TERRAIN_BLOCKS:
            raise ValueError(f"the terrain has {blocks} steps, stones and boxes: at most {MAX_TERRAIN_BLOCKS}")
        if cells > MAX_HEIGHTFIELD_CELLS:
            raise ValueError(f"the terrain's rough ground has {cells} cells in all: at most {MAX_HEIGHTFIELD_CELLS}")


# --- edge adapters ------------------------------------------------------------


class UnitreeStatus(Message, frozen=True, tag="unitree_status", kw_only=True):
    """Health of `zensim unitree`, the Unitree DDS adapter (rt/lowcmd, rt/lowstate), a few times a second."""

    seq: int
    """Counts up by one per published status."""
    dds_domain_id: int
    """DDS domain the adapter's participant is in."""
    dds_interface: str
    """Network interface DDS runs on; empty when Cyclone DDS chose."""
    lowcmd_received: int = 0
    """LowCmd_ samples read from rt/lowcmd since start, good or bad."""
    lowcmd_forwarded: int = 0
    """LowCmd_ samples turned into a MotorCommand on cmd/motors."""
    crc_errors: int = 0
    """LowCmd_ samples ignored because their crc did not match (as the robot ignores them)."""
    rejected: int = 0
    """LowCmd_ samples rejected whole: undecodable, bad mode_pr or motor mode, non-finite value, negative gain."""
    ab_mode_commands: int = 0
    """Accepted LowCmd_ samples with mode_pr 1 (A/B ankles), applied as pitch/roll."""
    lowstate_published: int = 0
    """LowState_ samples written on rt/lowstate."""
    lowstate_rate_hz: float = 0.0
    """LowState_ rate over the last status period, Hz (follows the sim's state_rate_hz)."""
    motion_switcher_requests: int = 0
    """Requests answered on rt/api/motion_switcher/request."""
    sim_time_s: float = 0.0
    """Sim time of the newest LowState_, s."""
    command_age_s: float | None = None
    """Wall time since the newest forwarded LowCmd_, s; null before the first one."""
    last_error: str | None = None
    """Why the most recent LowCmd_ was rejected or ignored, if one was."""
    sport_requests: int = 0
    """Requests answered on rt/api/sport/request (LocoClient), good or bad."""
    arm_sdk_received: int = 0
    """LowCmd_ samples read from rt/arm_sdk."""
    arm_sdk_rejected: int = 0
    """rt/arm_sdk samples not applied: undecodable, bad crc, non-finite value, negative gain."""
    loco_commands: int = 0
    """MotorCommands the locomotion controller put on cmd/motors."""
    loco_active: bool = False
    """True while the locomotion controller drives the robot (from the first FSM request to a ReleaseMode)."""
    loco_fsm_id: int = 0
    """The controller's FSM id (LocoClient: 0 zero torque, 1 damp, 3 sit, 500 start, 702, 706)."""
    policy_steps: int = 0
    """Steps of the walking policy run since start."""
    lowcmd_shed: int = 0
    """LowCmd_ samples read from rt/lowcmd but dropped unread because a newer one came in the same take
    (latest wins, as on cmd/motors: it would never have been applied). Not errors: counted in
    lowcmd_received, not in rejected."""
    requests_shed: int = 0
    """Requests on rt/api/sport/request and rt/api/motion_switcher/request dropped unanswered because more
    came than the adapter answers (100 a second over both, bursts of 50): a flood is shed before it costs
    the sim anything."""
    internal_errors: int = 0
    """Inputs whose handling failed in a way the adapter did not foresee (a bug): each counted, logged with
    its traceback at a bounded rate, a request answered 3202; the adapter goes on serving."""
    remote_rejected: int = 0
    """Samples on cmd/remote refused whole (not a RemoteState: an unknown button, a stick beyond -1..1, NaN)."""


class Ros1Status(Message, tag="ros1_status", frozen=True, kw_only=True):
    """Health of `zensim ros1`, the ROS 1 gateway (docs/ros.md), a few times a second."""

    seq: int
    """Counts up by one per published status."""
    master_uri: str
    """The ROS master the gateway registers with (ROS_MASTER_URI)."""
    master_up: bool = False
    """True when the master answered the gateway's last check (about once a second)."""
    master_restarts: int = 0
    """Times the gateway found a new master (a restarted roscore) and registered with it again."""
    joint_states_published: int = 0
    """sensor_msgs/JointState messages published on the joint states topic since start."""
    joint_states_rate_hz: float = 0.0
    """JointState rate over the last status period, Hz (the sim's state rate, at most `state_rate_hz`)."""
    sim_time_s: float = 0.0
    """Sim time of the newest JointState, s."""
    commands_received: int = 0
    """ROS messages read on the command topics (per-joint Float64 and the GUI's JointState), good or bad."""
    commands_forwarded: int = 0
    """Of those, the ones passed on to the bridge (cmd/joint/{joint}, cmd/joints); a GUI message in which no
    slider moved is accepted but not passed on."""
    rejected: int = 0
    """Of those, the ones refused whole: NaN or infinity, unknown joint, outside the joint's limits,
    names and positions of different lengths, a name given twice."""
    last_error: str | None = None
    """Why the most recent ROS message was refused, if one was."""
    command_age_s: float | None = None
    """Wall time since the newest forwarded command, s; null before the first one."""
    description_updates: int = 0
    """Times robot_description was set on the master (at start, after a sim or master restart)."""
    mesh_url: str = ""
    """Where the gateway serves the robot's meshes over http (robot_description points there); empty when it does not."""
    commands_shed: int = 0
    """Of those, valid ones replaced by a newer one on the same topic before their turn: each topic is passed
    on at most `command_rate_hz` times a second (the newest value always goes), so a flood never reaches
    the bridge and the sim."""


class Ros2Status(Message, tag="ros2_status", frozen=True, kw_only=True):
    """Health of `zensim ros2`, the ROS 2 face (docs/ros.md), a few times a second."""

    seq: int
    """Counts up by one per published status."""
    transports: tuple[str, ...] = ()
    """The ROS 2 transports it serves: `zenoh` (rmw_zenoh's format on zensim's router), `dds` (Cyclone DDS)."""
    domain_id: int = 0
    """The ROS domain (ROS_DOMAIN_ID) its topics are in."""
    joint_states_published: int = 0
    """sensor_msgs/JointState messages published since start (once per state, on every transport)."""
    joint_states_rate_hz: float = 0.0
    """JointState rate over the last status period, Hz (the sim's state rate, at most `state_rate_hz`)."""
    sim_time_s: float = 0.0
    """Sim time of the newest JointState, s."""
    commands_received: int = 0
    """ROS 2 messages read on the command topics (forward commands, trajectories, /cmd_vel), good or bad."""
    commands_forwarded: int = 0
    """Of those, the ones passed on to the bridge (cmd/joints)."""
    rejected: int = 0
    """Of those, the ones refused whole: bytes that are not the message (truncated, garbage CDR), a sample
    without rmw_zenoh's attachment, NaN or infinity, unknown joints, wrong lengths, outside the joint's
    limits, oversize, /cmd_vel while no walking service runs."""
    last_error: str | None = None
    """Why the most recent ROS 2 message was refused, if one was."""
    command_age_s: float | None = None
    """Wall time since the newest forwarded command, s; null before the first one."""


# --- walking: `zensim loco` (the walking controller) -------------------------------

MAX_VELOCITY: float = 10.0
"""No walking robot goes 10 m/s or turns 10 rad/s: a velocity beyond is refused whole as absurd (within
it, the walking service clips to its robot's own range, `velocity_limits` of LocoStatus)."""
MAX_VELOCITY_TIMEOUT_S: float = 864000.0
"""The longest a velocity command may hold (LocoClient.Move(continous_move=True) asks 864000 s)."""
DEFAULT_VELOCITY_TIMEOUT_S: float = 0.5
"""A velocity command lapses after this much sim time unless the next one comes: a client that died
(or lost its link) leaves a robot that stops and stands, not one that walks on."""
LocoVerb = Literal["zero_torque", "damp", "sit", "stand_up", "walk", "release"]


class VelocityCommand(Message, frozen=True, tag="velocity_command", kw_only=True, forbid_unknown_fields=True):
    """Walk: a body velocity for the walking controller (`zensim loco`), held until `timeout_s` of sim time
    passes or the next command comes (latest wins). All zero: stop stepping and stand."""

    vx: float = 0.0
    """Forward velocity in the robot's heading frame, m/s."""
    vy: float = 0.0
    """Lateral velocity, left positive, m/s."""
    wz: float = 0.0
    """Yaw rate, counter-clockwise positive, rad/s."""
    timeout_s: float = DEFAULT_VELOCITY_TIMEOUT_S
    """Sim time after which the command lapses and the robot stops, s (0..864000)."""
    at_s: float | None = None
    """Sim time from which the command holds, s: the walking controller keeps it (up to 1024 at once) and takes it
    at its first tick at or after `at_s`, the same tick in every run under lockstep; `timeout_s` counts from
    `at_s`. Null: from the tick it arrives at."""

    def __post_init__(self) -> None:
        _check_at(self.at_s)
        _check_finite("velocity", (self.vx, self.vy, self.wz, self.timeout_s))
        for name in ("vx", "vy", "wz"):
            if abs(getattr(self, name)) > MAX_VELOCITY:
                raise ValueError(f"`{name}` {getattr(self, name):.4g} is beyond +-{MAX_VELOCITY:g}: absurd for a walking robot")
        if not 0.0 <= self.timeout_s <= MAX_VELOCITY_TIMEOUT_S:
            raise ValueError(f"`timeout_s` must be in 0..{MAX_VELOCITY_TIMEOUT_S:g}, got {self.timeout_s:.4g}")


class ArmCommand(Message, frozen=True, tag="arm_command", kw_only=True, forbid_unknown_fields=True):
    """Upper-body targets blended over the walking controller's own (Unitree's rt/arm_sdk, forwarded by
    `zensim unitree`): each named joint gets weight x this + (1 - weight) x the controller's. The newest holds."""

    names: tuple[str, ...]
    """Joints the vectors address (the walking controller's upper-body joints only)."""
    weight: float
    """Blend weight, 0 (the controller alone) .. 1 (these targets alone)."""
    q: Vector
    """Target positions, rad."""
    dq: Vector
    """Target velocities, rad/s."""
    kp: Vector
    """Position gains, N m/rad."""
    kd: Vector
    """Velocity gains, N m s/rad."""
    tau: Vector
    """Feed-forward torques, N m."""

    def __post_init__(self) -> None:
        _check_unique("names", self.names)
        for field in ("q", "dq", "kp", "kd", "tau"):
            _check_length(field, getattr(self, field), len(self.names), "names")
            _check_finite(field, getattr(self, field))
        _check_finite("weight", (self.weight,))
        if not 0.0 <= self.weight <= 1.0:
            raise ValueError(f"`weight` must be in 0..1, got {self.weight:.4g}")
        _check_non_negative("kp", self.kp)
        _check_non_negative("kd", self.kd)


class LocoRequest(Message, frozen=True, tag="loco_request", kw_only=True, forbid_unknown_fields=True):
    """A walking verb for `zensim loco` (ctl/loco); an empty request changes nothing and answers the state.

    At most one of `verb` and `fsm_id`: a verb by name, or the sport service's FSM id as LocoClient sends it
    (0 zero torque, 1 damp, 3 sit, 500 start: stand and walk, 702 lie-to-stand, 706 squat-to-stand, or
    stand-to-squat while standing)."""

    verb: LocoVerb | None = None
    """zero_torque, damp (fold slowly), sit (to the squat), stand_up (to the stance, then balance), walk
    (stand up if needed, then walk at the velocity commanded), release (stop sending: another controller
    takes the motors)."""
    fsm_id: int | None = None
    """The sport service's FSM id; an id the controller does not run is refused."""
    balance_mode: int | None = None
    """LocoClient's balance mode, 0 or 1: stored and reported."""

    def __post_init__(self) -> None:
        if self.verb is not None and self.fsm_id is not None:
            raise ValueError("give `verb` or `fsm_id`, not both")
        if self.fsm_id is not None and not -(2**31) <= self.fsm_id < 2**31:
            raise ValueError("`fsm_id` is an int32")
        if self.balance_mode is not None and self.balance_mode not in (0, 1):
            raise ValueError(f"`balance_mode` is 0 or 1, got {self.balance_mode}")


class LocoStatus(Message, frozen=True, tag="loco_status", kw_only=True):
    """The walking controller's state (state/loco, and the reply of ctl/loco)."""

    seq: int = 0
    """Counts up by one per published status."""
    sim_time_s: float = 0.0
    """Sim time of the newest state the controller saw, s."""
    ok: bool = True
    """In a ctl/loco reply: false when the request was refused (then `error` says why)."""
    error: str | None = None
    """Why the request was refused (a reply), or why the latest input was (a status)."""
    active: bool = False
    """True while the controller drives the robot (from the first verb until `release`)."""
    fsm_id: int = 0
    """The FSM state as the sport service numbers it (0, 1, 3, 500, 702, 706)."""
    walking: bool = False
    """The walking policy balances the robot (stepping, or ready to step on the next command)."""
    stepping: bool = False
    """The feet move: a non-zero velocity is in force (at zero the robot stands with both feet planted)."""
    balance_mode: int = 0
    """LocoClient's balance mode, as last set."""
    commanded: Vector = (0.0, 0.0, 0.0)
    """Velocity in force (vx m/s, vy m/s, wz rad/s), after clipping; zero once it lapsed."""
    achieved: Vector = (0.0, 0.0, 0.0)
    """The base's velocity in its heading frame (vx m/s, vy m/s, wz rad/s), from state/odom."""
    command_left_s: float = 0.0
    """Sim time until the velocity command lapses, s."""
    velocity_limits: Vector = (0.0, 0.0, 0.0)
    """Largest |vx| m/s, |vy| m/s, |wz| rad/s the controller walks at (commands are clipped to them)."""
    velocity_received: int = 0
    """Samples read on cmd/velocity, good or bad."""
    velocity_refused: int = 0
    """Of those, the ones refused whole (undecodable, oversize, NaN, absurd)."""
    velocity_shed: int = 0
    """Of those, the ones replaced unread by a newer one before the controller's next tick (latest wins)."""
    requests: int = 0
    """ctl/loco requests answered."""
    requests_refused: int = 0
    """Of those, the ones refused (undecodable, unknown FSM id, wildcard key)."""
    arm_received: int = 0
    """Samples read on cmd/arms."""
    arm_refused: int = 0
    """Of those, the ones refused whole (wrong joints, gains stiffer than the controller's, out of range)."""
    commands_sent: int = 0
    """MotorCommands put on cmd/motors."""
    stall_ticks: int = 0
    """Of those, the ticks on a lockstep sim that had waited at one instant for 0.2-0.3 s of wall time with no state
    due for a tick (a state delay repeated an instant, a dropout withheld them): sent from the newest state."""
    policy_steps: int = 0
    """Steps of the walking policy run since start."""


REMOTE_BUTTONS = ("R1", "L1", "Start", "Select", "R2", "L2", "F1", "F3", "A", "B", "X", "Y", "Up", "Right", "Down", "Left")
"""The buttons of Unitree's wireless remote, in the bit order of LowState_.wireless_remote (bytes 2 and 3)."""
RemoteButton = Literal["R1", "L1", "Start", "Select", "R2", "L2", "F1", "F3", "A", "B", "X", "Y", "Up", "Right",
                       "Down", "Left"]


class RemoteState(Message, frozen=True, tag="remote_state", kw_only=True, forbid_unknown_fields=True):
    """Unitree's wireless remote as a person holds it (the viewer's keys or gamepad, any client): the buttons
    pressed and the sticks. `zensim unitree` writes it into LowState_.wireless_remote in Unitree's byte layout;
    the newest holds until the next."""

    buttons: tuple[RemoteButton, ...] = ()
    """Buttons held down."""
    lx: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.0
    """Left stick, right positive, -1..1."""
    ly: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.0
    """Left stick, forward positive, -1..1."""
    rx: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.0
    """Right stick, right positive, -1..1."""
    ry: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.0
    """Right stick, forward positive, -1..1."""

    def __post_init__(self) -> None:
        _check_finite("sticks", (self.lx, self.ly, self.rx, self.ry))
        if len(set(self.buttons)) != len(self.buttons):
            raise ValueError("`buttons` names a button more than once")


WIRE_TYPES: tuple[type[Message], ...] = (
    JointState,
    Odometry,
    Imu,
    Contacts,
    SimStatus,
    MotorCommand,
    JointTargets,
    BridgeReport,
    ResetRequest,
    PauseRequest,
    ResumeRequest,
    StepRequest,
    ModeRequest,
    CtlReply,
    PushRequest,
    BandRequest,
    FaultsRequest,
    RobotInfo,
    UnitreeStatus,
    AppliedCommand,
    AdvanceReply,
    Ros1Status,
    Ros2Status,
    WorldAdvanceRequest,
    WorldAdvanceReply,
    WorldInfo,
    VelocityCommand,
    ArmCommand,
    LocoRequest,
    LocoStatus,
    RemoteState,
)
"""Every top-level message type, in the order the docs list them."""
