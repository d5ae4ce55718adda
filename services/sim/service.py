"""The sim service's Zenoh wiring and its real-time loop.

Reads:   cmd/motors (MotorCommand, latest wins, applied every physics step)
Writes:  state/joints, state/odom, state/imu (state_rate_hz, sim time),
         state/sim (SimStatus, status_rate_hz, wall time)
Serves:  ctl/reset, ctl/pause, ctl/resume, ctl/step, ctl/mode (-> CtlReply),
         info/robot (RobotInfo), info/urdf (URDF text), info/mesh/{path} (mesh bytes)
Token:   alive/sim
Clock:   `clock lockstep` hands the loop to lockstep.py (each command advances; ctl/advance; state/applied)

One thread owns the physics: the loop below. Zenoh callbacks only decode,
validate and hand over: commands are merged into the simulation's held
targets (physics.py, under a lock), control requests are queued as jobs that
the loop runs between two steps, and the callback replies once its job ran.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.pacing import Pacer
from zensim.common.session import open_session
from zensim.common.settings import describe
from zensim.common.shutdown import stop_on_signals
from zensim.common.wire import TypedPublisher, payload_of
from zensim.robots import robot_files
from zensim.robots.builder import Robot, build
from zensim.schemas import (
    Codec,
    CtlReply,
    DecodeError,
    Imu,
    JointState,
    Keys,
    ModeRequest,
    MotorCommand,
    Odometry,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    SimStatus,
    StepRequest,
    encoding_of,
    is_json,
)
from zensim.schemas.messages import Message

from .physics import CommandError, Limits, Simulation
from .settings import SimSettings

logger = logging.getLogger("zensim.sim")

REQUEST_TIMEOUT_S = 60.0
"""Longest a control request waits for the loop (a 100000-step ctl/step takes a few s)."""
PAUSED_POLL_S = 0.005
FAST_BATCH_STEPS = 10
"""Steps run back to back at rtf 0 with wall-clock states (0.2-0.4 ms of wall time)."""


@dataclass
class Job:
    """A control request handed from a zenoh callback to the loop thread."""

    run: Callable[[], CtlReply]
    done: threading.Event = field(default_factory=threading.Event)
    reply: CtlReply | None = None


class SimService:
    """Runs a Simulation in real time and connects it to Zenoh."""

    def __init__(self, session: zenoh.Session, settings: SimSettings, sim: Simulation, stop: threading.Event) -> None:
        self.session = session
        self.settings = settings
        self.sim = sim
        self.stop = stop
        self.keys = Keys(settings.robot_id)
        # Tells clients (the bridge) that this is a new sim, not the one they knew: a restarted
        # sim starts its reset counter at 0 again, so `resets` alone cannot say so.
        self.run_id = uuid.uuid4().hex[:16]
        self.paused = settings.paused
        self.pacer = Pacer(sim.timestep_s, settings.rtf)
        self.jobs: queue.Queue[Job] = queue.Queue()
        self.reject_log = RateLimitedLog(logger)
        self.command_codec = Codec(MotorCommand)
        self.seq = 0
        self.status_seq = 0
        self._fallen_since: float | None = None
        self._robots_by_mode: dict[str, Robot] = {}
        self._refresh_info()

        keys = self.keys
        self.pub_joints = TypedPublisher(session, keys.joints, JointState)
        self.pub_odom = TypedPublisher(session, keys.odom, Odometry)
        self.pub_imu = TypedPublisher(session, keys.imu, Imu)
        self.pub_status = TypedPublisher(session, keys.sim_status, SimStatus)
        self.lockstep = None
        if settings.clock == "lockstep":
            from .lockstep import Lockstep  # imported here: lockstep.py builds on this module

            self.lockstep = Lockstep(self)
        self._declared = [
            session.declare_subscriber(keys.motors, self._on_command),
            session.declare_queryable(keys.ctl("reset"), self._ctl(ResetRequest, self._reset)),
            session.declare_queryable(keys.ctl("pause"), self._ctl(PauseRequest, self._pause)),
            session.declare_queryable(keys.ctl("resume"), self._ctl(ResumeRequest, self._resume)),
            session.declare_queryable(keys.ctl("step"), self._ctl(StepRequest, self._step)),
            session.declare_queryable(keys.ctl("mode"), self._ctl(ModeRequest, self._mode)),
            session.declare_queryable(keys.robot_info, self._on_info),
            session.declare_queryable(keys.urdf, self._on_urdf),
            session.declare_queryable(keys.mesh_any, self._on_mesh),
        ]
        self.token = session.liveliness().declare_token(keys.alive("sim"))

    # --- description -----------------------------------------------------

    def _refresh_info(self) -> None:
        """Re-render info/robot (after a mode switch); figures of the other mode come from a cached build."""
        sim = self.sim
        self._robots_by_mode[sim.mode] = sim.robot
        for mode in ("floating", "fixed"):
            if mode not in self._robots_by_mode:
                self._robots_by_mode[mode] = build(sim.files, mode)  # type: ignore[arg-type]
        info = sim.robot_info(self.keys, self.settings.state_rate_hz, self.settings.status_rate_hz, self._robots_by_mode)
        self._info = msgspec.structs.replace(
            info, run_id=self.run_id, clock=self.settings.clock,
            lockstep_steps=self.settings.lockstep_steps if self.settings.clock == "lockstep" else 0)

    def _on_info(self, query: zenoh.Query) -> None:
        data, encoding = payload_of(query)
        fmt = "json" if is_json(data, encoding) or _wants_json(query) else "msgpack"
        self._reply(query, self._info, fmt)

    def _on_urdf(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, self.sim.robot.urdf_text.encode(), encoding=zenoh.Encoding.APPLICATION_XML)

    def _on_mesh(self, query: zenoh.Query) -> None:
        path = self.keys.mesh_path(str(query.key_expr))
        mesh_files = self.sim.robot.mesh_files
        match = next((f for name, f in mesh_files.items() if self.keys.mesh(name) == str(query.key_expr)), None)
        if match is None:
            query.reply_err(f"no mesh {path!r}; RobotInfo.mesh_paths lists the meshes".encode())
            return
        query.reply(query.key_expr, Path(match).read_bytes(), encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM)

    # --- commands --------------------------------------------------------

    def _on_command(self, sample: zenoh.Sample) -> None:
        data, encoding = payload_of(sample)
        try:
            command = self.command_codec.decode(data, encoding)
            if self.lockstep is not None:  # lockstep: each command advances, on the loop thread
                self.lockstep.submit(command)
                return
            self.sim.accept_command(command)
        except (DecodeError, CommandError) as exc:
            self.sim.reject(str(exc))
            self.reject_log.warning("rejected command on %s: %s", sample.key_expr, exc)

    # --- control requests -----------------------------------------------

    def _ctl(self, request_type: type[Message], handler: Callable[[Message], CtlReply]) -> Callable[[zenoh.Query], None]:
        codec = Codec(request_type)

        def on_query(query: zenoh.Query) -> None:
            data, encoding = payload_of(query)
            # Answer in the request's own format; a bare `z_get` with no payload gets JSON.
            fmt = "msgpack" if data and not is_json(data, encoding) else "json"
            try:
                request = codec.decode(data, encoding)
            except DecodeError as exc:
                self._reply(query, self._status_reply(ok=False, error=str(exc)), fmt)
                return
            job = Job(lambda: handler(request))
            self.jobs.put(job)
            if not job.done.wait(REQUEST_TIMEOUT_S):
                self._reply(query, self._status_reply(ok=False, error="the sim loop did not answer in time"), fmt)
                return
            assert job.reply is not None
            self._reply(query, job.reply, fmt)

        return on_query

    def _reply(self, query: zenoh.Query, message: Message, fmt: str) -> None:
        payload = Codec(type(message)).encode(message, fmt)  # type: ignore[arg-type]
        query.reply(query.key_expr, payload, encoding=zenoh.Encoding(encoding_of(fmt)))  # type: ignore[arg-type]

    def _status_reply(self, ok: bool = True, error: str | None = None) -> CtlReply:
        sim = self.sim
        return CtlReply(ok=ok, error=error, sim_time_s=sim.sim_time_s, paused=self.paused, mode=sim.mode, steps=sim.steps)

    def _reset(self, request: ResetRequest) -> CtlReply:
        mode_before = self.sim.mode
        try:
            self.sim.reset(request)
        except CommandError as exc:
            return self._status_reply(ok=False, error=str(exc))
        if self.sim.mode != mode_before:
            self._refresh_info()
        self._after_jump()
        logger.info("reset (mode %s)", self.sim.mode)
        return self._status_reply()

    def _pause(self, _request: PauseRequest) -> CtlReply:
        self.paused = True
        return self._status_reply()

    def _resume(self, _request: ResumeRequest) -> CtlReply:
        self.paused = False
        self.pacer.restart()
        return self._status_reply()

    def _step(self, request: StepRequest) -> CtlReply:
        if not self.paused:
            return self._status_reply(ok=False, error="ctl/step works while paused; send ctl/pause first")
        self.sim.step(request.n)
        self._publish_states()
        return self._status_reply()

    def _mode(self, request: ModeRequest) -> CtlReply:
        if request.mode != self.sim.mode:
            self.sim.set_mode(request.mode)
            self._refresh_info()
            self._after_jump()
            logger.info("mode switched to %s", request.mode)
        return self._status_reply()

    def _after_jump(self) -> None:
        """After the state jumped (reset, rebuild): restart pacing, tell everyone at once."""
        self.pacer = Pacer(self.sim.timestep_s, self.settings.rtf)
        self._fallen_since = None
        self._publish_states()
        self._publish_status(rtf=0.0)

    def _run_jobs(self, timeout_s: float = 0.0) -> None:
        if timeout_s <= 0 and self.jobs.empty():  # the common case, without raising queue.Empty
            return
        try:
            job = self.jobs.get(timeout=timeout_s) if timeout_s > 0 else self.jobs.get_nowait()
        except queue.Empty:
            return
        while True:
            try:
                job.reply = job.run()
            except Exception as exc:  # a failed request must not take the loop down
                logger.exception("control request failed")
                job.reply = self._status_reply(ok=False, error=f"{type(exc).__name__}: {exc}")
            job.done.set()
            try:
                job = self.jobs.get_nowait()
            except queue.Empty:
                return

    # --- publishing ------------------------------------------------------

    def _publish_states(self) -> None:
        self.seq += 1
        sim = self.sim
        self.pub_joints.put(sim.joint_state(self.seq))
        self.pub_odom.put(sim.odometry(self.seq))
        self.pub_imu.put(sim.imu(self.seq))

    def _publish_status(self, rtf: float) -> None:
        self.status_seq += 1
        sim = self.sim
        self.pub_status.put(
            SimStatus(
                sim_time_s=sim.sim_time_s,
                rtf=rtf,
                paused=self.paused,
                mode=sim.mode,
                fallen=sim.fallen(),
                rejected_commands=sim.rejected,
                clamped_commands=sim.clamped,
                command_age_s=sim.command_age_s(),
                watchdog=sim.watchdog_engaged(),
                last_error=sim.last_error,
                seq=self.status_seq,
                steps=sim.steps,
                timestep_s=sim.timestep_s,
                target_rtf=self.settings.rtf,
                step_jitter_p99_s=self.pacer.jitter_p99_s(),
                resets=sim.resets,
                run_id=self.run_id,
                clock=self.settings.clock,
                waiting=self.lockstep is not None and self.lockstep.waiting,
            )
        )

    def _check_fall(self) -> None:
        if not self.settings.auto_reset_on_fall:
            return
        if not self.sim.fallen():
            self._fallen_since = None
            return
        if self._fallen_since is None:
            self._fallen_since = self.sim.sim_time_s
        elif self.sim.sim_time_s - self._fallen_since >= self.settings.fall_reset_delay_s:
            logger.warning("robot fell: resetting (auto_reset_on_fall)")
            self._reset(ResetRequest())

    # --- the loop --------------------------------------------------------

    def run(self) -> None:
        """Step, publish and serve until the stop event is set."""
        if self.lockstep is not None:
            self.lockstep.run()
            return
        sim, settings = self.sim, self.settings
        publish_every = max(1, round(1.0 / (settings.state_rate_hz * sim.timestep_s)))
        publish_period_s = 1.0 / settings.state_rate_hz
        wall_clock_states = settings.state_clock == "wall" or self.paused
        status_period_s = 1.0 / settings.status_rate_hz
        now = time.monotonic()
        next_status = next_publish = now
        last_status_wall, last_status_sim = now, sim.sim_time_s
        self._publish_states()
        while not self.stop.is_set():
            if self.paused:
                self._run_jobs(timeout_s=PAUSED_POLL_S)
                publish_due = True  # at the wall-clock rate below: joining viewers still need a state
                wall_clock_states = True
            else:
                self._run_jobs()
                if self.paused:  # a ctl/pause that just ran: not one step more
                    continue
                wall_clock_states = settings.state_clock == "wall"
                if settings.rtf > 0:
                    self.pacer.wait()
                    n = 1
                elif wall_clock_states:
                    n = FAST_BATCH_STEPS
                else:
                    # As fast as possible: run up to the next state in one go. Commands still take
                    # effect at the next step boundary (the per-step target check in sim.step).
                    n = publish_every - sim.steps % publish_every
                sim.step(n)
                self.pacer.stepped(n)
                publish_due = wall_clock_states or sim.steps % publish_every == 0
                if publish_due and sim.diverged():
                    logger.error("the physics diverged (NaN or huge accelerations): resetting")
                    self._reset(ResetRequest())
            now = time.monotonic()
            if publish_due and (not wall_clock_states or now >= next_publish):
                next_publish = now + publish_period_s
                self._publish_states()
                if not self.paused:
                    self._check_fall()
            if now >= next_status:
                wall = now - last_status_wall
                rtf = (sim.sim_time_s - last_status_sim) / wall if wall > 0 else 0.0
                self._publish_status(max(rtf, 0.0))
                last_status_wall, last_status_sim = now, sim.sim_time_s
                next_status = now + status_period_s

    def close(self) -> None:
        self.token.undeclare()
        if self.lockstep is not None:
            self.lockstep.close()
        for entity in self._declared:
            entity.undeclare()
        for publisher in (self.pub_joints, self.pub_odom, self.pub_imu, self.pub_status):
            publisher.undeclare()
        # Answer whatever is still waiting so no client hangs on a closing sim.
        while True:
            try:
                job = self.jobs.get_nowait()
            except queue.Empty:
                break
            job.reply = self._status_reply(ok=False, error="the sim is shutting down")
            job.done.set()


def _wants_json(query: zenoh.Query) -> bool:
    """`z_get -s 'zensim/g1/info/robot?format=json'` asks for JSON explicitly."""
    return str(query.parameters).find("format=json") >= 0


def run(settings: SimSettings) -> int:
    """Build the robot, open the session, loop until SIGINT/SIGTERM. Returns the exit code."""
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))
    # An explicit URDF stands alone: it must not pick up the bundled G1's control file.
    files = robot_files(None if settings.urdf else settings.robot, urdf=settings.urdf, control=settings.control)
    sim = Simulation(
        files,
        settings.mode,
        Limits(max_kp=settings.max_kp, max_kd=settings.max_kd),
        watchdog_timeout_s=settings.watchdog_timeout_s,
        timestep_s=settings.timestep_s,
    )
    logger.info("robot %s: %d joints, mode %s, step %.4f s", sim.robot.name, sim.robot.nu, sim.mode, sim.timestep_s)
    with open_session(settings.zenoh) as session:
        service = SimService(session, settings, sim, stop)
        logger.info("sim up on %s", service.keys.root)
        try:
            service.run()
        finally:
            service.close()
    logger.info("sim stopped after %.1f sim s", sim.sim_time_s)
    return 0
