"""The G1's high-level interface in the adapter: the sport service, arm_sdk and SportModeState_.

The locomotion controller (loco.py) ticks on the sim's own states: whenever the adapter completes a
JointState + Imu pair (the instant a LowState_ goes out) it hands the pair here; on a tick the controller's
targets go out on cmd/motors like any other command (so the sim, the recorder and resim see them). Sport
requests and arm_sdk commands come from the adapter's DDS thread. One lock covers the controller.

SportModeState_ (rt/odommodestate, 50 Hz of sim time; rt/lf/odommodestate, 10 Hz) is the sim's ground
truth from state/odom (the newest, pulled at that rate) and state/imu: position (world, m), body height, velocity (world, m/s), yaw speed
(body, rad/s), the IMU, `mode` 0 passive/zero torque/damp, 1 standing (ramps, balancing in place), 3
walking (a velocity in force), `stamp` the sim time.
"""

from __future__ import annotations

import logging
import threading

import numpy as np
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.wire import decode_input
from zensim.schemas import Codec, DecodeError, Imu, JointState, Keys, MotorCommand, Odometry, bounded

from . import sport
from .codec import CodecError, decode_low_cmd
from .highlevel_dds import HighLevelDds
from .idl import GoIMUState_, RequestIdentity_, Response_, ResponseHeader_, ResponseStatus_, SportModeState_, TimeSpec_
from .loco import ARM_SDK_FIRST, ARM_SDK_WEIGHT_SLOT, NUM_JOINTS, LocoController, Squat, Targets
from .lowlevel import rpy_from_wxyz

logger = logging.getLogger("zensim.unitree")

G1_FIRST_JOINTS = ("left_hip_pitch_joint", "left_hip_roll_joint", "left_hip_yaw_joint", "left_knee_joint")
ODOM_PERIOD_S = 0.02
ODOM_LF_EVERY = 5


def is_g1(joint_names: tuple[str, ...]) -> bool:
    """The controller drives the G1 29-DoF only (its motor order and the policy's leg joints)."""
    return len(joint_names) == NUM_JOINTS and joint_names[:4] == G1_FIRST_JOINTS


class HighLevelCounters:
    def __init__(self) -> None:
        self.sport_requests = 0
        self.arm_sdk_received = 0
        self.arm_sdk_rejected = 0
        self.loco_commands = 0


class HighLevel:
    """Owns the controller and the high-level DDS endpoints of one adapter.

    Args:
        session: the adapter's zenoh session (state/odom is read here).
        keys: the robot's keys.
        dds: the high-level DDS endpoints.
        publish: puts a MotorCommand on cmd/motors (the adapter's publisher).
        cap_bytes: the input size cap for state/odom.
    """

    def __init__(self, session: zenoh.Session, keys: Keys, dds: HighLevelDds, publish, cap_bytes: int) -> None:  # noqa: ANN001
        self._dds = dds
        self._publish = publish
        self._cap_bytes = cap_bytes
        self._lock = threading.Lock()
        self.controller = LocoController()
        self.counters = HighLevelCounters()
        self.enabled = False
        self._joint_names: tuple[str, ...] = ()
        self._latest: tuple[JointState, Imu] | None = None
        self._odom_codec = Codec(Odometry)
        self._next_odom_s: float | None = None
        self._odom_count = 0
        self._log = RateLimitedLog(logger, 1.0)
        self._request_log = RateLimitedLog(logger, 1.0)  # one line per request: a flood of them is bounded
        # The newest odometry only, pulled at SportModeState_'s rate from the state ticks: a Python
        # callback per 500 Hz sample would take the GIL from the DDS thread 500 times a second.
        self._odom = session.declare_subscriber(keys.odom, zenoh.handlers.RingChannel(1))

    def adopt(self, joint_names: tuple[str, ...], squat: Squat, cap_bytes: int) -> None:
        """A (new) robot: the controller runs only on the G1, and starts passive."""
        with self._lock:
            self.enabled = is_g1(joint_names)
            self.controller.squat = squat
            self._joint_names = joint_names
            self._cap_bytes = cap_bytes
            self.controller.release()
            self.controller.arm_sdk = None
            self._latest = None
        if not self.enabled:
            logger.info("the sport service and arm_sdk need the G1 29-DoF; this robot has %d joints", len(joint_names))

    # --- the sim's states (zenoh threads) --------------------------------------------

    def on_state(self, joints: JointState, imu: Imu) -> None:
        """One instant of the sim (a completed LowState_ pair): tick the controller, publish SportModeState_."""
        with self._lock:
            self._latest = (joints, imu)
            self._tick(force=False)
            message = self._odom_due(joints.sim_time_s, imu)
        if message is not None:
            try:
                self._dds.write_odom(*message)
            except Exception as exc:  # the binding's write errors are assorted
                self._log.warning("cannot write SportModeState_: %s", bounded(str(exc)))

    def _tick(self, force: bool) -> None:
        if not self.enabled:
            return
        if self._latest is None:
            if force:
                # No state seen yet (under lockstep the sim published its first one before we came):
                # an empty command changes nothing but, under lockstep, advances one period and so
                # brings the state the controller starts from.
                self._put(MotorCommand(names=(), q=()))
            return
        joints, imu = self._latest
        # Vectors are made inside, after the cheap due check: most states (450 of 500 a second) are not ticks.
        targets = self.controller.tick(joints.sim_time_s, joints.q, joints.dq, imu.quat_wxyz, imu.gyro, force=force)
        if targets is None:
            return
        self.counters.loco_commands += 1
        self._put(_motor_command(targets))

    def _put(self, command: MotorCommand) -> None:
        try:
            self._publish(command)
        except zenoh.ZError as exc:  # a state callback still running while the adapter closes
            self._log.warning("cannot put the controller's command: %s", exc)

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
        return self._sport_mode_state(odom, imu), self._odom_count % ODOM_LF_EVERY == 0

    def _sport_mode_state(self, odom: Odometry, imu: Imu) -> SportModeState_:
        state = self.controller.state
        moving = state.walking and any(self.controller.command_now(odom.sim_time_s))
        mode = 0 if not state.active or state.fsm_id in (0, 1) else (3 if moving else 1)
        seconds = int(odom.sim_time_s)
        imu_state = GoIMUState_(quaternion=list(imu.quat_wxyz), gyroscope=list(imu.gyro),
                                accelerometer=list(imu.accel), rpy=list(rpy_from_wxyz(*imu.quat_wxyz)))
        return SportModeState_(
            stamp=TimeSpec_(sec=seconds, nanosec=int((odom.sim_time_s - seconds) * 1e9)),
            imu_state=imu_state, mode=mode, gait_type=1 if moving else 0,
            position=list(odom.pos), body_height=float(odom.pos[2]), velocity=list(odom.lin_vel_world),
            yaw_speed=float(odom.ang_vel_body[2]),
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
        while True:
            try:
                request = self._dds.take_request()
            except Exception as exc:  # the binding raises assorted errors on an undecodable sample
                self._log.warning("undecodable sport request: %s", bounded(str(exc)))
                return
            if request is None:
                return
            identity = request.header.identity
            with self._lock:
                self.counters.sport_requests += 1
                if self.enabled:
                    now = 0.0 if self._latest is None else self._latest[0].sim_time_s
                    was_active = self.controller.state.active
                    code, data = sport.answer(identity.api_id, request.parameter, self.controller, now)
                    if not was_active:
                        # The first tick goes out now, on the newest state: under lockstep nothing else
                        # would move time. Later ticks follow the states (one command per 20 ms of sim
                        # time), so a forced extra one would put two commands in flight.
                        self._tick(force=True)
                else:
                    code, data = sport.RPC_ERR_SERVER_API_NOT_IMPL, ""
            self._request_log.info("sport: api %d %s -> code %d %s", identity.api_id, bounded(request.parameter, 80), code,
                        bounded(data, 80))
            if request.header.policy.noreply:
                continue
            self._dds.respond(Response_(
                header=ResponseHeader_(identity=RequestIdentity_(id=identity.id, api_id=identity.api_id),
                                       status=ResponseStatus_(code=code)),
                data=data, binary=[],
            ))

    def _handle_arm_sdk(self, data: bytes) -> None:
        error = None
        try:
            cmd = decode_low_cmd(data)
            if not cmd.crc_ok:
                error = f"crc mismatch (got {cmd.crc:#010x}): ignored, as the robot does"
            else:
                motors = cmd.motors[ARM_SDK_FIRST:NUM_JOINTS]
                weight = float(cmd.motors["q"][ARM_SDK_WEIGHT_SLOT])
                values = {f: motors[f].astype(float) for f in ("q", "dq", "kp", "kd", "tau")}
                if not (np.isfinite(weight) and all(np.all(np.isfinite(v)) for v in values.values())):
                    error = "a non-finite value"
                elif np.any(values["kp"] < 0) or np.any(values["kd"] < 0):
                    error = "a negative gain"
        except CodecError as exc:
            error = bounded(str(exc))
        with self._lock:
            self.counters.arm_sdk_received += 1
            if error is not None:
                self.counters.arm_sdk_rejected += 1
            elif self.enabled:
                self.controller.set_arm_sdk(weight=weight, **values)
        if error is not None:
            self._log.warning("LowCmd_ on rt/arm_sdk not applied: %s", error)

    def active(self) -> bool:
        """Whether the locomotion controller drives the robot (the motion switcher's CheckMode)."""
        with self._lock:
            return self.controller.state.active

    def release(self) -> None:
        """The motion switcher's ReleaseMode: the controller stops sending."""
        with self._lock:
            if self.controller.state.active:
                self._request_log.info("sport service released: the locomotion controller stops sending")
            self.controller.release()
            self.controller.arm_sdk = None

    def status_fields(self) -> dict:
        """The UnitreeStatus fields of the high-level interface."""
        with self._lock:
            c, state = self.counters, self.controller.state
            return {"sport_requests": c.sport_requests, "arm_sdk_received": c.arm_sdk_received,
                    "arm_sdk_rejected": c.arm_sdk_rejected, "loco_commands": c.loco_commands,
                    "loco_active": state.active, "loco_fsm_id": state.fsm_id,
                    "policy_steps": self.controller.policy_steps}

    def close(self) -> None:
        self._odom.undeclare()


def _motor_command(targets: Targets) -> MotorCommand:
    return MotorCommand(q=tuple(targets.q.tolist()), dq=tuple(targets.dq.tolist()), kp=tuple(targets.kp.tolist()),
                        kd=tuple(targets.kd.tolist()), tau=tuple(targets.tau.tolist()))
