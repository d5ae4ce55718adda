"""The physics of a world: one MjModel/MjData holding N >= 1 robots, stepped together. No network.

A robot alone is a world of one (`World.alone`: its own model, as `zensim.robots.builder.build` makes
it); `zensim sim --world lab.toml` is a world of several (`World.of_file`: one model from
`build_world`, one floor, contacts between the robots). Either way this class is the one place that
steps MuJoCo, checks the state is sound and reads every robot's states (world_states.py's reader);
each robot's own part (its commands, watchdog, pose, fall) is its Simulation (physics.py).

Everything here is for the thread holding the engine's physics lock (docs/architecture.md, "Threads").
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import mujoco
import numpy as np

from zensim.robots import RobotFiles, robot_files
from zensim.robots.builder import Placement, Robot, build, build_world
from zensim.schemas.messages import Mode, Terrain

from .physics import MAX_BASE_RISE_M, MAX_BASE_SPEED_M_S, Limits, Simulation, broken_warning
from .schedule import Schedule
from .world_file import WorldFile
from .world_states import FEW_ROBOTS, Frame, StateReader

logger = logging.getLogger("zensim.sim")

WATCHDOG_CHECK_PERIOD_S = 0.01
"""How often the world asks each robot's command watchdog (its timeout is 0.5 s by default, at least 10 ms):
once per state period rather than once per robot and step, which cost 5 % of a 32-G1 world's loop."""
SENSORS_OFF = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
"""MuJoCo's flag that skips the sensor stages of a step."""
WHOLE_WORLD = -1
"""World.broken's robot index for a fault of the whole world (MuJoCo's warnings: its data is the world's)."""


class World:
    """One MjModel/MjData holding every robot, and the Simulation of each (which share the data).

    Args:
        world_id: the world's id (a robot alone: its own id).
        ids: each robot's id, in order.
        files: each robot's files.
        robots: each robot in the one model (all share `robots[0].model`).
        limits: bounds on commanded gains.
        watchdog_timeout_s: wall-clock silence after which a robot holds its default pose.
        mode: the world's mode (a robot of a world file may stand in its own).
        timestep_s: the physics step asked for (None: the robots' control file's); kept for a rebuild.
        terrain: the ground built into the model (robots/terrain.py), described in info/robot; None: flat.
    """

    def __init__(self, world_id: str, ids: list[str], files: list[RobotFiles], robots: list[Robot], limits: Limits,
                 watchdog_timeout_s: float, mode: Mode, timestep_s: float | None = None,
                 terrain: Terrain | None = None) -> None:
        self.id = world_id
        self.mode: Mode = mode
        self.terrain = terrain
        self.steps = 0
        self.resets = 0
        self._timestep_s = timestep_s
        self.model = robots[0].model
        self.data = mujoco.MjData(self.model)
        self.sims: dict[str, Simulation] = {
            robot_id: Simulation(f, robot, self.data, limits, watchdog_timeout_s, terrain)
            for robot_id, f, robot in zip(ids, files, robots)}
        self.robots = tuple(self.sims.values())
        """Each robot's Simulation, in order."""
        self._unsensed = False
        """The last step ran without MuJoCo's sensors (`step`'s `sensed`)."""
        self.schedule = Schedule()
        """ctl requests waiting for their sim time (`at_s`): carried out by `step`, before the step that starts there."""
        self._next_watchdog_check = 0.0
        self._derive()
        mujoco.mj_forward(self.model, self.data)

    @staticmethod
    def alone(robot_id: str, files: RobotFiles, mode: Mode, limits: Limits, watchdog_timeout_s: float,
              timestep_s: float | None = None, terrain: Terrain | None = None) -> World:
        """A world of one robot: the model `build` makes (compiled once)."""
        return World(robot_id, [robot_id], [files], [_alone(files, mode, timestep_s, terrain)], limits,
                     watchdog_timeout_s, mode, timestep_s, terrain)

    @staticmethod
    def of_file(world_file: WorldFile, base: Path, mode: Mode, limits: Limits, watchdog_timeout_s: float,
                timestep_s: float | None = None, terrain: Terrain | None = None) -> World:
        """A world file's robots in one model (build_world: compiled once).

        Raises:
            OSError, ValueError: a robot's files cannot be read or built.
        """
        placements = []
        for entry in world_file.robots:
            urdf = None if entry.urdf is None else str(base / entry.urdf)
            control = None if entry.control is None else str(base / entry.control)
            files = robot_files(None if urdf else (entry.robot or "unitree_g1"), urdf=urdf, control=control)
            placements.append(Placement(f"{entry.id}/", files, entry.xy, math.radians(entry.yaw_deg), entry.mode))
        robots = build_world(placements, mode, timestep_s, terrain)
        return World(world_file.id, [entry.id for entry in world_file.robots], [p.files for p in placements], robots,
                     limits, watchdog_timeout_s, mode, timestep_s, terrain)

    def _derive(self) -> None:
        """What the step and the checks work out once per model, for all robots at once."""
        sims = self.robots
        floating = [sim.robot for sim in sims if sim.robot.free_qpos_adr >= 0]
        self._free = (np.array([r.free_qpos_adr + 2 for r in floating], int),
                      np.array([r.free_dof_adr for r in floating], int).reshape(-1, 1) + np.arange(3),
                      np.array([r.base_height_m + MAX_BASE_RISE_M for r in floating]))
        """Each floating robot's base height in qpos, its linear velocity in qvel (rows of 3), and its
        highest sound base height."""
        self.reader = StateReader(sims)
        """Reads every robot's states of one instant: the one state reader (the sim, `zensim resim`)."""
        self._fall_tilt_rad = np.array([sim.robot.control.model.fall_tilt_rad if sim.mode == "floating" else np.inf
                                        for sim in sims])
        """Each robot's fall threshold; a fixed robot never falls."""

    def __len__(self) -> int:
        return len(self.robots)

    @property
    def timestep_s(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def sim_time_s(self) -> float:
        return float(self.data.time)

    def rebuild(self, mode: Mode) -> None:
        """(a world of one) Build the robot again in `mode`, with new data at time 0: one compile.

        Raises:
            ValueError: a world of several robots (they share one model: each stays in its mode).
        """
        if len(self.robots) != 1:
            raise ValueError(f"a world of {len(self.robots)} robots keeps its mode; restart it with another `mode`")
        (sim,) = self.robots
        robot = _alone(sim.files, mode, self._timestep_s, self.terrain)
        self.model, self.data = robot.model, mujoco.MjData(robot.model)
        self.mode = mode
        self.steps = 0
        self.schedule.drop()  # time starts again at 0: what waited was the old episode's
        sim.attach(robot, self.data)
        self._derive()

    def step(self, n: int = 1, held: bool = False, sensed: bool = True) -> None:
        """Advance every robot `n` steps together, each with its own targets.

        A step runs as MuJoCo's split pair: mj_step2 (actuation, acceleration, integration) then mj_step1
        (positions, velocities and their sensors at the new instant). So between steps `data` always
        describes its own `data.time`: a state read now is not one step stale (a plain mj_step leaves body
        poses and sensors at the start of the step), and it costs no extra mj_forward. Only
        acceleration-stage values (the IMU's accelerometer, qfrc_actuator) describe the step that just ended.

        `held`: the targets are the same for all `n` steps (an advance: commands land between advances), so
        MuJoCo runs the middle steps in one call, without handing the GIL back and forth at each
        (mj_step2, mj_step n-1 times, mj_step1 is the step-by-step sequence to the bit, tests/test_world.py).

        `sensed`: MuJoCo's sensors are computed for the last of the `n` steps (False: for none). The sensors
        only feed the states, read after a step whose instant is published; skipping them at the other steps
        saves their cost (the feet's contact sensors: 3 us of the G1's 30-40 us step, 8-10 %). The physics
        does not read them: the steps are the same to the bit. `take` brings the position and velocity
        sensors up to date for a read after an unsensed step (a status's fall check).
        """
        model, data, sims = self.model, self.data, self.robots
        now = time.monotonic()
        check_watchdog = now >= self._next_watchdog_check
        if check_watchdog:
            self._next_watchdog_check = now + WATCHDOG_CHECK_PERIOD_S
        # A push or the band is a force worked out at every step boundary: then no steps run in one call.
        disturbed = [sim.disturbances for sim in sims if sim.disturbances.active()]
        # A delayed command in flight (ctl/faults' link) lands at its own step, a scheduled request too: then no
        # steps run in one call either.
        schedule = self.schedule
        batched = (held and n > 1 and not disturbed and schedule.next_step >= self.steps + n
                   and not any(sim.link.busy() for sim in sims))
        opt = model.opt
        blind = opt.disableflags | SENSORS_OFF
        seeing = blind & ~SENSORS_OFF
        opt.disableflags = blind
        try:
            if batched:
                for sim in sims:
                    sim.apply_targets(check_watchdog)
                mujoco.mj_step2(model, data)
                if n > 2:
                    mujoco.mj_step(model, data, nstep=n - 2)
                if sensed:
                    opt.disableflags = seeing
                mujoco.mj_step(model, data)
                mujoco.mj_step1(model, data)
            for i in range(0 if batched else n):
                if schedule.next_step <= self.steps + i:  # requests due before this step (a push, a fault): now
                    schedule.run_due(self.steps + i)
                    disturbed = [sim.disturbances for sim in sims if sim.disturbances.active()]
                for sim in sims:
                    sim.apply_targets(check_watchdog, i)
                check_watchdog = False
                for disturbances in disturbed:
                    disturbances.apply()
                if sensed and i == n - 1:
                    opt.disableflags = seeing
                mujoco.mj_step2(model, data)
                mujoco.mj_step1(model, data)
        finally:  # whatever happened in the steps, the model leaves here computing its sensors
            opt.disableflags = seeing
        self._unsensed = not sensed
        self.steps += n
        for sim in sims:
            sim.steps += n

    def broken(self) -> list[tuple[int, str]]:
        """Why the state cannot be trusted: (WHOLE_WORLD, reason) for MuJoCo's own guards, which are the whole
        world's (its data is), else (robot index, reason) for each robot whose own state is unsound; empty
        while all is sound. The one broken-physics check, after any steps, whoever ran them.

        MuJoCo's guards fire for NaN or huge accelerations, velocities, positions or controls: it then zeroes
        the controls or silently resets mjData to the model's reference pose every step (time stuck at 0).
        Every robot is checked at once first: only when something is off does each look at itself.
        """
        reason = broken_warning(self.data)
        if reason:
            return [(WHOLE_WORLD, reason)]
        if len(self.robots) <= FEW_ROBOTS:  # a robot alone: its own check costs half the vectorised one
            return [(index, reason) for index, sim in enumerate(self.robots) if (reason := sim.broken() or "")]
        data, (heights_at, velocities_at, highest) = self.data, self._free
        qpos, qvel = data.qpos, data.qvel
        sound = np.isfinite(qpos).all() and np.isfinite(qvel).all()
        if sound and len(heights_at):
            velocities = qvel[velocities_at]
            speeds2 = np.einsum("ij,ij->i", velocities, velocities)
            sound = bool((qpos[heights_at] <= highest).all() and (speeds2 <= MAX_BASE_SPEED_M_S ** 2).all())
        if sound:
            return []
        return [(index, reason) for index, sim in enumerate(self.robots) if (reason := sim.broken() or "")]

    def take(self, seqs: list[int]) -> Frame:
        """Every robot's figures of this instant, numbered `seqs` (the one state reader).

        After an unsensed step (`step`) the position and velocity sensors (the base's pose and twist, the IMU's
        orientation and gyro) are computed now; the accelerometer and the feet's contacts, which need the
        step's acceleration stage, are those of the last sensed step (at most a state period old)."""
        if self._unsensed:
            mujoco.mj_sensorPos(self.model, self.data)
            mujoco.mj_sensorVel(self.model, self.data)
            self._unsensed = False
        return self.reader.take(self.data, seqs)

    def fallen(self, frame: Frame) -> list[bool]:
        """Whether each robot of a frame tilts past its fall threshold."""
        return (frame.tilts_rad() > self._fall_tilt_rad).tolist()

    def reset_time(self) -> None:
        """mj_resetData of the whole world: time 0, warnings cleared (robots reset next)."""
        mujoco.mj_resetData(self.model, self.data)
        self.steps = 0
        self.schedule.drop()
        self.resets += 1


def _alone(files: RobotFiles, mode: Mode, timestep_s: float | None, terrain: Terrain | None) -> Robot:
    robot = build(files, mode, terrain)
    if timestep_s:
        robot.model.opt.timestep = timestep_s
    return robot
