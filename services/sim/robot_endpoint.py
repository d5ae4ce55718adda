"""One robot's keys, served the same way for a robot alone and for each robot of a world.

Reads:   cmd/motors (MotorCommand, latest wins at each physics step; under the lockstep clock of a robot
         alone every command advances, in arrival order)
Writes:  state/joints, state/odom, state/imu, state/contacts (state_rate_hz, sim time), state/sim (SimStatus,
         status_rate_hz, wall time), state/applied (AppliedCommand, lockstep alone: one per advance)
Serves:  ctl/reset, ctl/pause, ctl/resume, ctl/step, ctl/mode, ctl/push, ctl/band, ctl/faults (-> CtlReply), ctl/advance (lockstep alone:
         MotorCommand -> AdvanceReply), info/robot, info/urdf, info/mesh/{path} (common/description.py)
Token:   alive/sim

Every input is untrusted: a size cap before decoding (schemas/bounds.py), one decode path that turns
every failure into a counted, bounded refusal (common/wire.py, common/queryable.py), physical bounds from
the robot (physics.py), and control queryables that act only on a query for exactly their own key,
since a wildcard query (`zensim/g1/**`) reaches every queryable at once.

A robot's verbs act on that robot alone: ctl/reset resets only it, cmd/motors commands only it. Time is
the world's (its robots cannot run apart), so a robot of a world of several refuses ctl/pause, ctl/resume
and ctl/step, which would move or stop every robot, and its reply names the world's verbs instead
(zensim/{world}/world/*): a credential scoped to one robot of a world (docs/security.md) then cannot stop or
step the others through it. A robot alone (a world of one) still pauses and steps itself. The engine
(engine.py) does what each verb asks; this class only says it on the wire.
"""

from __future__ import annotations

import logging
import math
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import msgspec
import zenoh

from zensim.common.description import DescriptionServer, MeshError
from zensim.common.logs import RateLimitedLog
from zensim.common.queryable import TypedQuery, TypedQueryable
from zensim.common.wire import Refusals, TypedPublisher, decode_input
from zensim.robots.builder import MODES, ModeFigures, mode_figures
from zensim.robots.mesh_files import read_mesh
from zensim.schemas import (
    AdvanceReply,
    AppliedCommand,
    BandRequest,
    BandState,
    Codec,
    CtlReply,
    DecodeError,
    FaultsRequest,
    FaultsState,
    Keys,
    Mode,
    ModeRequest,
    MotorCommand,
    PauseRequest,
    PushRequest,
    PushState,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    SimStatus,
    StepRequest,
    bounded,
    topics,
)
from zensim.schemas.bounds import vector_cap_bytes
from zensim.schemas.messages import Message

from .engine import Engine
from .disturbances import DisturbanceError
from .faults import FaultError
from .physics import CommandError
from .world import WHOLE_WORLD
from .requests import Request, Requests, failures, run_guarded
from .schedule import ScheduleError
from .world_states import States

logger = logging.getLogger("zensim.sim")

COMMAND_RING = 1024
"""Newest command samples zenoh keeps for the command thread; older ones are dropped there under a flood."""


@dataclass(frozen=True)
class Snapshot:
    """What a reply made off the loop thread says of the robot: taken whole by the physics-lock holder."""

    sim_time_s: float
    steps: int
    mode: Mode
    paused: bool
    episode: str


@dataclass(frozen=True)
class Advanced:
    """The outcome of one advance of a robot alone: the reply, and what to publish (nothing when time stood)."""

    reply: AdvanceReply
    applied: AppliedCommand | None = None
    states: list[States] | None = None


class RobotEndpoint:
    """Serves robot `index` of the engine's world on zenoh/{robot}/...

    Args:
        session: the zenoh session.
        engine: the engine whose world holds the robot.
        index: the robot's place in the world.
        robot_id: its id (its key root).
        advances: each command advances the world (a robot alone under the lockstep clock: cmd/motors and
            ctl/advance); False: a command is held for the next steps (real time, or a world's lockstep,
            where world/advance moves time).
        refusal_logs: log limiters for refused commands and requests, shared by a world's robots (a flood to
            every robot is one line a second); None: the robot's own.
    """

    def __init__(self, session: zenoh.Session, engine: Engine, index: int, robot_id: str, advances: bool,
                 refusal_logs: tuple[RateLimitedLog, RateLimitedLog] | None = None) -> None:
        self._session = session
        self.engine = engine
        self.index = index
        self.sim = engine.world.robots[index]
        self.settings = engine.settings
        self.keys = keys = Keys(robot_id)
        # Tells clients (the bridge) that this is a new sim, not the one they knew: a restarted
        # sim starts its reset counter at 0 again, so `resets` alone cannot say so.
        self.run_id = uuid.uuid4().hex[:16]
        self.advances = advances
        command_log, request_log = refusal_logs or (None, None)
        self.command_refusals = Refusals(logger, "command", log=command_log)
        self.request_refusals = Refusals(logger, "request", log=request_log)
        self.requests = Requests(lambda reason: self._status_reply(ok=False, error=reason, off_loop=True), engine.work)
        self.shed_commands = 0
        """Commands shed unread (a newer one from the same source waited); written by the command thread only."""
        self.status_seq = 0
        self.applied_seq = 0
        self.command_codec = Codec(topics.MOTORS.message_type())
        self.input_cap_bytes = vector_cap_bytes(self.sim.robot.joint_names)
        self.snapshot = self._take_snapshot()
        self.info = self._describe()

        self.pub_joints = TypedPublisher.of(session, keys, topics.JOINTS)
        self.pub_odom = TypedPublisher.of(session, keys, topics.ODOM)
        self.pub_imu = TypedPublisher.of(session, keys, topics.IMU)
        self.pub_contacts = TypedPublisher.of(session, keys, topics.CONTACTS)
        self.pub_status = TypedPublisher.of(session, keys, topics.SIM_STATUS)
        self.pub_applied = TypedPublisher(session, keys.applied, AppliedCommand) if advances else None
        self.commands = session.declare_subscriber(keys.motors, zenoh.handlers.RingChannel(COMMAND_RING))
        """cmd/motors, taken by the engine's command thread (commands.py)."""
        self._queryables: list[TypedQueryable] = [
            self._ctl("reset", ResetRequest, self._reset),
            self._ctl("pause", PauseRequest, self._pause),
            self._ctl("resume", ResumeRequest, self._resume),
            self._ctl("step", StepRequest, self._step),
            self._ctl("mode", ModeRequest, self._mode),
            self._ctl("push", PushRequest, self._push),
            self._ctl("band", BandRequest, self._band),
            self._ctl("faults", FaultsRequest, self._faults),
        ]
        if advances:
            self._queryables.append(TypedQueryable(
                session, keys.ctl("advance"), self._on_advance, AdvanceReply, self.request_refusals, MotorCommand,
                self.input_cap_bytes, refused=self._advance_refusal, bad_input=self._bad_command,
                count_refused_replies=False))
        self.description = DescriptionServer(session, keys, self.request_refusals, lambda: self.info,
                                             lambda: self.sim.robot.urdf_text, self._mesh, missing="the sim")
        self.token: zenoh.LivelinessToken | None = None

    def announce(self) -> None:
        """Declare alive/sim: everything of this robot is served from now on."""
        self.token = self._session.liveliness().declare_token(self.keys.alive("sim"))

    # --- the engine's side (RobotPort) ------------------------------------------------------------

    def put_states(self, states: States) -> None:
        """Put one instant's states; joints and imu not while a sensor dropout withholds them (None)."""
        if states.joints is not None:
            self.pub_joints.put(states.joints)
        self.pub_odom.put(states.odom)
        if states.imu is not None:
            self.pub_imu.put(states.imu)
        self.pub_contacts.put(states.contacts)

    def publish_status(self, rtf: float, fallen: bool, jitter_p99_s: float, waiting: bool) -> None:
        """(physics lock held) SimStatus: the robot's figures, with the engine's rate, fall, jitter and wait."""
        self.status_seq += 1
        sim, settings = self.sim, self.settings
        disturbances = sim.disturbances
        self.pub_status.put(SimStatus(
            sim_time_s=sim.sim_time_s,
            rtf=rtf,
            paused=self.engine.paused,
            mode=sim.mode,
            fallen=fallen,
            rejected_commands=sim.rejected,
            shed_commands=self.shed_commands,
            clamped_commands=sim.clamped,
            command_age_s=sim.command_age_s(),
            watchdog=sim.watchdog_engaged(),
            last_error=sim.last_error,
            seq=self.status_seq,
            steps=sim.steps,
            timestep_s=sim.timestep_s,
            target_rtf=settings.rtf,
            step_jitter_p99_s=jitter_p99_s,
            resets=sim.resets,
            run_id=self.run_id,
            physics_resets=sim.physics_resets,
            last_reset_reason=sim.last_reset_reason,
            rejected_requests=self.request_refusals.count,
            clock=settings.clock,
            waiting=waiting and self.advances,
            episode=self.episode(),
            pushes=disturbances.push_states(),
            pushes_applied=disturbances.pushes_applied,
            last_push=disturbances.last_push,
            band=disturbances.band_state() if disturbances.band_holds() else None,
            variant=sim.variants.variant,
            faults=sim.faults.state,
            faults_set=sim.faults.changes,
            dropped_commands=sim.link.dropped,
            scheduled=self.engine.world.schedule.waiting(self.index),
            withheld_states=sim.faults.withheld,
        ))

    def jumped(self, rebuilt: bool) -> None:
        """(physics lock held) A reset (`rebuilt`: in a new model): info/robot says the new episode (and mode)."""
        # One value, replaced whole: a query answered meanwhile gets the old mode with the old
        # episode or the new with the new, never a mix.
        self.info = self._describe() if rebuilt else msgspec.structs.replace(
            self.info, episode=self.episode(), variant=self.sim.variants.variant)

    def take_snapshot(self) -> None:
        self.snapshot = self._take_snapshot()

    def count_shed(self) -> None:
        """One command shed unread (the command thread, the counter's one writer)."""
        self.shed_commands += 1

    def refuse_wildcard(self, sample: zenoh.Sample) -> None:
        """A command put on a wildcard key (it reaches every robot at once): refused unread, counted."""
        self.sim.reject(self.command_refusals.refuse(
            sample.key_expr, f"a command must be put on exactly {self.keys.motors}; one put on a wildcard "
                             "reaches every robot at once and is refused"))

    def undecodable(self, sample: zenoh.Sample) -> str | None:
        """Why `sample` does not decode (None when it does), counting nothing: the command thread screens a
        suspect source's older samples with it, then counts those refused at once (`refuse_undecodable`)."""
        try:
            decode_input(sample, self.command_codec, self.input_cap_bytes)
        except DecodeError as exc:
            return str(exc)
        return None

    def refuse_undecodable(self, sample: zenoh.Sample, reason: str, count: int) -> None:
        """Count `count` screened samples as refused (`reason`: the last one's, of `sample`)."""
        self.sim.reject(self.command_refusals.refuse(sample.key_expr, reason, count), count)

    def take_command(self, sample: zenoh.Sample) -> bool:
        """Decode, check and apply one command sample (the engine's command thread); False when refused."""
        sim = self.sim
        try:
            command = decode_input(sample, self.command_codec, self.input_cap_bytes)
            if self.advances:  # lockstep alone: each command advances, on this thread
                with self.engine.physics:
                    advanced = self._advance(command, hold_when_paused=True, key=self.keys.motors)
                    self._publish(advanced)
                return advanced.reply.ok
            sim.accept_command(command)
        except (DecodeError, CommandError) as exc:
            sim.reject(self.command_refusals.refuse(sample.key_expr, str(exc)))
            return False
        return True

    # --- description ------------------------------------------------------------------------------

    def episode(self) -> str:
        """SimStatus.episode: new at every reset (mode switches and automatic resets are resets too)
        and in every run, since `resets` counts from 0 again in a restarted sim."""
        return f"{self.run_id}.{self.sim.resets}"

    def _describe(self) -> RobotInfo:
        """info/robot now: the robot's figures in its mode, and its other modes' from its files (no compile
        where the control file gives their spawn height)."""
        sim, settings = self.sim, self.settings
        robot = sim.robot
        figures = {mode: ModeFigures(robot.default_q, robot.kp, robot.kd, robot.base_height_m) if mode == sim.mode
                   else mode_figures(sim.files, mode, sim.terrain) for mode in MODES}
        info = sim.robot_info(self.keys, settings.state_rate_hz, settings.status_rate_hz, figures)
        return msgspec.structs.replace(
            info, run_id=self.run_id, clock=settings.clock, episode=self.episode(),
            lockstep_steps=settings.lockstep_steps if settings.clock == "lockstep" else 0)

    def _mesh(self, key: str) -> bytes:
        path = next((f for name, f in self.sim.robot.mesh_files.items() if self.keys.mesh(name) == key), None)
        if path is None:
            name = key.removeprefix(f"{self.keys.root}/info/mesh/")
            raise MeshError(f"no mesh {name!r}; RobotInfo.mesh_paths lists the meshes")
        try:
            return read_mesh(Path(path))  # only if it is still the file checked at load (a swapped-in symlink is not)
        except OSError as exc:
            raise MeshError(f"mesh {Path(path).name} cannot be read: {exc.strerror}") from None

    # --- ctl verbs (run by the engine's loop, physics lock held) ------------------------------------

    def _ctl(self, verb: str, request_type: type[Message], handler: Callable) -> TypedQueryable:
        """One ctl queryable: checked and decoded on the callback, run by the loop, answered once."""
        def on_query(query: TypedQuery) -> None:
            self.requests.submit(Request(query, lambda: handler(query.request)))

        return TypedQueryable(self._session, self.keys.ctl(verb), on_query, CtlReply, self.request_refusals,
                              request_type, self.input_cap_bytes,
                              refused=lambda error: self._status_reply(ok=False, error=error, off_loop=True))

    def _reset(self, request: ResetRequest) -> CtlReply:
        try:
            self.engine.reset_robot(self.index, request)
        except CommandError as exc:
            return self._status_reply(ok=False, error=str(exc))
        variant = self.sim.variants.variant
        if variant is None:
            self.engine.request_log.info("%s reset (mode %s)", self.keys.robot, self.sim.mode)
        else:
            self.engine.request_log.info("%s reset (mode %s) as variant %d: %.4g kg (nominal %.4g)", self.keys.robot,
                                         self.sim.mode, variant.seed, variant.mass_kg, variant.nominal_mass_kg)
        return msgspec.structs.replace(self._status_reply(), variant=variant)

    def _shared_clock(self, verb: str) -> CtlReply | None:
        """The refusal of a verb that would move or stop every robot of a world of several; None: a robot alone."""
        world = self.engine.world
        if len(world) == 1:
            return None
        return self._status_reply(ok=False, error=bounded(
            f"ctl/{verb}: {self.keys.robot} is one of the {len(world)} robots of the world {world.id}, which share "
            f"one clock: it would {verb} them all; send {Keys(world.id).root}/world/{verb} (the world's verb), "
            f"nothing was done"))

    def _pause(self, _request: PauseRequest) -> CtlReply:
        if refused := self._shared_clock("pause"):
            return refused
        self.engine.pause()
        return self._status_reply()

    def _resume(self, _request: ResumeRequest) -> CtlReply:
        if refused := self._shared_clock("resume"):
            return refused
        self.engine.resume()
        return self._status_reply()

    def _step(self, request: StepRequest) -> CtlReply:
        if refused := self._shared_clock("step"):
            return refused
        if not self.engine.paused:
            return self._status_reply(ok=False, error="ctl/step works while paused; send ctl/pause first")
        broken = [reason for index, reason in self.engine.step(request.n) if index in (WHOLE_WORLD, self.index)]
        if broken:
            return self._status_reply(ok=False, error=f"the physics broke ({broken[0]}): reset")
        return self._status_reply()

    def _mode(self, request: ModeRequest) -> CtlReply:
        try:
            switched = self.engine.set_mode(self.index, request.mode)
        except CommandError as exc:
            return self._status_reply(ok=False, error=bounded(f"ctl/mode: {exc}"))
        if switched:
            self.engine.request_log.info("%s: mode switched to %s", self.keys.robot, request.mode)
        return self._status_reply()

    def _push(self, request: PushRequest) -> CtlReply:
        disturbances = self.sim.disturbances
        try:
            if request.at_s is not None:  # checked now, started at its time (the number of pushes then: its own check)
                planned = disturbances.plan(request)
                at_s = self._schedule("push", request.at_s, lambda: self._pushed(disturbances.push(request)))
                push = msgspec.structs.replace(planned.state(self.sim.timestep_s), start_s=at_s)
                return msgspec.structs.replace(self._status_reply(), push=push, scheduled_at_s=at_s)
            push = self._pushed(disturbances.push(request))
        except (DisturbanceError, ScheduleError) as exc:
            return self._status_reply(ok=False, error=bounded(str(exc)))
        return msgspec.structs.replace(self._status_reply(), push=push)

    def _pushed(self, push: PushState) -> PushState:
        self.engine.request_log.info("%s: push of %.4g N on %s for %.4g s", self.keys.robot,
                                     math.sqrt(math.fsum(f * f for f in push.force_n)), push.body, push.duration_s)
        return push

    def _band(self, request: BandRequest) -> CtlReply:
        disturbances = self.sim.disturbances
        try:
            if request.at_s is not None:
                disturbances.band_after(request)  # fits now: checked again at its time
                at_s = self._schedule("band", request.at_s, lambda: self._banded(disturbances.band(request)))
                return msgspec.structs.replace(self._status_reply(), band=disturbances.band_state(), scheduled_at_s=at_s)
            band = disturbances.band(request)
        except (DisturbanceError, ScheduleError) as exc:
            return self._status_reply(ok=False, error=bounded(str(exc)))
        if request.verb is not None or request.length_m is not None:
            self._banded(band)
        return msgspec.structs.replace(self._status_reply(), band=band)

    def _banded(self, band: BandState) -> None:
        self.engine.request_log.info("%s: band %s, %.3g m", self.keys.robot, "on" if band.on else "off", band.length_m)

    def _faults(self, request: FaultsRequest) -> CtlReply:
        faults = self.sim.faults
        try:
            if request.at_s is not None:
                faults.check(request)
                at_s = self._schedule("faults", request.at_s, lambda: self._set_faults(request))
                return msgspec.structs.replace(self._status_reply(), faults=faults.state, scheduled_at_s=at_s)
            state = self._set_faults(request)
        except (FaultError, ScheduleError) as exc:
            return self._status_reply(ok=False, error=bounded(str(exc)))
        return msgspec.structs.replace(self._status_reply(), faults=state)

    def _set_faults(self, request: FaultsRequest) -> FaultsState | None:
        state = self.sim.faults.request(request)
        if request.verb is not None:
            self.sim.faults_changed()
            link = request.link
            self.engine.request_log.info("%s: faults %s (%d joints, sensors %s, link %s)", self.keys.robot, request.verb,
                                         len(request.joints), "faulty" if request.sensors else "exact",
                                         "perfect" if link is None else
                                         f"delay {link.command_delay_steps} steps, drop {link.drop_probability:g}, "
                                         f"state delay {link.state_delay_steps} steps")
        return state

    def _schedule(self, verb: str, at_s: float, act: Callable[[], object]) -> float:
        """Keep a checked request for the step that starts at `at_s` (schedule.py); returns that step's sim time.

        Raises:
            ScheduleError: `at_s` has passed, or too many requests wait.
        """
        world = self.engine.world

        def run() -> None:  # at its time, on the thread that steps: what no longer fits is refused then
            try:
                act()
                return
            except (DisturbanceError, FaultError) as exc:
                reason = str(exc)
            except Exception as exc:  # a bug must not take the stepping thread down (run_guarded's rule)
                failures.exception("ctl/%s scheduled for %.6g s failed", verb, at_s)
                reason = bounded(f"{type(exc).__name__}: {exc}")
            self.sim.last_error = self.request_refusals.refuse(
                self.keys.ctl(verb), f"ctl/{verb} scheduled for {at_s:.6g} s, refused at its time: {reason}")

        due = world.schedule.add(self.index, at_s, world.sim_time_s, world.steps, world.timestep_s, run)
        return world.sim_time_s + (due - world.steps) * world.timestep_s

    def _status_reply(self, ok: bool = True, error: str | None = None, off_loop: bool = False) -> CtlReply:
        """The reply to a ctl request; `off_loop` on a thread without the physics lock (from the snapshot)."""
        now = self.snapshot if off_loop else self._take_snapshot()
        return CtlReply(ok=ok, error=error, sim_time_s=now.sim_time_s, paused=now.paused, mode=now.mode,
                        steps=now.steps, episode=now.episode)

    def _take_snapshot(self) -> Snapshot:
        """(physics lock held) The figures off-loop replies give, taken together."""
        sim = self.sim
        return Snapshot(sim.sim_time_s, sim.steps, sim.mode, self.engine.paused, self.episode())

    # --- lockstep alone: each command advances ------------------------------------------------------

    def _on_advance(self, query: TypedQuery[MotorCommand, AdvanceReply]) -> None:
        """ctl/advance: stepped right on the query's thread, under the physics lock (no hand-over to the loop
        in the controller's round trip); the asking client is answered first, then everyone else."""
        key = self.keys.ctl("advance")
        with self.engine.physics:
            advanced = run_guarded(lambda: self._advance(query.request, hold_when_paused=False, key=key),
                                   "ctl/advance", lambda error: Advanced(AdvanceReply(ok=False, error=error)))
            query.reply(advanced.reply)  # ends the query: its client need not wait for the publishing
            self._publish(advanced)

    def _advance(self, command: MotorCommand, hold_when_paused: bool, key: str) -> Advanced:
        """(physics lock held) Apply `command` and advance the world `lockstep_steps` steps.

        While paused, a command from cmd/motors is held (ctl/step then runs it) and one from ctl/advance is
        refused: neither moves time.
        """
        engine, sim = self.engine, self.sim
        if engine.paused and not hold_when_paused:
            return Advanced(self._advance_reply(False, "paused: send ctl/resume (or ctl/step to step by hand)"))
        try:
            checked = sim.check_command(command)
        except CommandError as exc:
            error = self.command_refusals.refuse(key, str(exc))
            sim.reject(error)
            return Advanced(self._advance_reply(False, error))
        if engine.paused:
            sim.accept_command(command, checked)
            return Advanced(self._advance_reply(True))
        self.applied_seq += 1
        applied = AppliedCommand(sim_time_s=sim.sim_time_s, seq=self.applied_seq, steps=self.settings.lockstep_steps,
                                 command=command)
        broken = engine.advance({self.index: (command, checked)})
        if broken:
            return Advanced(self._advance_reply(False, bounded(f"the physics broke ({broken[0][1]}): reset")))
        states = engine.read_states()
        self.take_snapshot()
        mine = states[self.index]
        reply = AdvanceReply(ok=True, sim_time_s=sim.sim_time_s, steps=sim.steps, joints=mine.joints, odom=mine.odom,
                             imu=mine.imu, contacts=mine.contacts)
        return Advanced(reply, applied, states)

    def _advance_reply(self, ok: bool, error: str | None = None) -> AdvanceReply:
        return AdvanceReply(ok=ok, error=error, sim_time_s=self.sim.sim_time_s, steps=self.sim.steps)

    def _advance_refusal(self, error: str) -> AdvanceReply:
        """A refused ctl/advance, answered without the physics lock: time and steps from the snapshot."""
        now = self.snapshot
        return AdvanceReply(ok=False, error=error, sim_time_s=now.sim_time_s, steps=now.steps)

    def _bad_command(self, key: object, reason: str) -> str:
        """A bad command is a bad command, whichever way it came: counted with those on cmd/motors."""
        error = self.command_refusals.refuse(key, reason)
        self.sim.reject(error)
        return error

    def _publish(self, advanced: Advanced) -> None:
        """(physics lock held) The new instant for everyone: joints, odom, imu (what pub/sub clients wait on),
        then what was applied; then the fall check."""
        if advanced.states is None or advanced.applied is None or self.pub_applied is None:
            return
        self.engine.submit_states(advanced.states)
        self.pub_applied.put(advanced.applied)
        self.engine.check_falls()

    def stop_commands(self) -> None:
        """Undeclare cmd/motors (first, at shutdown: the command thread's recv ends; see SimService.close)."""
        self.commands.undeclare()

    def close(self) -> None:
        """Undeclare the rest, once the command thread has ended (it publishes states under lockstep)."""
        if self.token is not None:
            self.token.undeclare()
        for queryable in self._queryables:
            queryable.undeclare()
        self.description.undeclare()
        publishers: list[TypedPublisher] = [self.pub_joints, self.pub_odom, self.pub_imu, self.pub_contacts,
                                            self.pub_status]
        for publisher in publishers + ([self.pub_applied] if self.pub_applied else []):
            publisher.undeclare()
        self.requests.close("the sim is shutting down")  # no client hangs on a closing sim
