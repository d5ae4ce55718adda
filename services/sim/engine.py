"""The one simulation engine: a World of N >= 1 robots, its clock, its loop, and what its verbs do to it.

A robot alone and a world of several run here the same way: one loop (real time, or lockstep where time
moves only by advances), one place that runs ctl requests between two steps, one advance (a robot's
ctl/advance or cmd/motors under lockstep, world/advance), one broken-physics check after any steps, one
fall check, one state reader (the World's). What is served on the network is the endpoints' business
(robot_endpoint.py for each robot's keys, world_endpoint.py for the world's verbs); the engine drives
them through a small interface (`RobotPort`: put states, publish a status, the robot's request queue).

Threads (docs/architecture.md, "Threads"): MjData is read and written only by the thread holding
`physics`: the loop, or, under lockstep, the thread that advances (a ctl/advance or world/advance
callback, the command thread for cmd/motors). Zenoh callbacks hand ctl requests to each endpoint's
queue (requests.py); the loop runs them. Off-loop replies come from snapshots the lock holder replaces
whole (`RobotPort.take_snapshot`).
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
from collections.abc import Sequence
from typing import Protocol

from zensim.common.logs import RateLimitedLog
from zensim.common.pacing import GIL_SWITCH_INTERVAL_S, Pacer
from zensim.robots.builder import mode_figures
from zensim.schemas import CtlReply, ResetRequest, bounded
from zensim.schemas.messages import Mode, MotorCommand

from .physics import Checked, CommandError
from .requests import Request, Requests
from .settings import SimSettings
from .world import WHOLE_WORLD, World
from .world_states import Frame, StatePublisher, States

logger = logging.getLogger("zensim.sim")

PAUSED_POLL_S = 0.005
"""Longest the loop waits for a request while time stands still (paused, or lockstep between advances)."""
FAST_BATCH_STEPS = 10
"""Steps run back to back at rtf 0 with wall-clock states (0.2-0.4 ms of wall time)."""


class PhysicsLock:
    """A lock that knows which thread holds it, so the threading rule can be checked, not just written.

    Used as `with engine.physics:`; `held()` says whether the calling thread holds it.
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


class Port(Protocol):
    """What the engine needs of an endpoint: its request queue and a snapshot for replies made off the loop."""

    requests: Requests

    def take_snapshot(self) -> None:
        """(physics lock held) Take the figures that replies made off the loop give."""


class RobotPort(Port, Protocol):
    """One robot's endpoint, as the engine drives it."""

    def put_states(self, states: States) -> None:
        """Put one instant's states of the robot (any thread)."""

    def publish_status(self, rtf: float, fallen: bool, jitter_p99_s: float, waiting: bool) -> None:
        """(physics lock held) Publish the robot's SimStatus with the engine's figures."""

    def jumped(self, rebuilt: bool) -> None:
        """(physics lock held) The robot's state jumped (a reset; `rebuilt`: a new model): say so."""


class Engine:
    """Runs a World: its clock, its loop, its verbs.

    Args:
        world: the physics.
        settings: the sim's settings (rates, rtf, clock, fall reset).
        stop: set to end the loop.
    """

    def __init__(self, world: World, settings: SimSettings, stop: threading.Event) -> None:
        self.world = world
        self.settings = settings
        self.stop = stop
        self.physics = PhysicsLock()
        """Held by whichever thread reads or writes MjData (the loop; an advancing thread under lockstep)."""
        self.paused = settings.paused
        self.pacer = Pacer(world.timestep_s, settings.rtf)
        self.lockstep = settings.clock == "lockstep"
        for sim in world.robots:  # lockstep: time stands still between advances, so silence is no fault
            sim.watchdog_enabled = not self.lockstep
        self.request_log = RateLimitedLog(logger)
        """The log of what requests did (a reset, a mode switch): one line a second however many come."""
        self._reset_log = RateLimitedLog(logger)
        """The log of the resets the engine makes itself (broken physics, falls): one line a second."""
        self.work = threading.Event()
        """Set when any endpoint queued a request: the loop waits on this one event for all of them."""
        self.seqs = [0] * len(world)
        """Each robot's state numbering (its JointState/Odometry/Imu `seq`)."""
        self.robots: list[RobotPort] = []
        self._ports: list[Port] = []
        self.publisher: StatePublisher | None = None

    def serve(self, robots: Sequence[RobotPort], others: Sequence[Port] = ()) -> None:
        """The endpoints to drive: one per robot, in the world's order, and any other (the world's verbs)."""
        self.robots = list(robots)
        self._ports = [*others, *robots]
        # A world's states are built and put on a thread of their own (world_states.py); a robot alone's at once.
        self.publisher = StatePublisher(self.world.reader, self._put_all, threaded=len(self.world) > 1)

    # --- what the verbs do (physics lock held) ---------------------------------------------------

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False
        self.pacer.restart()

    def step(self, n: int) -> list[tuple[int, str]]:
        """While paused: run `n` steps, check the physics, publish every robot's states.

        Returns:
            What broke (World.broken), already followed by a reset.
        """
        self.world.step(n)
        broken = self._check_broken()
        self.publish_states()
        return broken

    def reset_robot(self, index: int, request: ResetRequest, publish: bool = True) -> None:
        """Reset one robot (a pose, a height, a mode); the other robots, world time and the pacer's schedule go
        on. The robot's scheduled requests (`at_s`) are dropped.

        A mode other than the world's rebuilds a world of one (one compile); a world of several refuses it.

        Raises:
            CommandError: the request does not fit the robot (nothing changed).
        """
        sim = self.world.robots[index]
        rebuilt = request.mode is not None and request.mode != sim.mode
        if rebuilt:
            assert request.mode is not None
            if len(self.world) != 1:  # one model for every robot: each stays in the mode it was built in
                raise CommandError(f"a world of {len(self.world)} robots keeps its mode ({sim.mode}); restart the "
                                   "world with another `mode`")
            sim.check_reset(request, mode_figures(sim.files, request.mode, sim.terrain))  # before anything changes
            self._rebuild(request.mode)
        sim.reset(request)
        self.world.schedule.drop(index)  # a new episode: the requests it had waiting were the last one's
        self.robots[index].jumped(rebuilt)
        if publish:
            self.publish_states(only=index)
            self.robots[index].publish_status(0.0, False, 0.0, False)

    def set_mode(self, index: int, mode: Mode) -> bool:
        """Switch a world of one to `mode` (rebuilt, reset to the mode's default pose); False: already in it.

        Raises:
            CommandError: a world of several robots (they share one model: each stays in its mode).
        """
        if mode == self.world.robots[index].mode:
            return False
        self.reset_robot(index, ResetRequest(mode=mode))
        return True

    def reset_world(self) -> None:
        """Every robot to its default pose, world time to 0, the schedule from now."""
        self.world.reset_time()
        for index in range(len(self.world)):
            self.reset_robot(index, ResetRequest(), publish=False)
        self.pacer = Pacer(self.world.timestep_s, self.settings.rtf)
        self.publish_states()
        self.publish_statuses(0.0)

    def advance(self, commands: dict[int, tuple[MotorCommand, Checked]]) -> list[tuple[int, str]]:
        """One lockstep advance: every command applied (each checked before), `lockstep_steps` steps with the
        targets held, the physics checked. The caller reads the new instant (`read_states`) when nothing broke.

        Returns:
            What broke (World.broken), already followed by a reset.
        """
        sims = self.world.robots
        for index, (command, checked) in commands.items():
            sims[index].accept_command(command, checked)
        steps = self.settings.lockstep_steps
        self.world.step(steps, held=True)
        self.pacer.stepped(steps)
        return self._check_broken()

    def read_states(self) -> list[States]:
        """Every robot's next-numbered states of this instant (the one state reader), not yet published."""
        return self.world.reader.messages(self._take_frame())

    def submit_states(self, states: list[States]) -> None:
        """Publish what read_states read (after the states queued before them)."""
        assert self.publisher is not None
        self.publisher.submit(states)

    def check_falls(self) -> None:
        """After an advance: the fall check the loop makes at each state it publishes."""
        if self.settings.auto_reset_on_fall and not self.paused:
            self._check_falls(self.world.fallen(self.world.take(self.seqs)))

    def publish_states(self, only: int | None = None) -> None:
        """Every robot's states of this instant (or robot `only`'s), put after those queued before."""
        assert self.publisher is not None
        if only is None:
            self.publisher.submit(self._take_frame())
            return
        self.seqs[only] += 1
        frame = self.world.take(self.seqs)
        self.publisher.drain()  # first: the frames before it go through the faults' report before this one does
        self.robots[only].put_states(self.world.reader.messages(frame, only)[only])

    def publish_statuses(self, rtf: float, waiting: bool = False) -> None:
        """Every robot's SimStatus (the world's one pacer's jitter, read once, told to every robot), and every
        endpoint's snapshot for replies made off the loop."""
        fallen = self.world.fallen(self.world.take(self.seqs))
        jitter = self.pacer.jitter_p99_s()
        for port, robot_fallen in zip(self.robots, fallen):
            port.publish_status(rtf, robot_fallen, jitter, waiting)
        for any_port in self._ports:
            any_port.take_snapshot()

    # --- the checks -----------------------------------------------------------------------------

    def _check_broken(self) -> list[tuple[int, str]]:
        """Broken physics, after any steps: MuJoCo's warnings reset the world, a robot's own state that robot."""
        broken = self.world.broken()
        if broken and broken[0][0] == WHOLE_WORLD:
            self.world.reset_time()
            for index in range(len(self.world)):
                self._physics_reset(index, broken[0][1])
        else:
            for index, reason in broken:
                self._physics_reset(index, reason)
        return broken

    def _physics_reset(self, index: int, reason: str) -> None:
        """Follow broken physics with a real reset to the default pose, and say so."""
        sim = self.world.robots[index]
        sim.physics_resets += 1
        sim.last_reset_reason = bounded(f"the physics broke: {reason}")
        self._reset_log.log(logging.ERROR, "%s: %s: resetting to the default pose", self._name(index),
                            sim.last_reset_reason)
        self.reset_robot(index, ResetRequest(randomize=sim.variants.request))  # the same variant: the same run

    def _check_falls(self, fallen: list[bool]) -> None:
        """With auto_reset_on_fall: reset each robot whose fall lasted fall_reset_delay_s of sim time."""
        if not self.settings.auto_reset_on_fall:
            return
        now = self.world.sim_time_s
        for index, (sim, robot_fallen) in enumerate(zip(self.world.robots, fallen)):
            if not robot_fallen:
                sim.fallen_since = None
            elif sim.fallen_since is None:
                sim.fallen_since = now
            elif now - sim.fallen_since >= self.settings.fall_reset_delay_s:
                self._reset_log.warning("%s fell: resetting (auto_reset_on_fall)", self._name(index))
                sim.last_reset_reason = "fallen (auto_reset_on_fall)"
                self.reset_robot(index, ResetRequest(randomize=sim.variants.request))  # the same variant again

    # --- inside ---------------------------------------------------------------------------------

    def _name(self, index: int) -> str:
        return list(self.world.sims)[index]

    def _rebuild(self, mode: Mode) -> None:
        """A world of one in `mode` (one compile), its schedule from now."""
        self.world.rebuild(mode)
        self.pacer = Pacer(self.world.timestep_s, self.settings.rtf)
        self.request_log.info("rebuilt in mode %s", mode)

    def _take_frame(self) -> Frame:
        """Every robot's next-numbered figures of this instant."""
        for index in range(len(self.seqs)):
            self.seqs[index] += 1
        return self.world.take(self.seqs)

    def _put_all(self, states: list[States]) -> None:
        """Put every robot's states of one instant on its keys (the publisher thread, or at once)."""
        for port, robot_states in zip(self.robots, states):
            port.put_states(robot_states)

    def _run_request(self, request: Request) -> CtlReply:
        """(loop thread) Run one ctl request under the physics lock (requests.py turns a failure into its reply)."""
        with self.physics:
            try:
                return request.run()
            finally:
                for port in self._ports:
                    port.take_snapshot()

    def _serve_requests(self, timeout_s: float = 0.0) -> None:
        """(loop thread) Run every waiting request of every endpoint; wait up to `timeout_s` for the first."""
        if not self.work.is_set():
            if timeout_s <= 0 or not self.work.wait(timeout_s):
                return
        self.work.clear()  # before the queues are read: a request queued from here on sets it again
        for port in self._ports:
            while port.requests.run_next(self._run_request):
                pass

    # --- the loop -------------------------------------------------------------------------------

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
        world, settings = self.world, self.settings
        publish_every = max(1, round(1.0 / (settings.state_rate_hz * world.timestep_s)))
        publish_period_s = 1.0 / settings.state_rate_hz
        status_period_s = 1.0 / settings.status_rate_hz
        wall_clock_states = settings.state_clock == "wall" or self.paused
        now = time.monotonic()
        next_status = next_publish = now
        with self.physics:
            last_status_wall, last_status_sim = now, world.sim_time_s
            self.publish_states()
        while not self.stop.is_set():
            if self.paused or self.lockstep:  # time stands still: only requests (and advances) move it
                self._serve_requests(PAUSED_POLL_S)
                publish_due = wall_clock_states = self.paused  # joining viewers still need a state
            else:
                self._serve_requests()
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
                    # effect at the next step boundary (the per-step target check in World.step).
                    n = publish_every - world.steps % publish_every
                with self.physics:
                    # Sensors only for a step whose instant may be published (World.step's `sensed`).
                    world.step(n, sensed=wall_clock_states or (world.steps + n) % publish_every == 0)
                    self.pacer.stepped(n)
                    publish_due = wall_clock_states or world.steps % publish_every == 0
                    if publish_due:
                        self._check_broken()
            now = time.monotonic()
            if publish_due and (not wall_clock_states or now >= next_publish):
                with self.physics:
                    next_publish = now + publish_period_s
                    frame = self._take_frame()
                    assert self.publisher is not None
                    self.publisher.submit(frame)  # a world's: built and put on its own thread, during the next steps
                    if self.settings.auto_reset_on_fall and not self.paused:  # else no fall is acted on
                        self._check_falls(world.fallen(frame))
            if now >= next_status:
                waiting = self.lockstep and not self.paused and not self.physics.locked()
                with self.physics:  # the status reads MjData: never while another thread advances
                    wall = now - last_status_wall
                    rtf = (world.sim_time_s - last_status_sim) / wall if wall > 0 else 0.0
                    self.publish_statuses(max(rtf, 0.0), waiting)
                    last_status_wall, last_status_sim = now, world.sim_time_s
                next_status = now + status_period_s

    def close(self) -> None:
        if self.publisher is not None:
            self.publisher.close()

