"""The sim service's Zenoh wiring and its real-time loop.

Reads:   cmd/motors (MotorCommand, latest wins, applied every physics step)
Writes:  state/joints, state/odom, state/imu (state_rate_hz, sim time),
         state/sim (SimStatus, status_rate_hz, wall time)
Serves:  ctl/reset, ctl/pause, ctl/resume, ctl/step, ctl/mode (-> CtlReply),
         info/robot (RobotInfo), info/urdf (URDF text), info/mesh/{path} (mesh bytes)
Token:   alive/sim
Clock:   `clock lockstep` hands the loop to lockstep.py (each command advances; ctl/advance; state/applied)

Threads (the rule is docs/architecture.md's "Threads"): MjData is read and written only by the
thread holding `physics` (the loop; under `clock lockstep` also the thread that steps a command).
The command thread decodes the newest command of each source and merges it into the simulation's
held targets (physics.py, under its own lock); older ones from the same source are shed unread.
Zenoh callbacks only check, decode and hand over: a ctl request goes to `requests.py`, whose
queue the loop drains between two steps (it replies itself; a request waits at most a bounded
time, then is dropped, not run). Whatever a callback answers with (info/robot, a refusal) comes
from `_info` and `_snapshot`, values the loop replaces whole, never from MjData.

Every input is untrusted: a size cap before decoding (schemas/bounds.py), one
decode path that turns every failure into a counted, bounded refusal
(common/wire.py), physical bounds from the robot (physics.py), and control
queryables that act only on a query for exactly their own key, since a
wildcard query (`zensim/g1/**`) reaches every queryable at once.
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar
from pathlib import Path

import msgspec
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.pacing import GIL_SWITCH_INTERVAL_S, Pacer
from zensim.common.claim import current_owner, taken_message
from zensim.common.session import StartupError
from zensim.common.wire import Refusals, TypedPublisher, decode_input, is_wildcard, payload_of, reply
from zensim.robots import robot_files
from zensim.robots.builder import Robot, build
from zensim.robots.terrain import TerrainError, load_terrain
from zensim.schemas import topics
from zensim.schemas import (
    Codec,
    CtlReply,
    DecodeError,
    Imu,
    JointState,
    Odometry,
    Keys,
    MODES,
    Mode,
    ModeRequest,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    SimStatus,
    StepRequest,
    MSGPACK,
    bounded,
    is_json,
)
from zensim.schemas.bounds import vector_cap_bytes
from zensim.schemas.codec import Format
from zensim.schemas.messages import Message

from .physics import CommandError, Limits, Simulation
from .requests import Request, Requests, run_guarded
from .settings import SimSettings

logger = logging.getLogger("zensim.sim")
R = TypeVar("R", bound=Message)

PAUSED_POLL_S = 0.005
COMMAND_RING = 1024
"""Newest command samples zenoh keeps for the command thread; older ones are dropped there under a flood."""
COMMAND_BATCH_PERIOD_S = 0.002
"""Shortest wall time between two takes of commands (one 2 ms physics step of the G1).

Each take decodes only the newest sample of each source and sheds the rest unread, so a flood from
one source costs at most one decode per take (500 a second) however fast it comes, and a command
waits at most this long plus one take's work before it is applied: within 2 physics steps. (1 ms
takes cost the command thread ~13 % of a core under a 10 kHz flood, 2 ms ~8 %, measured side by side.)"""
COMMAND_POLL_S = 0.0005
"""How often the command thread empties zenoh's ring while it waits for the next take (5 samples of a
10 kHz flood: few enough that the ring holds on to no receive buffers)."""
FAST_BATCH_STEPS = 10
"""Steps run back to back at rtf 0 with wall-clock states (0.2-0.4 ms of wall time)."""


class PhysicsLock:
    """A lock that knows which thread holds it, so the threading rule can be checked, not just written.

    Used as `with service.physics:`; `held()` says whether the calling thread holds it.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._owner: int | None = None

    def __enter__(self) -> PhysicsLock:
        self._lock.acquire()
        self._owner = threading.get_ident()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._owner = None
        self._lock.release()

    def locked(self) -> bool:
        return self._lock.locked()

    def held(self) -> bool:
        """True when the calling thread holds the lock."""
        return self._owner == threading.get_ident()


@dataclass
class WorldClock:
    """Whether time runs, and its pacing: one robot's own, or shared by every robot of a world (world.py)."""

    paused: bool
    pacer: Pacer


@dataclass(frozen=True)
class Snapshot:
    """What a reply made off the loop thread says of the sim: taken whole by the physics-lock holder."""

    sim_time_s: float
    steps: int
    mode: Mode
    paused: bool
    episode: str


def source_of(sample: zenoh.Sample) -> object:
    """Who sent a sample: the publisher's id when it sets zenoh's source info, else None (one anonymous source)."""
    info = sample.source_info
    if info is None:
        return None
    source = info.source_id
    return (str(source.zid), source.eid)


class SimService:
    """Runs a Simulation in real time and connects it to Zenoh."""

    def __init__(self, session: zenoh.Session, settings: SimSettings, sim: Simulation, stop: threading.Event,
                 world: tuple[WorldClock, PhysicsLock] | None = None,
                 refusal_logs: tuple[RateLimitedLog, RateLimitedLog] | None = None) -> None:
        """`world`: the clock and physics lock a robot of a world shares with the others (world.py);
        None for a robot alone, whose loop is `run`. `refusal_logs`: the log limiters for refused commands
        and requests, shared by a world's robots; None: this robot's own."""
        self.session = session
        self.settings = settings
        self.sim = sim
        self.stop = stop
        self.keys = Keys(settings.robot_id)
        # Tells clients (the bridge) that this is a new sim, not the one they knew: a restarted
        # sim starts its reset counter at 0 again, so `resets` alone cannot say so.
        self.run_id = uuid.uuid4().hex[:16]
        self.clock = world[0] if world else WorldClock(settings.paused, Pacer(sim.timestep_s, settings.rtf))
        self.physics = world[1] if world else PhysicsLock()
        """Held by whichever thread reads or writes MjData (the loop; a lockstep command's thread)."""
        self.requests = Requests(lambda reason: self._status_reply(ok=False, error=reason, off_loop=True))
        self.shed_commands = 0
        """Commands shed unread (a newer one from the same source waited); written by the command thread only."""
        command_log, request_log = refusal_logs or (None, None)
        self.command_refusals = Refusals(logger, "command", log=command_log)
        self.request_refusals = Refusals(logger, "request", log=request_log)
        self.command_codec = Codec(topics.MOTORS.message_type())
        self.reply_codec = Codec(CtlReply)
        self.info_codec = Codec(RobotInfo)
        self.input_cap_bytes = vector_cap_bytes(sim.robot.joint_names)
        self.physics_resets = 0
        self.last_reset_reason: str | None = None
        self.seq = 0
        self.status_seq = 0
        self._fallen_since: float | None = None
        self._robots_by_mode: dict[Mode, Robot] = {}
        self._snapshot = self._take_snapshot()
        self.before_direct_put: Callable[[], None] = lambda: None
        """Called before a state is put on this thread: a world waits there for the states its publisher
        thread has yet to put (world_states.py), so that `seq` never goes back."""
        self._refresh_info()

        keys = self.keys
        self.pub_joints = TypedPublisher.of(session, keys, topics.JOINTS)
        self.pub_odom = TypedPublisher.of(session, keys, topics.ODOM)
        self.pub_imu = TypedPublisher.of(session, keys, topics.IMU)
        self.pub_status = TypedPublisher.of(session, keys, topics.SIM_STATUS)
        self.lockstep = None
        if settings.clock == "lockstep" and world is None:  # a world's lockstep is world/advance (world.py)
            from .lockstep import Lockstep  # imported here: lockstep.py builds on this module

            self.lockstep = Lockstep(self)
        # Commands arrive through a small ring kept by zenoh (in Rust): when a flood outruns the
        # decoding thread, the oldest samples are dropped there, before they cost the GIL anything,
        # and the newest command never waits behind a backlog (a plain callback queues 256 samples
        # and then pushes back on the router, which delayed a good client's commands by 100 ms).
        self.commands = session.declare_subscriber(keys.motors, zenoh.handlers.RingChannel(COMMAND_RING))
        self._command_thread: threading.Thread | None = None
        if world is None:  # a world takes every robot's commands on one thread (world_commands.py)
            self._command_thread = threading.Thread(target=self._drain_commands, name="sim-commands", daemon=True)
            self._command_thread.start()
        self._declared = [
            session.declare_queryable(keys.ctl("reset"), self._ctl("reset", ResetRequest, self._reset)),
            session.declare_queryable(keys.ctl("pause"), self._ctl("pause", PauseRequest, self._pause)),
            session.declare_queryable(keys.ctl("resume"), self._ctl("resume", ResumeRequest, self._resume)),
            session.declare_queryable(keys.ctl("step"), self._ctl("step", StepRequest, self._step)),
            session.declare_queryable(keys.ctl("mode"), self._ctl("mode", ModeRequest, self._mode)),
            session.declare_queryable(keys.robot_info, self._on_info),
            session.declare_queryable(keys.urdf, self._on_urdf),
            session.declare_queryable(keys.mesh_any, self._on_mesh),
        ]
        self.token: zenoh.LivelinessToken | None = None
        if world is None:  # a world says its robots are alive once it serves its own verbs too
            self.announce()

    def announce(self) -> None:
        """Declare alive/sim: everything of this robot is served from now on."""
        self.token = self.session.liveliness().declare_token(self.keys.alive("sim"))

    @property
    def paused(self) -> bool:
        return self.clock.paused

    @paused.setter
    def paused(self, value: bool) -> None:
        self.clock.paused = value

    @property
    def pacer(self) -> Pacer:
        return self.clock.pacer

    @pacer.setter
    def pacer(self, value: Pacer) -> None:
        self.clock.pacer = value

    # --- description -----------------------------------------------------

    def _refresh_info(self) -> None:
        """Re-render info/robot (after a mode switch); figures of the other mode come from a cached build."""
        sim = self.sim
        self._robots_by_mode[sim.mode] = sim.robot
        for mode in MODES:
            if mode not in self._robots_by_mode:
                self._robots_by_mode[mode] = build(sim.files, mode, sim.terrain)
        info = sim.robot_info(self.keys, self.settings.state_rate_hz, self.settings.status_rate_hz, self._robots_by_mode)
        # One value, replaced whole: a query answered meanwhile gets the old mode with the old
        # episode or the new with the new, never a mix.
        self._info = msgspec.structs.replace(
            info, run_id=self.run_id, clock=self.settings.clock, episode=self.episode(),
            lockstep_steps=self.settings.lockstep_steps if self.settings.clock == "lockstep" else 0)

    # info/* only describes: it may answer a wildcard query, always on its own key (a reply on
    # `zensim/g1/**` would not name what it is). Its payload is never read (JSON is asked for by
    # `?format=json`, or by sending any JSON payload, as the reply format of every query here).

    def _on_info(self, query: zenoh.Query) -> None:
        fmt: Format = "json" if _wants_json(query) or self._payload_is_json(query) else "msgpack"
        reply(query, self.keys.robot_info, self._info, fmt, self.info_codec)

    def episode(self) -> str:
        """SimStatus.episode: new at every reset (mode switches and automatic resets are resets too)
        and in every run, since `resets` counts from 0 again in a restarted sim."""
        return f"{self.run_id}.{self.sim.resets}"

    def _on_urdf(self, query: zenoh.Query) -> None:
        query.reply(self.keys.urdf, self.sim.robot.urdf_text.encode(), encoding=zenoh.Encoding.APPLICATION_XML)

    def _on_mesh(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        if is_wildcard(key):
            query.reply_err(b"info/mesh/{path} serves one mesh per query: name its path (RobotInfo.mesh_paths)")
            return
        match = next((f for name, f in self.sim.robot.mesh_files.items() if self.keys.mesh(name) == key), None)
        if match is None:
            path = key.removeprefix(f"{self.keys.root}/info/mesh/")
            query.reply_err(bounded(f"no mesh {path!r}; RobotInfo.mesh_paths lists the meshes").encode())
            return
        try:
            data = Path(match).read_bytes()
        except OSError as exc:
            query.reply_err(bounded(f"mesh {Path(match).name} cannot be read: {exc.strerror}").encode())
            return
        query.reply(key, data, encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM)

    def _payload_is_json(self, query: zenoh.Query) -> bool:
        """Whether to answer in JSON: the query's payload is JSON (an oversize one is judged by its label
        alone, not read: JSON unless it says msgpack, as the command line sets no label)."""
        payload = query.payload
        if payload is None:
            return False
        if len(payload) > self.input_cap_bytes:
            encoding = query.encoding
            return not (encoding is not None and str(encoding).startswith(MSGPACK))
        return is_json(*payload_of(query))

    # --- commands --------------------------------------------------------

    def _drain_commands(self) -> None:
        """Thread: take the ring's commands, newest of each source, until the subscriber is undeclared."""
        # recv() on the handler, not the subscriber: undeclaring a subscriber that another thread
        # is blocked in is refused ("Already borrowed"); the handler's recv just ends with ZError.
        ring = self.commands.handler
        # Latest wins at the physics step: a command with a newer one from the same source behind it
        # would be overwritten before any step saw it, so it is shed unread. Samples leave zenoh's
        # ring at once (a sample kept there keeps its receive buffer alive: the RSS grew by 20 MB
        # under a flood when the ring was left to fill between takes); only the newest of each
        # source waits here, for the next take.
        pending: dict[object, zenoh.Sample] = {}
        next_take = 0.0
        while True:
            try:
                sample = ring.recv() if not pending else ring.try_recv()
                while sample is not None:
                    if self.lockstep is not None:  # lockstep: every command advances, in arrival order
                        self.on_command(sample)
                    else:
                        source = source_of(sample)
                        if pending.pop(source, None) is not None:  # re-inserted: keeps arrival order
                            self.shed_commands += 1
                        pending[source] = sample
                    sample = ring.try_recv()
            except zenoh.ZError:  # undeclared at shutdown
                return
            if not pending:
                continue
            now = time.monotonic()
            if now < next_take:
                time.sleep(min(next_take - now, COMMAND_POLL_S))
                continue
            next_take = now + COMMAND_BATCH_PERIOD_S
            for sample in pending.values():
                self.on_command(sample)
            pending.clear()

    def on_command(self, sample: zenoh.Sample) -> None:
        """Decode, check and apply one command sample (the command thread: this robot's, or its world's)."""
        try:
            command = decode_input(sample, self.command_codec, self.input_cap_bytes)
            if self.lockstep is not None:  # lockstep: each command advances, on this thread
                self.lockstep.submit(command)
                return
            self.sim.accept_command(command)
        except (DecodeError, CommandError) as exc:
            self.sim.reject(self.command_refusals.refuse(sample.key_expr, str(exc)))

    # --- control requests -----------------------------------------------

    def _ctl(self, verb: str, request_type: type[R], handler: Callable[[R], CtlReply]) -> Callable[[zenoh.Query], None]:
        """The callback of one ctl queryable: exactly one reply per query, whatever it carries."""
        codec = Codec(request_type)
        own_key = self.keys.ctl(verb)

        def on_query(query: zenoh.Query) -> None:
            # Answer in the request's own format; a bare `z_get` with no payload gets JSON.
            fmt: Format = "json" if query.payload is None or self._payload_is_json(query) else "msgpack"
            if str(query.key_expr) != own_key:
                # `z_get zensim/g1/**` reaches every queryable: a control acts only when named.
                error = self.request_refusals.refuse(query.key_expr, f"ctl/{verb} acts only on a query for exactly "
                                                     f"{own_key}; nothing was done")
                reply(query, own_key, self._status_reply(ok=False, error=error, off_loop=True), fmt, self.reply_codec)
                return
            try:
                request = decode_input(query, codec, self.input_cap_bytes)
            except DecodeError as exc:
                error = self.request_refusals.refuse(query.key_expr, str(exc))
                reply(query, own_key, self._status_reply(ok=False, error=error, off_loop=True), fmt, self.reply_codec)
                return
            def answer(query: zenoh.Query, message: CtlReply) -> None:  # on the loop thread, or here when busy
                if not message.ok:
                    self.request_refusals.refuse(query.key_expr, message.error or "refused")
                reply(query, own_key, message, fmt, self.reply_codec)

            self.requests.submit(Request(query, lambda: handler(request), answer))

        return on_query

    def _status_reply(self, ok: bool = True, error: str | None = None, off_loop: bool = False) -> CtlReply:
        """The reply to a ctl request; `off_loop` on a thread without the physics lock (from the snapshot)."""
        if off_loop:
            now = self._snapshot
            return CtlReply(ok=ok, error=error, sim_time_s=now.sim_time_s, paused=now.paused, mode=now.mode,
                            steps=now.steps, episode=now.episode)
        sim = self.sim
        return CtlReply(ok=ok, error=error, sim_time_s=sim.sim_time_s, paused=self.paused, mode=sim.mode, steps=sim.steps,
                        episode=self.episode())

    def _take_snapshot(self) -> Snapshot:
        """(physics lock held) The figures off-loop replies give, taken together."""
        sim = self.sim
        return Snapshot(sim.sim_time_s, sim.steps, sim.mode, self.paused, self.episode())

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
        reason = self.sim.broken()
        if reason:
            self._physics_reset(reason)
            return self._status_reply(ok=False, error=f"the physics broke ({reason}): reset")
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
        self._info = msgspec.structs.replace(self._info, episode=self.episode())
        self.pacer = Pacer(self.sim.timestep_s, self.settings.rtf)
        self._fallen_since = None
        self._publish_states()
        self._publish_status(rtf=0.0)

    def _run_jobs(self, timeout_s: float = 0.0) -> None:
        """(loop thread) Run every waiting ctl request; wait up to `timeout_s` for the first."""
        if timeout_s <= 0 and self.requests.empty():  # the common case, without raising queue.Empty
            return
        taken = self.requests.run_next(timeout_s, self.run_request)
        while taken:
            taken = self.requests.run_next(0.0, self.run_request)

    def run_request(self, request: Request) -> CtlReply:
        """(loop thread) Run one ctl request under the physics lock; a failure becomes its reply, never the loop's end."""
        with self.physics:
            message = run_guarded(request.run, "a ctl request", lambda error: self._status_reply(ok=False, error=error))
            self._snapshot = self._take_snapshot()
        return message

    # --- publishing ------------------------------------------------------

    def _publish_states(self) -> None:
        """(physics lock held) The current instant on state/joints, odom, imu."""
        self.seq += 1
        sim = self.sim
        self._publish_messages(sim.joint_state(self.seq), sim.odometry(self.seq), sim.imu(self.seq))

    def _publish_messages(self, joints: JointState, odom: Odometry, imu: Imu) -> None:
        """(physics lock held) Put one instant's states, made by `_publish_states`, numbered `self.seq`."""
        self._snapshot = self._take_snapshot()
        self.before_direct_put()
        self.put_states(joints, odom, imu)

    def put_states(self, joints: JointState, odom: Odometry, imu: Imu) -> None:
        """Put one instant's states (any thread: a world puts every robot's from its publisher thread)."""
        self.pub_joints.put(joints)
        self.pub_odom.put(odom)
        self.pub_imu.put(imu)

    def _publish_status(self, rtf: float, fallen: bool | None = None, jitter_p99_s: float | None = None) -> None:
        """(physics lock held) SimStatus: it reads MjData (fallen, time). A world passes what it worked out
        for all robots at once: whether each has fallen, and its one pacer's jitter (read once per period)."""
        self.status_seq += 1
        sim = self.sim
        self.pub_status.put(
            SimStatus(
                sim_time_s=sim.sim_time_s,
                rtf=rtf,
                paused=self.paused,
                mode=sim.mode,
                fallen=sim.fallen() if fallen is None else fallen,
                rejected_commands=sim.rejected,
                shed_commands=self.shed_commands,
                clamped_commands=sim.clamped,
                command_age_s=sim.command_age_s(),
                watchdog=sim.watchdog_engaged(),
                last_error=sim.last_error,
                seq=self.status_seq,
                steps=sim.steps,
                timestep_s=sim.timestep_s,
                target_rtf=self.settings.rtf,
                step_jitter_p99_s=self.pacer.jitter_p99_s() if jitter_p99_s is None else jitter_p99_s,
                resets=sim.resets,
                run_id=self.run_id,
                physics_resets=self.physics_resets,
                last_reset_reason=self.last_reset_reason,
                rejected_requests=self.request_refusals.count,
                clock=self.settings.clock,
                waiting=self.lockstep is not None and self.lockstep.waiting,
                episode=self.episode(),
            )
        )

    def _check_fall(self, fallen: bool | None = None) -> None:
        """With auto_reset_on_fall: reset after a fall lasting fall_reset_delay_s (`fallen`: a world's
        verdict for all robots at once; None asks the sim)."""
        if not self.settings.auto_reset_on_fall:
            return
        if not (self.sim.fallen() if fallen is None else fallen):
            self._fallen_since = None
            return
        if self._fallen_since is None:
            self._fallen_since = self.sim.sim_time_s
        elif self.sim.sim_time_s - self._fallen_since >= self.settings.fall_reset_delay_s:
            logger.warning("robot fell: resetting (auto_reset_on_fall)")
            self.last_reset_reason = "fallen (auto_reset_on_fall)"
            self._reset(ResetRequest())

    def _physics_reset(self, reason: str) -> None:
        """Follow broken physics with a real reset to the default pose, and say so."""
        self.physics_resets += 1
        self.last_reset_reason = bounded(f"the physics broke: {reason}")
        logger.error("%s: resetting to the default pose", self.last_reset_reason)
        self._reset(ResetRequest())

    # --- the loop --------------------------------------------------------

    def run(self) -> None:
        """Step, publish and serve until the stop event is set."""
        # Zenoh callback threads (commands, queries) take the GIL for a few microseconds per sample.
        # Under a flood they take it back to back, and CPython hands it to a waiting thread only
        # after the switch interval (5 ms by default): the physics loop, waking every 2 ms step,
        # then waits up to 5 ms each time. A short interval bounds that wait.
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        # Everything made so far (the model, its description, meshes, zenoh's entities) lives as long as the
        # process: out of the collector's sight, a full collection no longer walks it (30 ms for a world of
        # 32 G1s, a step missed 15 times over; now well under 1 ms).
        gc.freeze()
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
        with self.physics:
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
                with self.physics:
                    sim.step(n)
                    self.pacer.stepped(n)
                    publish_due = wall_clock_states or sim.steps % publish_every == 0
                    if publish_due:
                        reason = sim.broken()
                        if reason:
                            self._physics_reset(reason)
            now = time.monotonic()
            with self.physics:
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
        if self.token is not None:
            self.token.undeclare()
        self.commands.undeclare()
        if self._command_thread is not None:
            self._command_thread.join(1.0)
        if self.lockstep is not None:
            self.lockstep.close()
        for entity in self._declared:
            entity.undeclare()
        for publisher in (self.pub_joints, self.pub_odom, self.pub_imu, self.pub_status):
            publisher.undeclare()
        self.requests.close("the sim is shutting down")  # no client hangs on a closing sim


def _wants_json(query: zenoh.Query) -> bool:
    """`z_get -s 'zensim/g1/info/robot?format=json'` asks for JSON explicitly."""
    return str(query.parameters).find("format=json") >= 0


def load_simulation(settings: SimSettings) -> Simulation:
    """Build the robot the settings name.

    Raises:
        StartupError: a missing or broken URDF, mesh or control file; the text names the file.
    """
    try:
        terrain = load_terrain(settings.terrain) if settings.terrain else None
    except TerrainError as exc:
        raise StartupError(f"terrain (--terrain / ZENSIM_SIM_TERRAIN): {bounded(str(exc), 400)}") from None
    # An explicit URDF stands alone: it must not pick up the bundled G1's control file.
    try:
        files = robot_files(None if settings.urdf else settings.robot, urdf=settings.urdf, control=settings.control)
        sim = Simulation(
            files,
            settings.mode,
            Limits(max_kp=settings.max_kp, max_kd=settings.max_kd),
            watchdog_timeout_s=settings.watchdog_timeout_s,
            timestep_s=settings.timestep_s,
            terrain=terrain,
        )
    except (OSError, ValueError) as exc:
        which = "--urdf / ZENSIM_SIM_URDF" if settings.urdf else "--robot / ZENSIM_SIM_ROBOT"
        raise StartupError(f"cannot load the robot ({which}, --control / ZENSIM_SIM_CONTROL): {bounded(str(exc), 400)}") from None
    logger.info("robot %s: %d joints, mode %s, step %.4f s", sim.robot.name, sim.robot.nu, sim.mode, sim.timestep_s)
    return sim


def run(session: zenoh.Session, settings: SimSettings, stop: threading.Event, sim: Simulation) -> int:
    """Serve `sim` on the session until `stop` is set. Returns the exit code."""
    owner = current_owner(session, Keys(settings.robot_id))
    if owner is not None:
        raise StartupError(taken_message(settings.robot_id, owner))
    service = SimService(session, settings, sim, stop)
    logger.info("sim up on %s", service.keys.root)
    try:
        service.run()
    finally:
        service.close()
    logger.info("sim stopped after %.1f sim s", sim.sim_time_s)
    return 0
