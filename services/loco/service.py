"""`zensim loco`'s wiring: the walking controller (controller.py) on the sim's states, for every front end.

Reads:
    {robot}/state/joints, state/imu   JointState + Imu of one instant (paired by seq): the controller ticks
    {robot}/state/odom                Odometry: the achieved velocity state/loco reports
    {robot}/state/sim                 SimStatus: a new `run_id` is a restarted sim (the robot is learnt again)
    {robot}/cmd/velocity              VelocityCommand (any client, LocoClient via unitree, /cmd_vel via ros1)
    {robot}/cmd/arms                  ArmCommand (Unitree's rt/arm_sdk via unitree)
    {robot}/info/robot                RobotInfo, at start and after a sim restart
Writes:
    {robot}/cmd/motors                MotorCommand, every joint, one per policy period of sim time while active
    {robot}/state/loco                LocoStatus at status_rate_hz and after each ctl/loco request
    {robot}/alive/loco                liveliness token while the controller runs
Serves:
    {robot}/ctl/loco                  LocoRequest -> LocoStatus (walking verbs, the sport service's FSM ids)

One robot, one walking controller: at start the service asks whether `alive/loco` is already up for its
robot id and, if so, refuses to start with one line. A robot whose joints no bundled walking.toml
describes has no walking controller: the service says so in one line and exits 0.

Threads: the controller and its counters have one owner at a time, `_lock`. The state callback (one
subscriber on `state/*`, so one thread, as in the Unitree adapter) ticks the controller; the cmd/velocity
callback decodes each sample and keeps the newest (latest wins: a flood costs a callback and a decode each;
the rest are counted as shed), or, one with `at_s`, keeps it for its tick (velocities.py); a cmd/arms sample is checked on its callback (each refusal counted); ctl/loco is decoded and applied on its callback under
the lock. No lock is held across a zenoh put.
"""

from __future__ import annotations

import logging
import math
import sys
import threading
import time
from dataclasses import dataclass

import zenoh

from zensim.common.follow import SimRun
from zensim.common.logs import RateLimitedLog
from zensim.common.robot_info import fetch_robot
from zensim.common.session import StartupError
from zensim.common.wire import Refusals, TypedPublisher, decode_input, payload_of, reply
from zensim.robots.walking import Walking, walking_for
from zensim.schemas import (ArmCommand, Codec, DecodeError, Imu, JointState, Keys, LocoRequest, LocoStatus, MotorCommand,
                            Odometry, RobotInfo, SimStatus, VelocityCommand, bounded, is_json, topics)
from zensim.schemas.bounds import MIN_CAP_BYTES, vector_cap_bytes
from zensim.schemas.codec import Format
from zensim.schemas.messages import MAX_SCHEDULED

from .arms import ArmRules, arm_blend
from .controller import FSM_IDS, VERB_FSM, LocoController, Targets
from .settings import LocoSettings
from .velocities import ScheduledVelocities

logger = logging.getLogger("zensim.loco")

REQUEST_STATUS_PERIOD_S = 0.05
"""A ctl/loco request also puts its state on state/loco, at most this often (the reply always carries it)."""
CLAIM_CHECK_S = 1.0
"""How long the startup check for another walking controller of this robot waits."""
STALLED_STATUSES = 3
"""Statuses in a row (10 Hz, wall clock: 0.2-0.3 s) of a lockstep sim waiting at one instant, while the controller is
active, after which it ticks on its newest state. Never in a run whose every state is due (one per policy period):
there the sim waits only for the milliseconds a tick takes, so a run stays the same to the bit."""
STALL_TICK_PERIOD_S = 0.2
"""At most one stall tick per this much wall time: statuses are input too, and a flood of forged `waiting` ones must
not become a flood of commands (a real sim says it at 10 Hz)."""
GIL_SWITCH_INTERVAL_S = 0.0002
"""As in the sim and the adapter: a state callback that wakes never waits CPython's default 5 ms."""


@dataclass(frozen=True)
class Robot:
    """The sim's robot and its walking controller's settings."""

    info: RobotInfo
    name: str
    walking: Walking


class LocoService:
    """The running service (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, robot: Robot, settings: LocoSettings) -> None:
        self.keys = keys
        self.robot = robot
        self.settings = settings
        self.controller = LocoController(robot.walking)
        self._lock = threading.Lock()
        self._joints: JointState | None = None
        self._latest: tuple[JointState, Imu] | None = None
        self._odom: zenoh.Sample | None = None
        self._velocity: VelocityCommand | None = None
        """The newest velocity command without `at_s` not yet taken (latest wins)."""
        self._scheduled = ScheduledVelocities()
        """Velocity commands with `at_s`, waiting for their tick."""
        self._last_velocity_now_s = 0.0
        self._stalled: tuple[float | None, int] = (None, 0)
        self._last_stall_tick = -math.inf
        """A lockstep sim waiting at one instant: that instant, and how many statuses in a row said so."""
        self._seq = 0
        self._last_request_status = 0.0
        self.sim_run = SimRun(robot.info.run_id)
        """state/sim's run: `sim_run.restarted` is set when a restarted sim's robot must be learned again."""
        self.counts = {"velocity_received": 0, "velocity_refused": 0, "velocity_shed": 0, "requests": 0,
                       "requests_refused": 0, "arm_received": 0, "arm_refused": 0, "commands_sent": 0,
                       "stall_ticks": 0}
        self.last_error: str | None = None
        info = robot.info
        self._cap = vector_cap_bytes(info.joint_names)
        self._small_cap = MIN_CAP_BYTES
        self._arm_rules = ArmRules.of(robot.walking, info.q_min, info.q_max, info.velocity_limit, info.effort_limit)
        self._codecs: dict[str, Codec] = {"joints": Codec(JointState), "imu": Codec(Imu), "odom": Codec(Odometry),
                                          "sim": Codec(SimStatus)}
        self._velocity_codec = Codec(VelocityCommand)
        self._arm_codec = Codec(ArmCommand)
        self._request_codec = Codec(LocoRequest)
        self._reply_codec = Codec(LocoStatus)
        self._velocity_refusals = Refusals(logger, "velocity command")
        self._arm_refusals = Refusals(logger, "arm command")
        self._request_refusals = Refusals(logger, "ctl/loco request")
        self._log = RateLimitedLog(logger, 1.0)
        self._request_log = RateLimitedLog(logger, 1.0)
        self._motors = TypedPublisher.of(session, keys, topics.MOTORS)
        self._status = TypedPublisher.of(session, keys, topics.LOCO_STATUS)
        self._motors_lock = threading.Lock()
        self._routes = {keys.joints: self._on_joints, keys.imu: self._on_imu, keys.odom: self._on_odom,
                        keys.sim_status: self._on_sim_status}
        self._declared: list[zenoh.Subscriber | zenoh.Queryable] = [
            session.declare_subscriber(f"{keys.root}/state/*", self._on_state),
            session.declare_subscriber(keys.velocity, self._on_velocity),
            session.declare_subscriber(keys.arms, self._on_arm),
            session.declare_queryable(keys.ctl_loco, self._on_request),
        ]

    # --- the sim's states (one callback thread) ------------------------------------

    def _on_state(self, sample: zenoh.Sample) -> None:
        handler = self._routes.get(str(sample.key_expr))
        if handler is not None:
            handler(sample)

    def _decode_state(self, sample: zenoh.Sample, which: str):  # noqa: ANN202 - one of four types
        try:
            return decode_input(sample, self._codecs[which], self._cap)
        except DecodeError as exc:
            self._log.warning("ignoring bad state/%s: %s", which, exc)
            return None

    def _on_joints(self, sample: zenoh.Sample) -> None:
        joints = self._decode_state(sample, "joints")
        if joints is not None and len(joints.q) == len(self.robot.walking.joints):
            self._joints = joints

    def _on_imu(self, sample: zenoh.Sample) -> None:
        imu = self._decode_state(sample, "imu")
        joints = self._joints
        if imu is None or joints is None or imu.seq != joints.seq:
            return
        with self._lock:
            self._latest = (joints, imu)
            command = self._tick(force=False)
        self._put(command)

    def _on_odom(self, sample: zenoh.Sample) -> None:
        self._odom = sample  # decoded only when a status goes out

    def _on_sim_status(self, sample: zenoh.Sample) -> None:
        status = self._decode_state(sample, "sim")
        if status is None:
            return
        self.sim_run.follows(status)  # sets sim_run.restarted on a new run
        command = None
        with self._lock:
            if status.clock != "lockstep" or not status.waiting or status.paused:
                self._stalled = (None, 0)
            else:
                at, count = self._stalled
                self._stalled = (status.sim_time_s, count + 1 if at == status.sim_time_s else 1)
                now = time.monotonic()
                if (self._stalled[1] >= STALLED_STATUSES and self.controller.state.active and self._latest is not None
                        and now - self._last_stall_tick >= STALL_TICK_PERIOD_S):
                    # The lockstep sim has waited on us at one instant for a few statuses: no state came that was
                    # due for a tick (a state delay repeated an instant; a dropout withheld them). We are its clock:
                    # a command from the newest state we have moves it on, as a real controller's timer would.
                    self._stalled, self._last_stall_tick = (None, 0), now
                    self.counts["stall_ticks"] += 1
                    command = self._tick(force=True)
        self._put(command)

    def _tick(self, force: bool) -> MotorCommand | None:
        """The controller's command for the newest state, if one is due (under `_lock`)."""
        self._take_velocity()
        if self._latest is None:
            if force and self.controller.state.active:
                # No state seen yet (under lockstep the sim published its first one before we came): an
                # empty command changes nothing but, under lockstep, advances one period and so brings
                # the state the controller starts from.
                return MotorCommand(names=(), q=())
            return None
        joints, imu = self._latest
        targets = self.controller.tick(joints.sim_time_s, joints.q, joints.dq, imu.quat_wxyz, imu.gyro, force=force)
        if targets is None:
            return None
        self.counts["commands_sent"] += 1
        return _motor_command(targets)

    def _put(self, command: MotorCommand | None) -> None:
        if command is None:
            return
        try:
            with self._motors_lock:
                self._motors.put(command)
        except zenoh.ZError as exc:  # a state callback still running while the service closes
            self._log.warning("cannot put the controller's command: %s", exc)

    # --- cmd/velocity (latest wins, taken at the next tick) and cmd/arms ---------------------

    def _on_velocity(self, sample: zenoh.Sample) -> None:
        # Decoded as it comes (a few microseconds): one with `at_s` is kept for its tick, not shed by the next.
        try:
            command = decode_input(sample, self._velocity_codec, self._small_cap)
        except DecodeError as exc:
            error = self._velocity_refusals.refuse(sample.key_expr, str(exc))
            with self._lock:
                self.counts["velocity_received"] += 1
                self.counts["velocity_refused"] += 1
                self.last_error = error
            return
        with self._lock:
            self.counts["velocity_received"] += 1
            if command.at_s is not None and command.at_s > self._now_s():
                if not self._scheduled.add(command):
                    self.counts["velocity_refused"] += 1
                    self.last_error = self._velocity_refusals.refuse(
                        sample.key_expr, f"{MAX_SCHEDULED} velocity commands already wait for their `at_s`; "
                                         "this one was not kept")
                return
            if self._velocity is not None:
                self.counts["velocity_shed"] += 1
            self._velocity = command

    def _on_arm(self, sample: zenoh.Sample) -> None:
        # Each arm command is checked as it comes (not latest-wins): each one refused is counted, and the
        # sender (the Unitree adapter) reports those refusals as its own.
        try:
            command = decode_input(sample, self._arm_codec, self._cap)
            blend = arm_blend(command, self._arm_rules)
        except (DecodeError, ValueError) as exc:
            error = self._arm_refusals.refuse(sample.key_expr, str(exc))
            with self._lock:
                self.counts["arm_received"] += 1
                self.counts["arm_refused"] += 1
                self.last_error = error
            return
        with self._lock:
            self.counts["arm_received"] += 1
            self.controller.set_arm(blend)

    def _now_s(self) -> float:
        return 0.0 if self._latest is None else self._latest[0].sim_time_s

    def _take_velocity(self) -> None:
        """(under `_lock`, at each state) The newest plain command, then those whose `at_s` came, in order."""
        now = self._now_s()
        if now < self._last_velocity_now_s - 1e-9:  # sim time went back (a reset): a new episode
            self._scheduled.clear()
        self._last_velocity_now_s = now
        command, self._velocity = self._velocity, None
        due = self._scheduled.due(now) if self._scheduled else []
        for command in ([command] if command is not None else []) + due:
            # `timeout_s` counts from `at_s`: one that came late (its time past on arrival) ends when it would have.
            held_s = command.timeout_s if command.at_s is None else max(0.0, command.at_s + command.timeout_s - now)
            self.controller.set_velocity(command.vx, command.vy, command.wz, held_s, now)

    # --- ctl/loco ------------------------------------------------------------------------

    def _on_request(self, query: zenoh.Query) -> None:
        data, encoding = payload_of(query) if query.payload is not None and len(query.payload) <= self._small_cap else (b"", None)
        fmt: Format = "json" if query.payload is None or is_json(data, encoding) else "msgpack"
        own = self.keys.ctl_loco
        error = None
        command = None
        if str(query.key_expr) != own:
            # A wildcard query reaches every queryable: a control acts only when named.
            error = f"ctl/loco acts only on a query for exactly {own}; nothing was done"
        else:
            try:
                request = decode_input(query, self._request_codec, self._small_cap) if query.payload is not None \
                    else LocoRequest()
            except DecodeError as exc:
                error = str(exc)
        with self._lock:
            self.counts["requests"] += 1
            if error is None:
                was_active = self.controller.state.active
                error = self._apply(request)
                if error is None and not was_active and self.controller.state.active:
                    # The first tick goes out now, on the newest state: under lockstep nothing else would
                    # move time. Later ticks follow the states (one command per policy period of sim
                    # time), so a forced extra one would put two commands in flight.
                    command = self._tick(force=True)
            if error is not None:
                self.counts["requests_refused"] += 1
                error = self._request_refusals.refuse(query.key_expr, error)
                self.last_error = error
            status = self._status_message(ok=error is None, error=error, is_reply=True)
        self._put(command)
        reply(query, own, status, fmt, self._reply_codec)
        now = time.monotonic()
        if now - self._last_request_status >= REQUEST_STATUS_PERIOD_S:  # a flood of requests: not a status each
            self._last_request_status = now
            self._status.put(status)
        self._request_log.info("ctl/loco: %s -> %s", bounded(str(data, "utf-8", "replace"), 80),
                               "ok" if error is None else error)

    def start(self, verb: str) -> None:
        """Run a walking verb at start (the `start` setting), as a ctl/loco request would."""
        with self._lock:
            error = self._apply(LocoRequest(verb=verb))  # type: ignore[arg-type]  # a LocoVerb, from the settings
            command = self._tick(force=True) if error is None else None
        self._put(command)
        logger.info("started with %r", verb)

    def _apply(self, request: LocoRequest) -> str | None:
        """Carry a request out (under `_lock`); the reason it cannot be, or None."""
        controller = self.controller
        fsm_id = request.fsm_id if request.verb is None else VERB_FSM.get(request.verb)
        if request.fsm_id is not None and request.fsm_id not in FSM_IDS:
            return f"FSM id {request.fsm_id} is not one the controller runs ({', '.join(map(str, FSM_IDS))})"
        if request.balance_mode is not None:
            controller.state.balance_mode = request.balance_mode
        if request.verb == "release":
            controller.release()
            controller.set_arm(None)
        elif fsm_id is not None:
            controller.set_fsm(fsm_id)
        return None

    # --- status ------------------------------------------------------------------------

    def _achieved(self) -> tuple[float, float, float]:
        sample = self._odom
        if sample is None:
            return (0.0, 0.0, 0.0)
        try:
            odom: Odometry = decode_input(sample, self._codecs["odom"], self._cap)
        except DecodeError:
            return (0.0, 0.0, 0.0)
        w, x, y, z = odom.quat_wxyz
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        vx, vy = odom.lin_vel_world[0], odom.lin_vel_world[1]
        c, s = math.cos(yaw), math.sin(yaw)
        return (c * vx + s * vy, -s * vx + c * vy, float(odom.ang_vel_body[2]))

    def _status_message(self, ok: bool = True, error: str | None = None, is_reply: bool = False) -> LocoStatus:
        """The state as it is now (under `_lock`)."""
        controller, now = self.controller, self._now_s()
        state = controller.state
        command = controller.command_now(now)
        self._seq += 1
        return LocoStatus(
            seq=self._seq, sim_time_s=now, ok=ok, error=error if is_reply else self.last_error,
            active=state.active, fsm_id=state.fsm_id, walking=state.active and state.walking,
            stepping=controller.stepping(now), balance_mode=state.balance_mode,
            commanded=tuple(float(v) for v in command), achieved=self._achieved(),
            command_left_s=max(0.0, state.velocity.until_s - now) if any(command) else 0.0,
            velocity_limits=tuple(float(v) for v in self.robot.walking.max_velocity),
            policy_steps=controller.policy_steps, **self.counts,
        )

    def publish_status(self) -> None:
        with self._lock:
            status = self._status_message()
        self._status.put(status)

    def close(self) -> None:
        for declared in self._declared:
            declared.undeclare()
        self._motors.undeclare()
        self._status.undeclare()


def _motor_command(targets: Targets) -> MotorCommand:
    return MotorCommand(q=tuple(targets.q.tolist()), dq=tuple(targets.dq.tolist()), kp=tuple(targets.kp.tolist()),
                        kd=tuple(targets.kd.tolist()), tau=tuple(targets.tau.tolist()))


def robot_of(info: RobotInfo) -> Robot | None:
    """The robot with its walking controller, or None when no walking.toml describes its joints."""
    found = walking_for(tuple(info.joint_names))
    return None if found is None else Robot(info, found[0], found[1])


def other_controller(session: zenoh.Session, keys: Keys) -> bool:
    """Whether a walking controller already serves this robot id (its alive/loco token is up)."""
    return any(reply.ok is not None for reply in session.liveliness().get(keys.alive("loco"), timeout=CLAIM_CHECK_S))


def run(session: zenoh.Session, settings: LocoSettings, stop: threading.Event) -> int:
    """Learn the robot, check it walks and nobody else walks it, run the controller until `stop`.

    Returns:
        The process exit code (0 for a robot without a walking controller: nothing to do).
    """
    keys = Keys(settings.robot_id)
    if other_controller(session, keys):
        raise StartupError(f"robot {settings.robot_id!r} already has a walking controller (its alive/loco token is "
                           "up): one robot, one walking controller; stop that one, or use --robot-id")
    logger.info("asking the sim on %s", keys.robot_info)
    info = fetch_robot(session, keys, settings.info_timeout_s, stop, lambda i: i, logger)
    if info is None:
        return 0
    robot = robot_of(info)
    if robot is None:
        logger.warning("robot %r (%s, %d joints) has no walking controller (no robot folder's walking.toml has its "
                       "joints): zensim loco has nothing to do", info.robot, info.model, len(info.joint_names))
        return 0
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    service = LocoService(session, keys, robot, settings)
    if settings.start:
        service.start(settings.start)
    token = session.liveliness().declare_token(keys.alive("loco"))
    logger.info("zensim loco up: %s's walking controller (%s) for %s; cmd/velocity, ctl/loco", robot.name,
                robot.walking.weights.name, keys.root)
    period_s = 1.0 / settings.status_rate_hz
    try:
        while not stop.wait(period_s):
            if service.sim_run.restarted.is_set():
                info = fetch_robot(session, keys, settings.info_timeout_s, stop, lambda i: i, logger)
                if info is None:
                    break
                if robot_of(info) is None or tuple(info.joint_names) != robot.walking.joints:
                    logger.error("the restarted sim runs another robot (%s): exiting", info.model)
                    return 1
                with service._lock:
                    service.controller.release()
                    service.sim_run.adopt(info.run_id)
            service.publish_status()
    finally:
        token.undeclare()
        service.close()
    c = service.counts
    logger.info("%d commands sent (%d on a stalled lockstep sim); cmd/velocity %d read, %d refused, %d shed; ctl/loco "
                "%d, %d refused", c["commands_sent"], c["stall_ticks"], c["velocity_received"], c["velocity_refused"],
                c["velocity_shed"], c["requests"], c["requests_refused"])
    return 0
