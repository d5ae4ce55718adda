"""Several robots in one MuJoCo world: the world file, the shared model, and the one loop that steps it.

`zensim sim --world lab.toml` builds ONE model holding every robot of the file (robots/builder.py
`build_world`: one floor, contacts between robots), steps it in one loop, and serves each robot
on its own key root `zensim/{robot}/...` through an ordinary SimService (service.py): the same
messages, ctl verbs, watchdog, bounds and episode as a robot alone, so the bridge, the viewer, the
recorder and the Unitree adapter work per robot unchanged. What is the world's rather than one
robot's lives under the world's id: `zensim/{world}/world/pause|resume|step|reset`.
`zensim/{world}/world/info` lists the world's robots (what `zensim viz --world` draws).

Time is the world's: a robot's ctl/pause, ctl/resume and ctl/step act on the whole world (its
robots cannot run apart), and a robot's ctl/reset resets only that robot (world time goes on).

Threads: as for one robot (docs/architecture.md, "Threads"), with one physics lock for the world,
shared by every robot's service; the loop here holds it while it steps and publishes.
"""

from __future__ import annotations

import gc
import logging
import math
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import msgspec
import mujoco
import numpy as np
import zenoh

from zensim.common.claim import current_owner, taken_message
from zensim.common.logs import RateLimitedLog
from zensim.common.pacing import Pacer
from zensim.common.session import StartupError
from zensim.common.wire import Refusals, decode_input, payload_of
from zensim.common.wire import reply as send
from zensim.robots import robot_files
from zensim.robots.builder import Placement, build_world
from zensim.robots.terrain import TerrainError, load_terrain, terrain_from_table
from zensim.schemas import (
    Codec,
    CtlReply,
    DecodeError,
    Keys,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    StepRequest,
    RobotStates,
    WorldAdvanceReply,
    WorldAdvanceRequest,
    WorldInfo,
    WorldRobot,
    bounded,
    is_json,
)
from zensim.schemas.bounds import vector_cap_bytes
from zensim.schemas.codec import Format
from zensim.schemas.keys import check_robot_id
from zensim.schemas.messages import Message, Mode, Terrain

from .physics import MAX_BASE_RISE_M, CommandError, MAX_BASE_SPEED_M_S, Limits, Simulation, broken_warning
from .requests import Request, Requests, run_guarded
from .service import FAST_BATCH_STEPS, GIL_SWITCH_INTERVAL_S, PAUSED_POLL_S, PhysicsLock, SimService, WorldClock
from .settings import SimSettings
from .world_commands import WorldCommands
from .world_states import Frame, StatePublisher, StateReader, States

logger = logging.getLogger("zensim.sim")

WORLD_INPUT_CAP_BYTES = 4096
"""Largest world/* request: they carry at most a step count."""
WATCHDOG_CHECK_PERIOD_S = 0.01
"""How often the world asks each robot's command watchdog (its timeout is 0.5 s by default, at least 10 ms):
once per state period rather than once per robot and step, which cost 5 % of a 32-G1 world's loop."""


class RobotEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One `[[robots]]` table of a world file."""

    id: str
    """The robot's id: its key root is zensim/{id}/."""
    robot: str | None = None
    """A bundled robot (unitree_g1, alias g1); default unitree_g1 unless `urdf` is given."""
    urdf: str | None = None
    """Any URDF instead (meshes resolve beside it); a relative path is relative to the world file."""
    control: str | None = None
    """Its control file (default: the bundled robot's, else control.toml beside the URDF)."""
    xy: tuple[float, float] = (0.0, 0.0)
    """Spawn position of the base in the world, m."""
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360, le=360)] = 0.0
    """Spawn heading, degrees about the world's z (0 faces +x)."""
    mode: Mode | None = None
    """floating or fixed (welded on a stand at its spawn); default: --mode."""


class WorldFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A world file: `id` (the world's key root, default `world`) and its robots."""

    robots: Annotated[list[RobotEntry], msgspec.Meta(min_length=1, max_length=256)]
    id: str = "world"
    terrain: Terrain | None = None
    """The `[terrain]` table: the world's ground (robots/terrain.py); none: the flat floor."""


def read_world_file(path: str) -> WorldFile:
    """Parse and check a world file.

    Raises:
        StartupError: unreadable, malformed, unknown fields, duplicate or bad ids, non-finite spawns.
    """
    try:
        text = Path(path).read_bytes()
        world = msgspec.toml.decode(text, type=WorldFile)
        if world.terrain is not None:  # checked as a terrain file is: an unknown key in it is refused
            terrain_from_table(msgspec.toml.decode(text)["terrain"])
        ids = [world.id, *(entry.id for entry in world.robots)]
        for robot_id in ids:
            check_robot_id(robot_id)
        if len(set(ids)) != len(ids):
            raise ValueError(f"ids must be unique (the world's and its robots'): {ids}")
        for entry in world.robots:
            if not all(math.isfinite(v) and abs(v) <= 1e4 for v in entry.xy):
                raise ValueError(f"robot {entry.id}: xy must be finite and within 10 km")
    except (OSError, ValueError, msgspec.DecodeError) as exc:
        raise StartupError(f"world file {path} (--world / ZENSIM_SIM_WORLD): {bounded(str(exc), 400)}") from None
    return world


class World:
    """One MjModel/MjData holding every robot, and the Simulation of each (which share the data)."""

    def __init__(self, world_file: WorldFile, base: Path, settings: SimSettings, terrain: Terrain | None = None) -> None:
        self.id = world_file.id
        self.terrain = terrain
        self.entries = tuple(world_file.robots)
        placements = []
        try:
            for entry in world_file.robots:
                urdf = None if entry.urdf is None else str(base / entry.urdf)
                control = None if entry.control is None else str(base / entry.control)
                files = robot_files(None if urdf else (entry.robot or "unitree_g1"), urdf=urdf, control=control)
                placements.append(Placement(f"{entry.id}/", files, entry.xy, math.radians(entry.yaw_deg), entry.mode))
            robots = build_world(placements, settings.mode, settings.timestep_s, terrain)
        except (OSError, ValueError) as exc:
            raise StartupError(f"cannot build the world ({settings.world}): {bounded(str(exc), 400)}") from None
        self.model = robots[0].model
        self.data = mujoco.MjData(self.model)
        self.mode: Mode = settings.mode
        self.steps = 0
        self.resets = 0
        limits = Limits(max_kp=settings.max_kp, max_kd=settings.max_kd)
        self.sims: dict[str, Simulation] = {}
        for entry, placement, robot in zip(world_file.robots, placements, robots):
            self.sims[entry.id] = Simulation(placement.files, robot.mode, limits, settings.watchdog_timeout_s,
                                             shared=(robot, self.data, self.step), terrain=terrain)
        self._sims = tuple(self.sims.values())
        for sim in self._sims:  # lockstep: time stands still between advances, so silence is no fault
            sim.watchdog_enabled = settings.clock == "realtime"
        floating = [sim.robot for sim in self._sims if sim.robot.free_qpos_adr >= 0]
        self._free = (np.array([r.free_qpos_adr + 2 for r in floating], int),
                      np.array([r.free_dof_adr for r in floating], int)[:, None] + np.arange(3),
                      np.array([r.base_height_m + MAX_BASE_RISE_M for r in floating]))
        """Each floating robot's base height in qpos, its linear velocity in qvel (rows of 3), and its
        highest sound base height."""
        self.reader = StateReader(self._sims)
        self._next_watchdog_check = 0.0
        self._fall_tilt_rad = np.array([sim.robot.control.model.fall_tilt_rad if sim.mode == "floating" else np.inf
                                        for sim in self._sims])
        """Each robot's fall threshold; a fixed robot never falls."""
        mujoco.mj_forward(self.model, self.data)

    @property
    def timestep_s(self) -> float:
        return float(self.model.opt.timestep)

    def step(self, n: int = 1, held: bool = False) -> None:
        """(physics lock held) Advance every robot `n` steps together, each with its own targets.

        `held`: the targets are the same for all `n` steps (world/advance: commands land between advances),
        so MuJoCo runs the middle steps in one call, without handing the GIL back and forth at each
        (Simulation.step says why a step is mj_step2 then mj_step1; mj_step2, mj_step n-1 times, mj_step1
        is that sequence to the bit, tests/test_world.py).
        """
        model, data, sims = self.model, self.data, self._sims
        now = time.monotonic()
        check_watchdog = now >= self._next_watchdog_check
        if check_watchdog:
            self._next_watchdog_check = now + WATCHDOG_CHECK_PERIOD_S
        if held and n > 1:
            for sim in sims:
                sim.apply_targets(check_watchdog)
            mujoco.mj_step2(model, data)
            mujoco.mj_step(model, data, nstep=n - 1)
            mujoco.mj_step1(model, data)
        for _ in range(0 if held and n > 1 else n):
            for sim in sims:
                sim.apply_targets(check_watchdog)
            check_watchdog = False
            mujoco.mj_step2(model, data)
            mujoco.mj_step1(model, data)
        self.steps += n
        for sim in sims:
            sim.steps += n

    def broken_sims(self) -> list[Simulation]:
        """(physics lock held) The robots whose state cannot be trusted (Simulation.broken), checked for all
        robots at once first: only when something is off does each robot look at itself."""
        data, (heights_at, velocities_at, highest) = self.data, self._free
        qpos, qvel = data.qpos, data.qvel
        sound = np.isfinite(qpos).all() and np.isfinite(qvel).all()
        if sound and len(heights_at):
            velocities = qvel[velocities_at]
            speeds2 = np.einsum("ij,ij->i", velocities, velocities)
            sound = bool((qpos[heights_at] <= highest).all() and (speeds2 <= MAX_BASE_SPEED_M_S ** 2).all())
        return [] if sound else [sim for sim in self._sims if sim.broken()]

    def fallen(self, frame: Frame) -> list[bool]:
        """Whether each robot of a frame tilts past its fall threshold (as Simulation.fallen, all at once)."""
        return (frame.tilts_rad() > self._fall_tilt_rad).tolist()

    def reset_time(self) -> None:
        """(physics lock held) mj_resetData of the whole world: time 0, warnings cleared (robots reset next)."""
        mujoco.mj_resetData(self.model, self.data)
        self.steps = 0
        self.resets += 1


def world_info(world: World, robots: list[SimService]) -> WorldInfo:
    """world/info's answer: the world's id and, for each robot in file order, its model, mode and spawn."""
    return WorldInfo(world=world.id, robots=tuple(
        WorldRobot(robot=entry.id, model=robot._info.model, mode=robot._info.mode, xy=entry.xy, yaw_deg=entry.yaw_deg)
        for entry, robot in zip(world.entries, robots)), terrain=world.terrain)


def load_world(settings: SimSettings) -> World:
    """Read the world file the settings name and build it (before the session: a bad file fails fast)."""
    assert settings.world is not None
    world_file = read_world_file(settings.world)
    terrain = world_file.terrain
    if settings.terrain:
        if terrain is not None:
            raise StartupError(f"the world file {settings.world} has a [terrain] table and --terrain names another: give one")
        try:
            terrain = load_terrain(settings.terrain)
        except TerrainError as exc:
            raise StartupError(f"terrain (--terrain / ZENSIM_SIM_TERRAIN): {bounded(str(exc), 400)}") from None
    world = World(world_file, Path(settings.world).resolve().parent, settings, terrain)
    logger.info("world %s: %d robots (%s), %d bodies, mode %s, step %.4f s", world.id, len(world.sims),
                ", ".join(world.sims), world.model.nbody, world.mode, world.timestep_s)
    return world


class WorldService:
    """Serves every robot of a World (one SimService each) and the world's own verbs; runs the one loop."""

    def __init__(self, session: zenoh.Session, settings: SimSettings, world: World, stop: threading.Event) -> None:
        self.world = world
        self.settings = settings
        self.stop = stop
        self.keys = Keys(world.id)
        self.run_id = uuid.uuid4().hex[:16]
        self.clock = WorldClock(settings.paused, Pacer(world.timestep_s, settings.rtf))
        self.physics = PhysicsLock()
        refusal_logs = (RateLimitedLog(logger), RateLimitedLog(logger))  # a flood to every robot: one line a second
        self.robots = [
            SimService(session, msgspec.structs.replace(settings, robot_id=robot_id), sim, stop,
                       world=(self.clock, self.physics), refusal_logs=refusal_logs)
            for robot_id, sim in world.sims.items()
        ]
        self._by_sim = {id(robot.sim): robot for robot in self.robots}
        self._unpublished: list[States] | None = None
        """States an advance read, put once its client has the reply (physics lock held)."""
        self.commands = WorldCommands(self.robots)
        """Takes every robot's commands on one thread (world_commands.py)."""
        self.publisher = StatePublisher(world.reader, self._put_all)
        """Puts the loop's states from a thread of its own (world_states.py)."""
        for robot in self.robots:  # a robot's own puts (reset, ctl/step) wait for the states queued before them
            robot.before_direct_put = self.publisher.drain
        self.refusals = Refusals(logger, "world request")
        self.lockstep = settings.clock == "lockstep"
        self.advance_cap_bytes = WORLD_INPUT_CAP_BYTES + sum(vector_cap_bytes(sim.robot.joint_names)
                                                             for sim in world.sims.values())
        self.requests = Requests(lambda reason: self._reply(ok=False, error=reason))
        self.reply_codec = Codec(CtlReply)
        self._last = self._take_reply_state()
        keys = self.keys
        self._declared = [
            session.declare_queryable(keys.world_pause, self._verb(keys.world_pause, PauseRequest, self._pause)),
            session.declare_queryable(keys.world_resume, self._verb(keys.world_resume, ResumeRequest, self._resume)),
            session.declare_queryable(keys.world_step, self._verb(keys.world_step, StepRequest, self._step)),
            session.declare_queryable(keys.world_reset, self._verb(keys.world_reset, ResetRequest, self._reset)),
            session.declare_queryable(keys.world_advance, self._verb(keys.world_advance, WorldAdvanceRequest,
                                                                     self._advance, self.advance_cap_bytes)),
        ]
        self.info, self.info_codec = world_info(world, self.robots), Codec(WorldInfo)
        self._declared.append(session.declare_queryable(keys.world_info, self._on_info))
        for robot in self.robots:  # alive/sim last: a client that saw it finds the world's verbs served too
            robot.announce()
        self.token = session.liveliness().declare_token(keys.alive("world"))
        """The world's own id is taken while it runs (services/common/claim.py)."""

    # --- world/info: what the world holds --------------------------------------------------------

    def _on_info(self, query: zenoh.Query) -> None:
        """Answer world/info (WorldInfo, made once: a world's robots never change while it runs).

        Exact key only, as the verbs: a reply to a wildcard would not say which world it lists.
        The payload is never decoded; JSON is asked for as on info/robot (`?format=json` or a JSON payload).
        """
        own_key = self.keys.world_info
        payload = query.payload
        if payload is not None and len(payload) > WORLD_INPUT_CAP_BYTES:
            error = f"payload of {len(payload)} bytes is over this key's cap of {WORLD_INPUT_CAP_BYTES} bytes"
        elif str(query.key_expr) != own_key:
            error = f"answers only a query for exactly {own_key}"
        else:
            json_wanted = "format=json" in str(query.parameters) or (payload is not None and is_json(*payload_of(query)))
            send(query, own_key, self.info, "json" if json_wanted else "msgpack", self.info_codec)
            return
        query.reply_err(self.refusals.refuse(query.key_expr, error).encode())

    # --- the world's verbs ---------------------------------------------------------------------

    def _verb(self, own_key: str, request_type: type, handler: Callable,
              cap_bytes: int = WORLD_INPUT_CAP_BYTES) -> Callable[[zenoh.Query], None]:
        codec: Codec[Message] = Codec(request_type)
        advance = request_type is WorldAdvanceRequest

        def reply(query: zenoh.Query, key: str, message: CtlReply | WorldAdvanceReply, fmt: Format, _codec: Codec) -> None:
            if advance and isinstance(message, CtlReply):  # a refusal made before the request ran
                message = WorldAdvanceReply(ok=False, error=message.error, sim_time_s=message.sim_time_s,
                                            steps=message.steps)
            send(query, key, message, fmt, _codec)

        def on_query(query: zenoh.Query) -> None:
            payload = query.payload
            fmt: Format = ("json" if payload is None or len(payload) > cap_bytes
                           or is_json(*payload_of(query)) else "msgpack")
            if str(query.key_expr) != own_key:
                error = self.refusals.refuse(query.key_expr, f"acts only on a query for exactly {own_key}; nothing was done")
                reply(query, own_key, self._reply(ok=False, error=error), fmt, self.reply_codec)
                return
            try:
                request = decode_input(query, codec, cap_bytes)
            except DecodeError as exc:
                reply(query, own_key, self._reply(ok=False, error=self.refusals.refuse(query.key_expr, str(exc))),
                      fmt, self.reply_codec)
                return

            def answer(query: zenoh.Query, message: CtlReply) -> None:
                if not message.ok:
                    self.refusals.refuse(query.key_expr, message.error or "refused")
                reply(query, own_key, message, fmt, self.reply_codec)

            if advance:
                # As ctl/advance of a robot alone (lockstep.py): stepped on this thread, under the physics
                # lock, answered first and then published; no hand-over to the loop thread on the way.
                with self.physics:
                    self._unpublished = None
                    message = run_guarded(lambda: handler(request), "world/advance",
                                          lambda error: self._reply(ok=False, error=error))
                    answer(query, message)
                    query.drop()
                    if self._unpublished is not None:  # put by the publisher thread, while the client reads
                        self.publisher.submit(self._unpublished)
                    self._last = self._take_reply_state()
                return
            self.requests.submit(Request(query, lambda: handler(request), answer))

        return on_query

    def _take_reply_state(self) -> CtlReply:
        """(physics lock held) The world's figures, taken whole, for replies made off the loop."""
        world = self.world
        return CtlReply(ok=True, sim_time_s=float(world.data.time), paused=self.clock.paused, mode=world.mode,
                        steps=world.steps, episode=f"{self.run_id}.{world.resets}")

    def _reply(self, ok: bool = True, error: str | None = None) -> CtlReply:
        return msgspec.structs.replace(self._last, ok=ok, error=error)

    def _pause(self, _request: PauseRequest) -> CtlReply:
        self.clock.paused = True
        return self._take_reply_state()

    def _resume(self, _request: ResumeRequest) -> CtlReply:
        self.clock.paused = False
        self.clock.pacer.restart()
        return self._take_reply_state()

    def _step(self, request: StepRequest) -> CtlReply:
        if not self.clock.paused:
            return self._reply(ok=False, error="world/step works while paused; send world/pause first")
        self.world.step(request.n)
        self._after_steps()
        self._publish_states()
        return self._take_reply_state()

    def _reset(self, request: ResetRequest) -> CtlReply:
        if request != ResetRequest():
            return self._reply(ok=False, error="world/reset takes an empty request (every robot to its default "
                                               "pose); send ctl/reset to one robot for a pose, a height or a mode")
        self.world.reset_time()
        for robot in self.robots:
            robot._reset(ResetRequest())
        self.clock.pacer = Pacer(self.world.timestep_s, self.settings.rtf)
        logger.info("world reset")
        return self._take_reply_state()

    def _publish_states(self) -> None:
        """(physics lock held) Every robot's states of this instant, put now (after those queued before)."""
        self._put_states(self._read_states())

    def _take_frame(self) -> Frame:
        """(physics lock held) Every robot's next-numbered figures of this instant (one read of MjData for all)."""
        robots = self.robots
        for robot in robots:
            robot.seq += 1
        return self.world.reader.take(self.world.data, [r.seq for r in robots])

    def _read_states(self) -> list[States]:
        """(physics lock held) Every robot's next-numbered states of this instant, not yet published."""
        return self.world.reader.messages(self._take_frame())

    def _put_states(self, states: list[States]) -> None:
        """(physics lock held) Put what _read_states read, on each robot's keys, after the queued frames."""
        self.publisher.drain()
        self._put_all(states)

    def _put_all(self, states: list[States]) -> None:
        """Put every robot's states of one instant on its keys (the publisher thread, or a drained queue)."""
        for robot, (joints, odom, imu) in zip(self.robots, states):
            robot.put_states(joints, odom, imu)

    def _advance(self, request: WorldAdvanceRequest) -> WorldAdvanceReply | CtlReply:
        """(physics lock held, on the query's thread) Every command checked first, then all applied, then one advance."""
        if not self.lockstep:
            return self._reply(ok=False, error="world/advance works under --clock lockstep; this world runs in real time")
        if self.clock.paused:
            return self._reply(ok=False, error="paused: send world/resume (or world/step to step by hand)")
        sims = self.world.sims
        unknown = [robot for robot in request.commands if robot not in sims]
        if unknown:
            return self._reply(ok=False, error=bounded(f"no robot {unknown[0]!r} in this world; robots: {', '.join(sims)}"))
        checked = {}
        for robot, command in request.commands.items():
            try:
                checked[robot] = sims[robot].check_command(command)
            except CommandError as exc:
                return self._reply(ok=False, error=bounded(f"robot {robot}: {exc}; nothing was applied"))
        for robot, command in request.commands.items():
            sims[robot].accept_command(command, checked[robot])
        self.world.step(self.settings.lockstep_steps, held=True)
        self._after_steps()
        states = self._unpublished = self._read_states()  # published once the client has its reply
        return WorldAdvanceReply(ok=True, sim_time_s=float(self.world.data.time), steps=self.world.steps,
                                 states={robot.keys.robot: RobotStates(joints=j, odom=o, imu=i)
                                         for robot, (j, o, i) in zip(self.robots, states)})

    def _run_request(self, request: Request) -> CtlReply:
        with self.physics:
            message = run_guarded(request.run, "a world request", lambda error: self._reply(ok=False, error=error))
            self._last = self._take_reply_state()
        return message

    # --- the loop -------------------------------------------------------------------------------

    def _run_jobs(self) -> None:
        """(loop thread) Every waiting request: the world's, then each robot's."""
        if not self.requests.empty():  # the common case, without raising queue.Empty
            while self.requests.run_next(0.0, self._run_request):
                pass
        for robot in self.robots:
            robot._run_jobs()

    def _after_steps(self) -> None:
        """(physics lock held) Broken physics: MuJoCo's warnings reset the world, a robot's own state that robot."""
        reason = broken_warning(self.world.data)
        if reason:
            self.world.reset_time()
            for robot in self.robots:
                robot._physics_reset(reason)
            return
        for sim in self.world.broken_sims():
            robot = self._by_sim[id(sim)]
            reason = sim.broken()
            if reason:
                robot._physics_reset(reason)

    def run(self) -> None:
        """Step every robot, publish each one's states and status, serve requests, until stopped.

        The same schedule as SimService.run for one robot (service.py), over all robots at once.
        """
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)  # why: service.py SimService.run
        gc.freeze()  # why: service.py SimService.run
        world, settings, clock, robots = self.world, self.settings, self.clock, self.robots
        timestep = world.timestep_s
        publish_every = max(1, round(1.0 / (settings.state_rate_hz * timestep)))
        publish_period_s = 1.0 / settings.state_rate_hz
        status_period_s = 1.0 / settings.status_rate_hz
        wall_clock_states = settings.state_clock == "wall" or clock.paused
        now = time.monotonic()
        next_status = next_publish = now
        with self.physics:
            last_status_wall, last_status_sim = now, float(world.data.time)
            self._publish_states()
        while not self.stop.is_set():
            self._run_jobs()
            if self.lockstep:  # time moves only by world/advance (and world/step while paused): wait for one
                self.requests.run_next(PAUSED_POLL_S, self._run_request)
                publish_due, wall_clock_states = clock.paused, True
            elif clock.paused:
                time.sleep(PAUSED_POLL_S)
                publish_due = wall_clock_states = True
            else:
                wall_clock_states = settings.state_clock == "wall"
                if settings.rtf > 0:
                    clock.pacer.wait()
                    n = 1
                elif wall_clock_states:
                    n = FAST_BATCH_STEPS
                else:
                    n = publish_every - world.steps % publish_every
                with self.physics:
                    world.step(n)
                    clock.pacer.stepped(n)
                    publish_due = wall_clock_states or world.steps % publish_every == 0
                    if publish_due:
                        self._after_steps()
            now = time.monotonic()
            with self.physics:
                if publish_due and (not wall_clock_states or now >= next_publish):
                    next_publish = now + publish_period_s
                    frame = self._take_frame()
                    self.publisher.submit(frame)  # built and put on the publisher thread, during the next steps
                    fallen = world.fallen(frame)
                    if not clock.paused:
                        for robot, robot_fallen in zip(robots, fallen):
                            robot._check_fall(robot_fallen)
                if now >= next_status:
                    wall = now - last_status_wall
                    rtf = (float(world.data.time) - last_status_sim) / wall if wall > 0 else 0.0
                    fallen = world.fallen(world.reader.take(world.data, [r.seq for r in robots]))
                    jitter = clock.pacer.jitter_p99_s()  # the world's one pacer: read once, told to every robot
                    for robot, robot_fallen in zip(robots, fallen):
                        robot._publish_status(max(rtf, 0.0), robot_fallen, jitter)
                        robot._snapshot = robot._take_snapshot()  # for replies made off the loop
                    last_status_wall, last_status_sim = now, float(world.data.time)
                    next_status = now + status_period_s
                self._last = self._take_reply_state()

    def close(self) -> None:
        self.token.undeclare()
        for entity in self._declared:
            entity.undeclare()
        self.commands.close()
        self.publisher.close()
        self.requests.close("the world is shutting down")
        for robot in self.robots:
            robot.close()


def run_world(session: zenoh.Session, settings: SimSettings, stop: threading.Event, world: World) -> int:
    """Serve `world` on the session until `stop` is set. Returns the exit code."""
    for robot_id in (world.id, *world.sims):
        owner = current_owner(session, Keys(robot_id))
        if owner is not None:
            raise StartupError(taken_message(robot_id, owner))
    service = WorldService(session, settings, world, stop)
    logger.info("world up on %s/world: %s", service.keys.root, ", ".join(f"zensim/{r}" for r in world.sims))
    try:
        service.run()
    finally:
        service.close()
    logger.info("world stopped after %.1f sim s", float(world.data.time))
    return 0
