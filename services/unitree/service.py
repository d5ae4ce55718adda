"""The Unitree adapter's wiring: Unitree's DDS topics on one side, zensim's Zenoh keys on the other.

Reads:
    rt/lowcmd (DDS)                   LowCmd_: CRC checked, validated, forwarded to cmd/motors
    rt/api/motion_switcher/request    Request_: answered (switcher.py)
    {robot}/state/joints, state/imu   JointState + Imu of one instant -> one LowState_
    {robot}/info/robot                RobotInfo, queried at start and after a sim restart (the joint order)
    {robot}/state/sim                 SimStatus: a new `run_id` means a new sim, perhaps another robot
    {robot}/cmd/remote                RemoteState: Unitree's wireless remote, into LowState_.wireless_remote
Writes:
    rt/lowstate (DDS)                 LowState_, one per sim state (500 Hz sim states: 500 Hz LowState_)
    rt/lf/lowstate (DDS)              the same LowState_ every 20 ms of sim time (the low-frequency copy)
    rt/api/motion_switcher/response   Response_
    {robot}/cmd/motors                MotorCommand, every joint, one per accepted LowCmd_
    {robot}/state/unitree             UnitreeStatus at status_rate_hz
    {robot}/alive/unitree             liveliness token, once the robot is known
The G1's high-level API (highlevel.py: rt/api/sport/*, rt/arm_sdk, rt/odommodestate) shares the
participant and the DDS thread; it forwards to the walking controller, `zensim loco` (ctl/loco,
cmd/velocity, cmd/arms; its state on state/loco).

A DDS thread waits on both DDS readers; one zenoh callback thread (one subscriber on `state/*`)
builds LowState_. Nothing queues: a LowCmd_ is forwarded as soon as it is read, a LowState_ written
as soon as its pair is complete.

LowCmd_ floods are shed as on the Zenoh path (the sim's command thread): latest wins. The DDS thread
takes rt/lowcmd at most once per LOWCMD_TAKE_PERIOD_S, decodes and forwards only the newest sample of
each take and counts the others as shed (UnitreeStatus.lowcmd_shed), unread: however fast a flood
comes, it costs at most one decode and one cmd/motors put per ms, and the sim keeps time. (Before,
Cyclone's default one-sample reader history dropped most of a flood silently and the rest, ~1800 a
second at 10 kHz, all went on to the sim.) The price: a LowCmd_ that comes less than 1 ms after the
previous take waits for the rest of that ms; a controller at 1 kHz or slower never does.

Latency (benchmarks/unitree_latency.py, docs/benchmarks.md): the state path is one thread, so a
JointState and the Imu the sim sends right after it are handled in order on the thread that already
runs, with no hand-over between two callback threads (each a wake-up and a GIL transfer, and with two
threads a lagging one made pairs miss: 320-415 LowState_ a second instead of 500 on a loaded machine);
and the GIL switch interval is short, as in the sim, so a thread that wakes for a LowCmd_ or a state
never waits the default 5 ms for another that holds it.

`_lock` guards the builder and the counters only, and is never held across a DDS write or a zenoh
put (a write that blocks would stall the thread reading rt/lowcmd behind it); `_write_lock`
keeps LowState_ writes in the order their pairs completed (docs/architecture.md, "Threads").
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from zensim.common.follow import SimRun
from zensim.common.logs import RateLimitedLog
from zensim.common.pacing import GIL_SWITCH_INTERVAL_S
from zensim.common.robot_info import fetch_robot
from zensim.common.wire import TypedPublisher, decode_input
from zensim.schemas import (Codec, DecodeError, Imu, JointState, Keys, RemoteState, RobotInfo, SimStatus, UnitreeStatus, bounded,
                            topics)
from zensim.schemas.bounds import MIN_CAP_BYTES, vector_cap_bytes

from . import switcher
from .codec import NUM_MOTORS, CodecError, decode_low_cmd
from .dds import UnitreeDds
from .highlevel import HighLevel
from .highlevel_dds import HighLevelDds
from .idl import RequestIdentity_, Response_, ResponseHeader_, ResponseStatus_
from .lowlevel import LowCmdError, LowStateBuilder, motor_command, wireless_remote
from .requests import REQUESTS_PER_S, RequestBudget
from .settings import UnitreeSettings

logger = logging.getLogger("zensim.unitree")

DDS_WAIT_S = 0.1
"""Longest the DDS thread blocks before it looks at the stop flag."""
LOWCMD_TAKE_PERIOD_S = 0.001
"""Shortest wall time between two takes of rt/lowcmd. A controller at 500 Hz or 1 kHz (the SDK's
examples) sends slower than this and never waits; a faster one has its older samples shed."""
LOWSTATE_LF_PERIOD_S = 0.02
"""rt/lf/lowstate, the low-frequency copy of LowState_: one per 20 ms of sim time (50 Hz)."""


@dataclass(frozen=True)
class Robot:
    """What the adapter knows of the sim's robot."""

    joint_names: tuple[str, ...]
    """The canonical joint order: LowCmd_/LowState_ motor i is joint i."""
    run_id: str
    """The sim run that described it (RobotInfo.run_id)."""

    @classmethod
    def from_info(cls, info: RobotInfo) -> Robot:
        """Raises ValueError for a robot with more joints than LowCmd_ has motor slots."""
        if len(info.joint_names) > NUM_MOTORS:
            raise ValueError(f"the robot has {len(info.joint_names)} joints; LowCmd_ has {NUM_MOTORS} motor slots")
        return cls(tuple(info.joint_names), info.run_id)


class Counters:
    """What the status reports; updated under the adapter's lock."""

    def __init__(self) -> None:
        self.lowcmd_received = 0
        self.lowcmd_forwarded = 0
        self.lowcmd_shed = 0
        self.crc_errors = 0
        self.rejected = 0
        self.ab_mode_commands = 0
        self.lowstate_published = 0
        self.motion_switcher_requests = 0
        self.requests_shed = 0
        self.internal_errors = 0
        """Inputs whose handling raised an error nobody foresaw (a bug): counted, logged, survived."""
        self.remote_rejected = 0
        self.sim_time_s = 0.0
        self.last_command: float | None = None  # monotonic time of the newest forwarded LowCmd_
        self.last_error: str | None = None


class UnitreeAdapter:
    """The running adapter (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, robot: Robot, settings: UnitreeSettings,
                 dds: UnitreeDds) -> None:
        self._settings = settings
        self._dds = dds
        self._lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._built = 0  # LowState_ pairs completed (under _lock); the write order
        self._written = 0  # the newest pair written (under _write_lock)
        self.counters = Counters()
        self.sim_run = SimRun(robot.run_id)
        """state/sim's run: `sim_run.restarted` is set when another sim run's robot must be learned again."""
        self.highlevel: HighLevel | None = None
        self.adopt(robot)
        self._joints_codec = Codec(JointState)
        self._imu_codec = Codec(Imu)
        self._sim_codec = Codec(SimStatus)
        self._reject_log = RateLimitedLog(logger, 1.0)
        self._request_log = RateLimitedLog(logger, 1.0)
        self._state_log = RateLimitedLog(logger, 5.0)
        self._shed_log = RateLimitedLog(logger, 1.0)
        self._error_log = RateLimitedLog(logger, 1.0)
        self._budget = RequestBudget()
        self._ab_logged = False
        self._motors = TypedPublisher.of(session, keys, topics.MOTORS)
        self._status = TypedPublisher.of(session, keys, topics.UNITREE_STATUS)
        self._motors_lock = threading.Lock()
        # The sport service, arm_sdk and SportModeState_ (highlevel.py): forwarded to `zensim loco`.
        self.highlevel = HighLevel(session, keys, HighLevelDds(dds), self._cap_bytes, self._budget)
        self.highlevel.adopt(robot.joint_names, self._cap_bytes)
        # One subscriber, so one callback thread, for the sim's states: see the module docstring.
        # Other state/* keys (odom, the adapter's own status) are dropped by the key lookup.
        self._state_routes = {keys.joints: self._on_joints, keys.imu: self._on_imu,
                              keys.sim_status: self._on_sim_status}
        self._remote_codec = Codec(RemoteState)
        self._next_lf_s: float | None = None
        self._subscribers = [session.declare_subscriber(f"{keys.root}/state/*", self._on_any_state),
                             session.declare_subscriber(keys.remote, self._on_remote)]

    def adopt(self, robot: Robot) -> None:
        """Take `robot` (at start, and after a sim restart): its joint order is the motor order."""
        with self._lock:
            self._robot = robot
            self._builder = LowStateBuilder(len(robot.joint_names), self._settings.mode_machine)
            self._cap_bytes = vector_cap_bytes(robot.joint_names)
            self.sim_run.adopt(robot.run_id)
        if self.highlevel is not None:
            self.highlevel.adopt(robot.joint_names, self._cap_bytes)

    # --- zensim -> DDS (the state callback thread) ---------------------------------

    def _on_any_state(self, sample: zenoh.Sample) -> None:
        handler = self._state_routes.get(str(sample.key_expr))
        if handler is not None:
            handler(sample)

    def _on_joints(self, sample: zenoh.Sample) -> None:
        self._on_state(sample, self._joints_codec, "joints")

    def _on_imu(self, sample: zenoh.Sample) -> None:
        self._on_state(sample, self._imu_codec, "imu")

    def _on_sim_status(self, sample: zenoh.Sample) -> None:
        try:
            status = decode_input(sample, self._sim_codec, self._cap_bytes)
        except DecodeError as exc:
            self._state_log.warning("ignoring bad SimStatus: %s", exc)
            return
        self.sim_run.follows(status)  # sets sim_run.restarted on a new run; the episode means nothing here

    def _on_state(self, sample: zenoh.Sample, codec: Codec, which: str) -> None:
        try:
            message = decode_input(sample, codec, self._cap_bytes)
            with self._lock:
                data = getattr(self._builder, which)(message)
                if data is None:
                    return
                self._built += 1
                order = self._built
            with self._write_lock:
                if order < self._written:  # the other state thread wrote a newer pair meanwhile
                    return
                self._written = order
                self._dds.write_lowstate(data)
                if self._lf_due(message.sim_time_s):
                    self._dds.write_lowstate_lf(data)
            with self._lock:
                self.counters.lowstate_published += 1
                self.counters.sim_time_s = message.sim_time_s
                pair = self._builder.pair()
        except (DecodeError, ValueError, OSError) as exc:
            self._state_log.warning("cannot turn state/%s into LowState_: %s", which, exc)
            return
        if pair is not None and self.highlevel is not None:
            self.highlevel.on_state(*pair)  # SportModeState_ at its rate

    def _lf_due(self, now_s: float) -> bool:
        """Whether this LowState_ also goes out on rt/lf/lowstate: every LOWSTATE_LF_PERIOD_S of sim time
        (sim time going back, a reset, starts the schedule over). Called under `_write_lock`."""
        due = self._next_lf_s is None or now_s >= self._next_lf_s - 1e-9 or now_s < self._next_lf_s - 2 * LOWSTATE_LF_PERIOD_S
        if due:
            self._next_lf_s = now_s + LOWSTATE_LF_PERIOD_S
        return due

    def _on_remote(self, sample: zenoh.Sample) -> None:
        """cmd/remote: the newest remote state goes into every LowState_ after it (wireless_remote)."""
        try:
            remote = wireless_remote(decode_input(sample, self._remote_codec, MIN_CAP_BYTES))
        except DecodeError as exc:
            with self._lock:
                self.counters.remote_rejected += 1
            self._reject_log.warning("RemoteState on cmd/remote not applied: %s", exc)
            return
        with self._lock:
            self._builder.remote = remote

    # --- DDS -> zensim (the DDS thread) --------------------------------------------

    def handle_lowcmd(self, data: bytes, shed: int = 0) -> None:
        """Check one serialized LowCmd_ and forward it, or count why not.

        Args:
            data: the newest LowCmd_ of a take.
            shed: how many older ones that take held (counted as read and shed, not decoded).
        """
        command = None
        error = None
        crc_error = False
        try:
            low_cmd = decode_low_cmd(data)
            if not low_cmd.crc_ok:
                crc_error = True
                error = f"crc mismatch (got {low_cmd.crc:#010x}): ignored, as the robot does"
            else:
                command = motor_command(low_cmd, self._robot.joint_names)
        except (CodecError, LowCmdError) as exc:
            error = bounded(str(exc))
        with self._lock:
            c = self.counters
            c.lowcmd_received += 1 + shed
            c.lowcmd_shed += shed
            if command is None:
                if crc_error:
                    c.crc_errors += 1
                else:
                    c.rejected += 1
                c.last_error = error
            else:
                c.lowcmd_forwarded += 1
                c.last_command = time.monotonic()
                if command.ab_mode:
                    c.ab_mode_commands += 1
                self._builder.mode_pr = 1 if command.ab_mode else 0
        if command is None:
            self._reject_log.warning("LowCmd_ on rt/lowcmd not applied: %s", error)
            return
        if command.ab_mode and not self._ab_logged:
            self._ab_logged = True
            logger.warning("LowCmd_ with mode_pr 1 (A/B ankles): zensim simulates pitch/roll ankles and "
                           "applies the ankle targets as pitch/roll")
        self._put_motors(command.command)

    def _put_motors(self, command) -> None:  # noqa: ANN001
        """cmd/motors from the DDS thread (LowCmd_): one zenoh publisher, used by one thread at a time."""
        with self._motors_lock:
            self._motors.put(command)

    def handle_requests(self) -> None:
        """Take every waiting motion-switcher request; answer those the budget admits (requests.py)."""
        intake = self._budget.admit(self._dds.take_requests())
        with self._lock:
            self.counters.requests_shed += intake.shed
        if intake.shed:
            self._shed_log.warning("motion switcher: %d request(s) shed unanswered (more than %g a second come in)",
                                   intake.shed, REQUESTS_PER_S)
        for why in intake.undecodable:
            self._reject_log.warning("undecodable motion-switcher request: %s", why)
        for request in intake.requests:
            identity = request.header.identity
            # Only CheckMode needs to know (a question to the walking controller over Zenoh).
            highlevel = self.highlevel if identity.api_id == switcher.API_ID_CHECK_MODE else None
            code, data = switcher.answer(identity.api_id, highlevel is not None and highlevel.active())
            if identity.api_id == switcher.API_ID_RELEASE_MODE and self.highlevel is not None:
                self.highlevel.release()  # a low-level program takes the robot from the sport service
            with self._lock:
                self.counters.motion_switcher_requests += 1
            self._request_log.info("motion switcher: api %d -> code %d %s", identity.api_id, code, data)
            if request.header.policy.noreply:
                continue
            self._dds.respond(Response_(
                header=ResponseHeader_(identity=RequestIdentity_(id=identity.id, api_id=identity.api_id),
                                       status=ResponseStatus_(code=code)),
                data=data, binary=[],
            ))

    def dds_loop(self, stop: threading.Event) -> None:
        """The DDS thread: wait for samples, handle them, until `stop`.

        It wakes at most once per LOWCMD_TAKE_PERIOD_S whatever comes in (a flood on any reader piles
        up in that reader meanwhile and is taken in one go), and each reader's handling is guarded: an
        error nobody foresaw is counted (internal_errors), logged with its traceback at a bounded rate,
        and the thread goes on serving the others.
        """
        next_take = 0.0
        while not stop.is_set():
            self._dds.wait(DDS_WAIT_S)
            wait_s = next_take - time.monotonic()
            if wait_s > 0:
                time.sleep(wait_s)  # at most LOWCMD_TAKE_PERIOD_S: a flood's samples pile up meanwhile
            next_take = time.monotonic() + LOWCMD_TAKE_PERIOD_S
            if self._dds.has_lowcmd():
                self._guarded("rt/lowcmd", self._take_lowcmd)
            if self._dds.has_request():
                self._guarded("rt/api/motion_switcher/request", self.handle_requests)
            if self.highlevel is not None:
                self._guarded("the sport service or rt/arm_sdk", self.highlevel.poll)

    def _take_lowcmd(self) -> None:
        samples = self._dds.take_lowcmd()
        if samples:  # latest wins: the older ones would be overwritten before a physics step
            self.handle_lowcmd(samples[-1], shed=len(samples) - 1)

    def _guarded(self, what: str, handle: Callable[[], None]) -> None:
        try:
            handle()
        except Exception as exc:
            with self._lock:
                self.counters.internal_errors += 1
                self.counters.last_error = bounded(f"{what}: {type(exc).__name__}: {exc}")
            self._error_log.exception("handling %s failed (counted in internal_errors; the DDS thread goes on)", what)

    # --- status ----------------------------------------------------------------------

    def lowstate_published(self) -> int:
        """LowState_ written so far (read under the lock: the state threads count it)."""
        with self._lock:
            return self.counters.lowstate_published

    def publish_status(self, seq: int, rate_hz: float) -> None:
        highlevel = self.highlevel.status_fields() if self.highlevel is not None else {}
        with self._lock:
            c = self.counters
            status = UnitreeStatus(
                seq=seq, dds_domain_id=self._settings.domain_id,
                dds_interface=self._settings.interface,
                lowcmd_received=c.lowcmd_received, lowcmd_forwarded=c.lowcmd_forwarded, lowcmd_shed=c.lowcmd_shed,
                crc_errors=c.crc_errors, rejected=c.rejected, ab_mode_commands=c.ab_mode_commands,
                lowstate_published=c.lowstate_published, lowstate_rate_hz=rate_hz,
                motion_switcher_requests=c.motion_switcher_requests, sim_time_s=c.sim_time_s,
                command_age_s=None if c.last_command is None else time.monotonic() - c.last_command,
                last_error=c.last_error, remote_rejected=c.remote_rejected,
                **dict(highlevel, requests_shed=c.requests_shed + highlevel.get("requests_shed", 0),
                       internal_errors=c.internal_errors + highlevel.get("internal_errors", 0)),
            )
        self._status.put(status)

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        if self.highlevel is not None:
            self.highlevel.close()
        self._motors.undeclare()
        self._status.undeclare()


def run(session: zenoh.Session, settings: UnitreeSettings, stop: threading.Event) -> int:
    """Learn the robot's joints, open DDS, bridge until `stop` is set.

    Returns:
        The process exit code.
    """
    keys = Keys(settings.robot_id)
    logger.info("asking the sim on %s", keys.robot_info)
    robot = fetch_robot(session, keys, settings.info_timeout_s, stop, Robot.from_info, logger)
    if robot is None:
        return 0
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    dds = UnitreeDds(settings.domain_id, settings.interface)
    adapter = UnitreeAdapter(session, keys, robot, settings, dds)
    dds_thread = threading.Thread(target=adapter.dds_loop, args=(stop,), name="dds", daemon=True)  # its death: below
    dds_thread.start()
    token = session.liveliness().declare_token(keys.alive("unitree"))
    logger.info("unitree adapter up: %d motors <-> %s; DDS domain %d on %s", len(robot.joint_names), keys.root,
                settings.domain_id, settings.interface or "(auto)")
    period_s = 1.0 / settings.status_rate_hz
    seq = 0
    last_count, last_time = 0, time.monotonic()
    code = 0
    try:
        while not stop.wait(period_s):
            if not dds_thread.is_alive():
                # Health must be true: without its DDS thread the adapter reads no command, request or
                # release, so it stops rather than keep a token and a status that say all is well.
                logger.error("the DDS thread ended (see the error above): rt/lowcmd, the sport service and "
                             "arm_sdk are no longer read; exiting")
                code = 1
                break
            if adapter.sim_run.restarted.is_set():
                robot = fetch_robot(session, keys, settings.info_timeout_s, stop, Robot.from_info, logger)
                if robot is None:
                    break
                adapter.adopt(robot)
                logger.info("robot from the restarted sim: %d motors", len(robot.joint_names))
            now = time.monotonic()
            count = adapter.lowstate_published()
            adapter.publish_status(seq, (count - last_count) / (now - last_time))
            last_count, last_time = count, now
            seq += 1
    finally:
        token.undeclare()
        dds_thread.join(2 * DDS_WAIT_S + 1.0)
        adapter.close()
    c = adapter.counters
    logger.info("%d LowCmd_ read, %d forwarded, %d shed, %d crc errors, %d rejected; %d LowState_ written",
                c.lowcmd_received, c.lowcmd_forwarded, c.lowcmd_shed, c.crc_errors, c.rejected,
                c.lowstate_published)
    return code
