"""The G1's high-level interface in the adapter: the sport service, arm_sdk and SportModeState_.

The walking controller is its own service, `zensim loco` (services/loco/): the sport service forwards
to it over Zenoh, as any other front end does. SetFsmId and SetBalanceMode are ctl/loco queries (answered
from the controller's reply: an id it does not run is a 3204), SetVelocity a put on cmd/velocity
(duration = its timeout), the Get calls read the controller's newest state (state/loco, or the reply of
the last query); rt/arm_sdk commands are checked here and forwarded on cmd/arms. The motion switcher's
CheckMode asks ctl/loco whether the controller is active, its ReleaseMode sends `release`. While no
walking controller answers, sport requests get 3203 (not implemented) and a bounded log line says why.

SportModeState_ (rt/odommodestate, 50 Hz of sim time; rt/lf/odommodestate, 10 Hz) is the sim's ground
truth from state/odom (the newest, pulled at that rate) and state/imu: position (world, m), body height, velocity (world, m/s), yaw speed
(body, rad/s), the IMU, `mode` 0 passive/zero torque/damp, 1 standing (ramps, balancing in place), 3
walking (a velocity in force and the feet stepping), `stamp` the sim time. `foot_force` is the sim's
state/contacts (the newest): each foot's summed contact normal force in N, rounded and held within int16,
the robot's feet in their order (the G1: [0] left, [1] right; [2] and [3], a quadruped's hind feet, stay 0).
"""

from __future__ import annotations

import logging
import math
import threading

import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.wire import TypedPublisher, decode_input, error_text, read_payload
from zensim.schemas import (ArmCommand, Codec, Contacts, DecodeError, Imu, JointState, Keys, LocoRequest, LocoStatus,
                            Odometry, VelocityCommand, bounded, topics)
from zensim.schemas.bounds import MIN_CAP_BYTES
from zensim.schemas.messages import MAX_VELOCITY, MAX_VELOCITY_TIMEOUT_S

from . import sport
from .codec import CodecError, decode_low_cmd
from .highlevel_dds import HighLevelDds
from .idl import GoIMUState_, Request_, RequestIdentity_, Response_, ResponseHeader_, ResponseStatus_, SportModeState_, TimeSpec_
from .lowlevel import rpy_from_wxyz
from .requests import REQUESTS_PER_S, RequestBudget

logger = logging.getLogger("zensim.unitree")

ODOM_PERIOD_S = 0.02
ODOM_LF_EVERY = 5
ARM_SDK_FIRST = 12
"""rt/arm_sdk carries motors 12..28 (the G1's waist and arms)."""
ARM_SDK_LAST = 28
ARM_SDK_WEIGHT_SLOT = 29
"""kNotUsedJoint: its q is the arm_sdk weight."""
WALKER_TIMEOUT_S = 1.0
"""Longest a sport request waits for the walking controller's answer on ctl/loco."""
FOOT_FORCE_SLOTS = 4
"""SportModeState_.foot_force (unitree_go's layout, a quadruped's four feet)."""
INT16_MAX = 32767


def foot_force(contacts: Contacts | None) -> list[int]:
    """SportModeState_.foot_force from the sim's contacts: each foot's normal force, N, rounded, within int16,
    the feet in the robot's order; zeros without contacts (none seen yet, or a robot without feet). A state is
    anyone's to publish: a value that is no force (NaN, negative) reads 0, one beyond int16 its largest."""
    forces = [] if contacts is None else list(contacts.normal_force_n[:FOOT_FORCE_SLOTS])
    return ([min(INT16_MAX, round(force)) if force > 0 and math.isfinite(force) else 0 for force in forces]
            + [0] * (FOOT_FORCE_SLOTS - len(forces)))


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class ZenohWalker:
    """The walking controller (`zensim loco`) reached over Zenoh: sport.Walker for the sport service.

    `status` is the newest LocoStatus seen, from state/loco or a ctl/loco reply (by `seq`: the service
    counts both), so a Get right after a Set sees the Set.
    """

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self._session = session
        self._keys = keys
        self._request_codec = Codec(LocoRequest)
        self._status_codec = Codec(LocoStatus)
        self._lock = threading.Lock()
        self._latest: LocoStatus | None = None
        self._log = RateLimitedLog(logger, 5.0)
        self._velocity = TypedPublisher.of(session, keys, topics.VELOCITY)
        self._arms = TypedPublisher.of(session, keys, topics.ARMS)
        self._subscriber = session.declare_subscriber(keys.loco_status, self._on_status)
        # Whether a walking controller is up (its alive/loco token): without one a request fails at once
        # instead of holding the DDS thread for WALKER_TIMEOUT_S (rt/lowcmd waits behind it).
        self._present = threading.Event()
        self._alive = session.liveliness().declare_subscriber(keys.alive("loco"), self._on_alive, history=True)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._present.set()
        else:
            self._present.clear()

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            self._keep(decode_input(sample, self._status_codec, MIN_CAP_BYTES))
        except DecodeError as exc:
            self._log.warning("ignoring bad LocoStatus: %s", exc)

    def _keep(self, status: LocoStatus) -> None:
        with self._lock:
            if self._latest is None or status.seq >= self._latest.seq:
                self._latest = status

    def latest(self) -> LocoStatus | None:
        """The newest state seen, or None before any (no walking controller heard from)."""
        with self._lock:
            return self._latest

    def status(self) -> LocoStatus:
        latest = self.latest()
        return latest if latest is not None else self.request()

    def request(self, fsm_id: int | None = None, balance_mode: int | None = None, verb: str | None = None) -> LocoStatus:
        if not self._present.is_set():
            self._log.warning("no walking controller is up for this robot (start `zensim loco`): sport requests get %d",
                              sport.RPC_ERR_SERVER_API_NOT_IMPL)
            raise sport.NoWalker("no walking controller is up")
        payload = self._request_codec.encode(LocoRequest(fsm_id=fsm_id, balance_mode=balance_mode, verb=verb),  # type: ignore[arg-type]
                                             "msgpack")
        for reply in self._session.get(self._keys.ctl_loco, payload=payload, timeout=WALKER_TIMEOUT_S):
            if reply.ok is None:
                self._log.warning("ctl/loco answered an error: %s", error_text(reply.err))
                continue
            try:
                status = self._status_codec.decode(*read_payload(reply.ok, MIN_CAP_BYTES))
            except DecodeError as exc:
                self._log.warning("unusable ctl/loco reply: %s", exc)
                continue
            self._keep(status)
            return status
        self._log.warning("no walking controller answers on %s (start `zensim loco`): sport requests get %d",
                          self._keys.ctl_loco, sport.RPC_ERR_SERVER_API_NOT_IMPL)
        raise sport.NoWalker("no walking controller answers")

    def velocity(self, vx: float, vy: float, wz: float, duration_s: float) -> None:
        if not self._present.is_set():
            raise sport.NoWalker("no walking controller is up")
        # LocoClient may ask up to 1e9 (the controller clips to its robot's range): the wire takes +-10.
        self._velocity.put(VelocityCommand(vx=_clip(vx, MAX_VELOCITY), vy=_clip(vy, MAX_VELOCITY),
                                           wz=_clip(wz, MAX_VELOCITY), timeout_s=min(duration_s, MAX_VELOCITY_TIMEOUT_S)))

    def arms(self, command: ArmCommand) -> None:
        self._arms.put(command)

    def close(self) -> None:
        self._subscriber.undeclare()
        self._alive.undeclare()
        self._velocity.undeclare()
        self._arms.undeclare()


class HighLevelCounters:
    def __init__(self) -> None:
        self.sport_requests = 0
        self.requests_shed = 0
        self.internal_errors = 0
        self.arm_sdk_received = 0
        self.arm_sdk_rejected = 0


class HighLevel:
    """The high-level DDS endpoints of one adapter, forwarding to the walking controller.

    Args:
        session: the adapter's zenoh session (state/odom, state/loco, ctl/loco, cmd/velocity, cmd/arms).
        keys: the robot's keys.
        dds: the high-level DDS endpoints.
        cap_bytes: the input size cap for state/odom.
        budget: the requests the adapter answers (shared with the motion switcher; requests.py).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, dds: HighLevelDds, cap_bytes: int,
                 budget: RequestBudget) -> None:
        self._dds = dds
        self._budget = budget
        self._cap_bytes = cap_bytes
        self._lock = threading.Lock()
        self.walker = ZenohWalker(session, keys)
        self.counters = HighLevelCounters()
        self._arm_names: tuple[str, ...] = ()
        self._odom_codec = Codec(Odometry)
        self._next_odom_s: float | None = None
        self._odom_count = 0
        self._log = RateLimitedLog(logger, 1.0)
        self._request_log = RateLimitedLog(logger, 1.0)  # one line per request: a flood of them is bounded
        self._shed_log = RateLimitedLog(logger, 1.0)
        self._error_log = RateLimitedLog(logger, 1.0)
        # The newest odometry only, pulled at SportModeState_'s rate from the state ticks: a Python
        # callback per 500 Hz sample would take the GIL from the DDS thread 500 times a second.
        self._odom = session.declare_subscriber(keys.odom, zenoh.handlers.RingChannel(1))
        # The feet's contacts the same way (foot_force); the newest decoded one is kept between odometries.
        self._contacts_codec = Codec(Contacts)
        self._contacts_sub = session.declare_subscriber(keys.contacts, zenoh.handlers.RingChannel(1))
        self._contacts: Contacts | None = None

    def adopt(self, joint_names: tuple[str, ...], cap_bytes: int) -> None:
        """A (new) robot: rt/arm_sdk's motors 12..28 are its joints 12..28 (a robot with fewer has no arm_sdk).

        Args:
            joint_names: the robot's joints, canonical order.
            cap_bytes: the input size cap for state/odom.
        """
        with self._lock:
            self._cap_bytes = cap_bytes
            self._arm_names = joint_names[ARM_SDK_FIRST:ARM_SDK_LAST + 1] if len(joint_names) > ARM_SDK_LAST else ()

    # --- the sim's states (zenoh threads) --------------------------------------------

    def on_state(self, joints: JointState, imu: Imu) -> None:
        """One instant of the sim (a completed LowState_ pair): publish SportModeState_ when due."""
        with self._lock:
            message = self._odom_due(joints.sim_time_s, imu)
        if message is not None:
            try:
                self._dds.write_odom(*message)
            except Exception as exc:  # the binding's write errors are assorted
                self._log.warning("cannot write SportModeState_: %s", bounded(str(exc)))

    def _odom_due(self, now_s: float, imu: Imu) -> tuple[SportModeState_, bool] | None:
        """SportModeState_ from the newest odometry, every ODOM_PERIOD_S of sim time (None between)."""
        if self._next_odom_s is not None and self._next_odom_s - 2 * ODOM_PERIOD_S <= now_s < self._next_odom_s - 1e-9:
            return None  # (sim time going back, a reset, starts the schedule over)
        sample = self._odom.try_recv()
        if sample is None:
            return None
        try:
            odom = decode_input(sample, self._odom_codec, self._cap_bytes)
        except DecodeError as exc:
            self._log.warning("ignoring bad Odometry: %s", exc)
            return None
        self._next_odom_s = now_s + ODOM_PERIOD_S
        self._odom_count += 1
        contacts = self._contacts_sub.try_recv()
        if contacts is not None:
            try:
                self._contacts = decode_input(contacts, self._contacts_codec, self._cap_bytes)
            except DecodeError as exc:
                self._log.warning("ignoring bad Contacts: %s", exc)
        return self._sport_mode_state(odom, imu), self._odom_count % ODOM_LF_EVERY == 0

    def _sport_mode_state(self, odom: Odometry, imu: Imu) -> SportModeState_:
        state = self.walker.latest()
        moving = state is not None and state.stepping and any(state.commanded)
        mode = 0 if state is None or not state.active or state.fsm_id in (0, 1) else (3 if moving else 1)
        seconds = int(odom.sim_time_s)
        imu_state = GoIMUState_(quaternion=list(imu.quat_wxyz), gyroscope=list(imu.gyro),
                                accelerometer=list(imu.accel), rpy=list(rpy_from_wxyz(*imu.quat_wxyz)))
        return SportModeState_(
            stamp=TimeSpec_(sec=seconds, nanosec=int((odom.sim_time_s - seconds) * 1e9)),
            imu_state=imu_state, mode=mode, gait_type=1 if moving else 0,
            position=list(odom.pos), body_height=float(odom.pos[2]), velocity=list(odom.lin_vel_world),
            yaw_speed=float(odom.ang_vel_body[2]), foot_force=foot_force(self._contacts),
        )

    # --- DDS (the adapter's DDS thread) --------------------------------------------------

    def poll(self) -> None:
        """Answer waiting sport requests and take arm_sdk commands."""
        if self._dds.has_request():
            self._handle_requests()
        if self._dds.has_arm_sdk():
            for data in self._dds.take_arm_sdk():
                self._handle_arm_sdk(data)

    def _handle_requests(self) -> None:
        """Take every waiting sport request; answer those the budget admits (requests.py), shed the rest."""
        intake = self._budget.admit(self._dds.take_requests())
        with self._lock:
            self.counters.requests_shed += intake.shed
        if intake.shed:
            self._shed_log.warning("sport: %d request(s) shed unanswered (more than %g a second come in)",
                                   intake.shed, REQUESTS_PER_S)
        for why in intake.undecodable:
            self._log.warning("undecodable sport request: %s", why)
        for request in intake.requests:
            self._answer(request)

    def _answer(self, request: Request_) -> None:
        """Forward one sport request and answer it. A failure nobody foresaw is answered 3202 (the SDK's
        server-internal error), counted and logged with its traceback at a bounded rate: one request
        never ends the thread that serves the others (a 400-digit integer once did)."""
        identity = request.header.identity
        with self._lock:
            self.counters.sport_requests += 1
        try:
            # No lock held: the walking controller's answer comes over the network.
            code, data = sport.answer(identity.api_id, request.parameter, self.walker)
        except Exception:
            with self._lock:
                self.counters.internal_errors += 1
            self._error_log.exception("sport request (api %d) failed: answered %d, counted in internal_errors",
                                      identity.api_id, sport.RPC_ERR_SERVER_INTERNAL)
            code, data = sport.RPC_ERR_SERVER_INTERNAL, ""
        self._request_log.info("sport: api %d %s -> code %d %s", identity.api_id, bounded(request.parameter, 80), code,
                               bounded(data, 80))
        if request.header.policy.noreply:
            return
        self._dds.respond(Response_(
            header=ResponseHeader_(identity=RequestIdentity_(id=identity.id, api_id=identity.api_id),
                                   status=ResponseStatus_(code=code)),
            data=data, binary=[],
        ))

    def _handle_arm_sdk(self, data: bytes) -> None:
        """Check one rt/arm_sdk LowCmd_ (decode, crc, finite, non-negative gains) and forward it on cmd/arms;
        the walking controller checks it against the robot (gains, limits) and counts what it refuses."""
        error = None
        command = None
        try:
            cmd = decode_low_cmd(data)
            if not cmd.crc_ok:
                error = f"crc mismatch (got {cmd.crc:#010x}): ignored, as the robot does"
            elif not self._arm_names:
                error = "this robot has no motors 12..28"
            else:
                motors = cmd.motors[ARM_SDK_FIRST:ARM_SDK_LAST + 1]
                weight = float(cmd.motors["q"][ARM_SDK_WEIGHT_SLOT])
                values = {f: tuple(motors[f].astype(float).tolist()) for f in ("q", "dq", "kp", "kd", "tau")}
                # The weight is clipped to [0, 1], as the robot does; everything else is refused when bad.
                weight = max(0.0, min(1.0, weight)) if weight == weight else weight
                command = ArmCommand(names=self._arm_names, weight=weight, **values)
        except CodecError as exc:
            error = bounded(str(exc))
        except ValueError as exc:  # ArmCommand's own checks: a non-finite value, a negative gain
            error = bounded(str(exc))
            command = None
        with self._lock:
            self.counters.arm_sdk_received += 1
            if error is not None:
                self.counters.arm_sdk_rejected += 1
        if error is not None:
            self._log.warning("LowCmd_ on rt/arm_sdk not applied: %s", error)
        elif command is not None:
            self.walker.arms(command)

    def active(self) -> bool:
        """Whether the walking controller drives the robot (the motion switcher's CheckMode)."""
        try:
            return self.walker.request().active
        except sport.NoWalker:
            return False

    def release(self) -> None:
        """The motion switcher's ReleaseMode: the walking controller stops sending."""
        try:
            if self.walker.request(verb="release").ok:
                self._request_log.info("sport service released: the walking controller stops sending")
        except sport.NoWalker:
            pass

    def status_fields(self) -> dict:
        """The UnitreeStatus fields of the high-level interface (the controller's from its newest state)."""
        loco = self.walker.latest() or LocoStatus()
        with self._lock:
            c = self.counters
            return {"sport_requests": c.sport_requests, "arm_sdk_received": c.arm_sdk_received,
                    # arm_sdk commands the walking controller refused (its own checks) count as rejected too
                    "arm_sdk_rejected": c.arm_sdk_rejected + loco.arm_refused, "loco_commands": loco.commands_sent,
                    "loco_active": loco.active, "loco_fsm_id": loco.fsm_id,
                    "policy_steps": loco.policy_steps, "requests_shed": c.requests_shed,
                    "internal_errors": c.internal_errors}

    def close(self) -> None:
        self._odom.undeclare()
        self._contacts_sub.undeclare()
        self.walker.close()
