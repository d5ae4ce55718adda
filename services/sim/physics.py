"""The robot's physics, with no network: commands in, states out.

`Simulation` owns one compiled robot and its MjData. It validates motor
commands against the robot, holds the newest one and applies it at every
step, runs the command watchdog, detects falls, and turns MuJoCo's arrays
into wire messages. The service (service.py) only moves bytes; tests and
benchmarks drive this class directly.

Threading: `accept_command` runs on the service's command thread while the
loop steps; the command is merged under `_lock` into a fresh set of arrays and
swapped in whole, so a step never sees half of a command. The counters
(`rejected`, `clamped`) change under the same lock, as several threads count
into them. Everything that reads or writes `data` (MjData) is for the thread
holding the service's physics lock (docs/architecture.md, "Threads").
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np

from zensim.robots import RobotFiles
from zensim.robots.builder import Mode, Robot, build
from zensim.schemas import (
    SCHEMA_VERSION,
    bounded,
    short_repr,
    Gains,
    Imu,
    JointState,
    Keys,
    MotorCommand,
    Odometry,
    ResetRequest,
    RobotInfo,
)
from zensim.schemas.messages import Terrain

from .mjdata import actuator_index, actuator_values, base_tilt_rad, read_base, read_imu, reset, write_actuators

logger = logging.getLogger(__name__)

# Physical bounds on what a command may ask for. Finite is not sane: MuJoCo zeroes every control when
# one is huge (mjWARN_BADCTRL) and the whole robot collapses, so values no real robot could take are
# refused whole instead of being passed on.
TAU_LIMIT_FACTOR = 2.0
"""Largest feed-forward torque, in multiples of the joint's effort limit (the motor's peak)."""
DQ_LIMIT_FACTOR = 2.0
"""Largest target velocity, in multiples of the joint's velocity limit."""
Q_RANGE_MARGIN_RAD = 2 * math.pi
"""A target within this of the joint range is clamped to it; one further out is refused."""
FALLBACK_EFFORT_LIMIT = 1000.0
"""Effort limit used for the bound when the description gives none (0 or absent), N m."""
FALLBACK_VELOCITY_LIMIT = 100.0
"""Velocity limit used for the bound when the description gives none (0 or absent), rad/s."""
RESET_HEIGHT_MIN_FACTOR = 0.5
"""Lowest reset height, as a fraction of the mode's spawn height (lower buries the legs in the floor)."""
RESET_HEIGHT_MAX_ABOVE_M = 5.0
"""Highest reset height above the mode's spawn height, m."""
MAX_BASE_SPEED_M_S = 50.0
"""A base faster than this has not fallen, it has been thrown by broken physics (free fall from 100 m: 44 m/s)."""
MAX_BASE_RISE_M = 20.0
"""A base this far above its spawn height has been launched by broken physics."""
BROKEN_PHYSICS_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADCTRL,
)
"""MuJoCo's own guards: when one fires it has already zeroed the controls or reset mjData."""


class Checked(NamedTuple):
    """A command checked against one build of the robot (Simulation.check_command)."""

    robot: Robot
    idx: np.ndarray | slice
    """The joints it addresses: canonical indices, or a slice of all of them."""
    q: np.ndarray
    """Its targets, clamped to the joint limits."""
    kp: np.ndarray
    kd: np.ndarray
    clamped: int
    """How many targets were clamped."""


class CommandError(ValueError):
    """A command that does not fit the robot (unknown joint, wrong length, gain out of bounds)."""


@dataclass(frozen=True)
class MotorTargets:
    """A complete command for every joint, canonical order (what the actuators get each step).

    What the actuators take (mjdata.actuator_values) is worked out once, here, on the thread that made
    the command: the loop, which applies it, then only copies three arrays (in a world of 32 robots
    commanded at 100 Hz, working it out on the loop took a third of the loop's Python time).
    """

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray
    actuators: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False)
    """-kp, -kd and ctrl, as mjdata.write_actuators takes them."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "actuators", actuator_values(self.q, self.dq, self.kp, self.kd, self.tau))

    @staticmethod
    def hold(robot: Robot, q: np.ndarray) -> MotorTargets:
        """Hold pose `q` with the robot's configured gains."""
        zeros = np.zeros(robot.nu)
        return MotorTargets(q.copy(), zeros, robot.kp.copy(), robot.kd.copy(), zeros.copy())


@dataclass(frozen=True)
class Limits:
    """Bounds on what a command may ask for."""

    max_kp: float
    max_kd: float


class Simulation:
    """One robot in MuJoCo, driven by motor commands.

    Args:
        files: the robot's URDF and control file.
        mode: `floating` or `fixed`.
        limits: bounds on commanded gains.
        watchdog_timeout_s: wall-clock silence after which the default pose is held.
        timestep_s: physics step; None keeps the control file's.
        shared: a robot of a world (services/sim/world.py): its Robot in the world's model, the world's
            MjData, and the world's step (which steps every robot at once). None: a world of its own.
        terrain: the ground (robots/terrain.py), built into the model and described in info/robot; None: flat.
    """

    def __init__(
        self,
        files: RobotFiles,
        mode: Mode,
        limits: Limits,
        watchdog_timeout_s: float,
        timestep_s: float | None = None,
        shared: tuple[Robot, mujoco.MjData, Callable[[int], None]] | None = None,
        terrain: Terrain | None = None,
    ) -> None:
        self.files = files
        self.terrain = terrain
        self._shared = shared
        self.limits = limits
        self.watchdog_timeout_s = watchdog_timeout_s
        self._timestep_override = timestep_s
        self._lock = threading.Lock()
        self.rejected = 0
        self.clamped = 0
        self.last_error: str | None = None
        self.resets = 0
        self._last_command_wall: float | None = None
        self._watchdog_on = False
        """The watchdog's verdict at the last apply_targets that checked it (or reset, or a command)."""
        self.watchdog_enabled = True
        """False under the lockstep clock: time stands still between commands, so silence is no fault."""
        self._load(mode)
        self.reset()
        self.resets = 0

    # --- model -----------------------------------------------------------

    def _load(self, mode: Mode) -> None:
        if self._shared is not None:
            if mode != self._shared[0].mode:
                raise CommandError(f"a robot of a world stays in the world's mode ({self._shared[0].mode}); "
                                   "restart the world in another mode")
            robot, self.data = self._shared[0], self._shared[1]
        else:
            robot = build(self.files, mode, self.terrain)
            if self._timestep_override:
                robot.model.opt.timestep = self._timestep_override
            self.data = mujoco.MjData(robot.model)
        self.robot = robot
        self._index = {name: i for i, name in enumerate(robot.joint_names)}
        self._applied: MotorTargets | None = None
        self._actuators = actuator_index(robot)
        """The robot's actuators, as write_actuators takes them."""
        self._safe = MotorTargets.hold(robot, robot.default_q)
        """What the watchdog holds: the default pose on the configured gains."""
        self.steps = 0
        # A URDF without limits gives inf (or 0): the bound then falls back to a figure no motor exceeds.
        effort, velocity = robot.effort_limit, robot.velocity_limit
        effort = np.where(np.isfinite(effort) & (effort > 0), effort, FALLBACK_EFFORT_LIMIT)
        velocity = np.where(np.isfinite(velocity) & (velocity > 0), velocity, FALLBACK_VELOCITY_LIMIT)
        self._max_tau = TAU_LIMIT_FACTOR * effort
        self._max_dq = DQ_LIMIT_FACTOR * velocity
        self._q_far_low = robot.q_min - Q_RANGE_MARGIN_RAD
        self._q_far_high = robot.q_max + Q_RANGE_MARGIN_RAD
        """Targets beyond these are refused; between them and the range, clamped."""

    @property
    def mode(self) -> Mode:
        return self.robot.mode

    @property
    def timestep_s(self) -> float:
        return float(self.robot.model.opt.timestep)

    @property
    def sim_time_s(self) -> float:
        return float(self.data.time)

    def set_mode(self, mode: Mode) -> None:
        """Rebuild the model in `mode` and reset to its default pose."""
        if mode != self.mode:
            self._load(mode)
            self.reset()

    def reset(self, request: ResetRequest | None = None) -> None:
        """Reset to the default pose, or the pose and height in `request` (mode switch included).

        Raises:
            CommandError: the request names unknown joints or has the wrong length.
        """
        request = request or ResetRequest()
        q = self._pose_from(request)  # checked before anything changes
        self._check_height(request)
        if request.mode is not None and request.mode != self.mode:
            if self._shared is not None:
                raise CommandError(f"a robot of a world stays in the world's mode ({self.mode})")
            other = build(self.files, request.mode, self.terrain)  # checked against the new mode before switching
            self._check_height(request, other)
            self._load(request.mode)
            q = self._pose_from(request)
        reset(self.robot, self.data, q, request.base_height_m)
        with self._lock:
            self._targets = MotorTargets.hold(self.robot, q)
            self._last_command_wall = None
        self._watchdog_on = self.watchdog_engaged()
        self.steps = 0
        self.resets += 1
        self._apply(self._targets)
        if self.robot.slot is None:  # a robot of a world: mjdata.reset ran its own forward, the others untouched
            mujoco.mj_forward(self.robot.model, self.data)

    def _pose_from(self, request: ResetRequest) -> np.ndarray:
        q = self.robot.default_q.copy()
        if request.q is None:
            return q
        if request.names is None:
            if len(request.q) != self.robot.nu:
                raise CommandError(f"`q` has {len(request.q)} values, the robot has {self.robot.nu} joints")
            idx = np.arange(self.robot.nu)
        else:
            idx = self._indices(request.names)
        wanted = np.asarray(request.q, float)
        self._check_range("q", idx, wanted)
        q[idx] = wanted
        return np.clip(q, self.robot.q_min, self.robot.q_max)

    def _check_height(self, request: ResetRequest, robot: Robot | None = None) -> None:
        """Refuse a reset height no robot stands at: buried in the floor or far up in the air."""
        if request.base_height_m is None:
            return
        low, high = reset_height_range(robot or self.robot)
        if not low <= request.base_height_m <= high:
            raise CommandError(f"`base_height_m` {request.base_height_m:g} is outside [{low:.3g}, {high:.3g}] m")

    def _check_range(self, field: str, idx: np.ndarray | slice, q: np.ndarray) -> None:
        robot = self.robot
        far = (q < self._q_far_low[idx]) | (q > self._q_far_high[idx])
        if far.any():
            i = int(np.flatnonzero(far)[0])
            j = int(np.arange(robot.nu)[idx][i])
            raise CommandError(f"`{field}` of {robot.joint_names[j]} is {q[i]:g}, more than a full turn "
                               f"outside its range [{robot.q_min[j]:.3g}, {robot.q_max[j]:.3g}]")

    def _check_bound(self, field: str, idx: np.ndarray | slice, values: np.ndarray, bound: np.ndarray, what: str) -> None:
        over = np.abs(values) > bound[idx]
        if over.any():
            i = int(np.flatnonzero(over)[0])
            j = int(np.arange(self.robot.nu)[idx][i])
            raise CommandError(f"`{field}` of {self.robot.joint_names[j]} is {values[i]:g}, beyond "
                               f"{bound[j]:.4g} ({what})")

    # --- commands --------------------------------------------------------

    def _indices(self, names: tuple[str, ...]) -> np.ndarray:
        unknown = [name for name in names if name not in self._index]
        if unknown:
            shown = ", ".join(short_repr(name) for name in unknown[:3])
            more = f" and {len(unknown) - 3} more" if len(unknown) > 3 else ""
            raise CommandError(f"unknown joint(s): {shown}{more}")
        return np.fromiter((self._index[name] for name in names), int, len(names))

    def accept_command(self, command: MotorCommand, checked: Checked | None = None) -> int:
        """Validate `command` against the robot and make it the one applied from the next step on.

        A partial command (with `names`) changes only those joints. Nothing is
        changed when any part is invalid.

        Returns:
            The number of joints whose target was clamped to the joint limits.

        Raises:
            CommandError: unknown joints, wrong vector length, gains out of bounds.
        """
        robot = self.robot
        if checked is None or checked.robot is not robot:  # unchecked, or checked against a model since rebuilt
            checked = self._checked(command)
        idx, clipped, kp, kd, n_clamped = checked.idx, checked.q, checked.kp, checked.kd, checked.clamped
        whole = None
        if isinstance(idx, slice):  # every joint: nothing of the held command stays, so it is made unlocked
            zeros = np.zeros(robot.nu)  # MotorTargets' arrays are never written after it is made: shared safely
            whole = MotorTargets(clipped, zeros if command.dq is None else np.asarray(command.dq, float), kp, kd,
                                 zeros if command.tau is None else np.asarray(command.tau, float))
        with self._lock:
            if robot is not self.robot:  # the model was rebuilt meanwhile
                raise CommandError("the model changed while the command was checked; send it again")
            if whole is None:  # some joints: merged into the held command, which another command may replace
                base = self._targets
                q, dq, kp_all, kd_all, tau = base.q.copy(), base.dq.copy(), base.kp.copy(), base.kd.copy(), base.tau.copy()
                q[idx] = clipped
                dq[idx] = 0.0 if command.dq is None else command.dq
                kp_all[idx] = kp
                kd_all[idx] = kd
                tau[idx] = 0.0 if command.tau is None else command.tau
                whole = MotorTargets(q, dq, kp_all, kd_all, tau)  # complete before it is made: it derives from them
            self._targets = whole
            self._last_command_wall = time.monotonic()
            self._watchdog_on = False
            if n_clamped:
                self.clamped += 1
        return n_clamped

    def check_command(self, command: MotorCommand) -> Checked:
        """accept_command's checks alone: raise CommandError when `command` does not fit the robot, change
        nothing; the result, given to accept_command, spares it checking again (world.py checks every
        robot's command before it applies any)."""
        return self._checked(command)

    def _checked(self, command: MotorCommand) -> Checked:
        """The robot checked against, the joints a command addresses, its targets clamped to the joint
        limits, its gains, and how many targets were clamped."""
        robot = self.robot
        # Numpy methods and ufuncs rather than np.any / np.clip (Python wrappers around them): on 29 values
        # the call overhead is the cost, and a world checks every robot's command of every advance.
        idx: np.ndarray | slice
        if command.names is None:
            if len(command.q) != robot.nu:
                raise CommandError(f"`q` has {len(command.q)} values, the robot has {robot.nu} joints")
            idx = slice(None)  # every joint: a slice selects without copying
        else:
            idx = self._indices(command.names)
        q = np.asarray(command.q, float)
        kp = robot.kp[idx] if command.kp is None else np.asarray(command.kp, float)
        kd = robot.kd[idx] if command.kd is None else np.asarray(command.kd, float)
        if (kp > self.limits.max_kp).any():
            raise CommandError(f"`kp` above the limit {self.limits.max_kp}")
        if (kd > self.limits.max_kd).any():
            raise CommandError(f"`kd` above the limit {self.limits.max_kd}")
        self._check_range("q", idx, q)
        if command.dq is not None:
            self._check_bound("dq", idx, np.asarray(command.dq, float), self._max_dq,
                              f"{DQ_LIMIT_FACTOR:g} x the velocity limit")
        if command.tau is not None:
            self._check_bound("tau", idx, np.asarray(command.tau, float), self._max_tau,
                              f"{TAU_LIMIT_FACTOR:g} x the effort limit")
        clipped = np.minimum(np.maximum(q, robot.q_min[idx]), robot.q_max[idx])
        n_clamped = int(np.count_nonzero(clipped != q))
        return Checked(robot, idx, clipped, kp, kd, n_clamped)

    def reject(self, reason: str) -> None:
        """Count a rejected command (decode or validation failure); any thread."""
        text = bounded(reason)
        with self._lock:
            self.rejected += 1
            self.last_error = text

    def command_age_s(self) -> float | None:
        """Wall time since the newest accepted command; None before the first."""
        last = self._last_command_wall
        return None if last is None else time.monotonic() - last

    def watchdog_engaged(self) -> bool:
        """True when no command came within the timeout: the sim then holds the default pose."""
        if not self.watchdog_enabled:
            return False
        age = self.command_age_s()
        return age is None or age > self.watchdog_timeout_s

    def targets(self) -> MotorTargets:
        """What the actuators get now: the newest command, or the safe pose under the watchdog."""
        if self.watchdog_engaged():
            return self._safe_targets()
        return self._targets

    def _safe_targets(self) -> MotorTargets:
        return self._safe

    # --- stepping --------------------------------------------------------

    def _apply(self, targets: MotorTargets) -> None:
        write_actuators(self.robot, self.data, self._actuators, *targets.actuators)
        self._applied = targets

    def step(self, n: int = 1) -> None:
        """Advance `n` physics steps, applying the current targets before each.

        A step runs as MuJoCo's split pair: mj_step2 (actuation, acceleration,
        integration) then mj_step1 (positions, velocities and their sensors at
        the new instant). So between steps `data` always describes its own
        `data.time`: a state read now is not one step stale (a plain mj_step
        leaves body poses and sensors at the start of the step), and it costs
        no extra mj_forward. Only acceleration-stage values (the IMU's
        accelerometer, qfrc_actuator) describe the step that just ended.

        The actuators keep their ctrl and gains between steps, so targets are
        written only when they changed: a new command, or the watchdog
        engaging or letting go. That keeps the hot loop at MuJoCo's own cost.
        """
        if self._shared is not None:  # one robot of a world: the world steps every robot together
            self._shared[2](n)
            return
        model, data = self.robot.model, self.data
        for _ in range(n):
            self.apply_targets()
            mujoco.mj_step2(model, data)
            mujoco.mj_step1(model, data)
        self.steps += n

    def apply_targets(self, check_watchdog: bool = True) -> None:
        """Give the actuators the current targets, when they changed since the last step.

        `check_watchdog` False keeps the watchdog's last verdict instead of reading the clock: a world
        of many robots asks it once per state period, not once per robot and step. A command accepted
        meanwhile lets go of the watchdog at once (accept_command clears the verdict).
        """
        if check_watchdog:
            self._watchdog_on = self.watchdog_engaged()
        targets = self._safe_targets() if self._watchdog_on else self._targets
        if targets is not self._applied:
            self._apply(targets)

    def broken(self) -> str | None:
        """Why the physics state cannot be trusted any more, or None while it is sound.

        MuJoCo's guards fire first for NaN or huge accelerations, velocities,
        positions or controls: it then zeroes the controls or silently resets
        mjData to the model's reference pose every step (time stuck at 0). A
        state can also be finite and still impossible: a robot launched out
        of the floor at 500 m/s. The service follows any of these with a real
        reset and says why, instead of streaming a teleported robot.
        """
        data, robot = self.data, self.robot
        if robot.slot is None:  # in a world, MuJoCo's warnings are the world's (world.py checks them)
            reason = broken_warning(data)
            if reason:
                return reason
        qpos, qvel = (data.qpos, data.qvel) if robot.slot is None else (data.qpos[robot.slot.qpos], data.qvel[robot.slot.dof])
        if not (np.all(np.isfinite(qpos)) and np.all(np.isfinite(qvel))):
            return "a non-finite position or velocity"
        if robot.free_qpos_adr >= 0:
            height = float(data.qpos[robot.free_qpos_adr + 2])
            speed = float(np.linalg.norm(data.qvel[robot.free_dof_adr:robot.free_dof_adr + 3]))
            if speed > MAX_BASE_SPEED_M_S:
                return f"the base moves at {speed:.3g} m/s (more than {MAX_BASE_SPEED_M_S:g})"
            if height > robot.base_height_m + MAX_BASE_RISE_M:
                return f"the base is {height:.3g} m high (spawned at {robot.base_height_m:.3g})"
        return None

    def fallen(self) -> bool:
        return self.mode == "floating" and base_tilt_rad(self.robot, self.data) > self.robot.control.model.fall_tilt_rad

    # --- messages --------------------------------------------------------

    def joint_state(self, seq: int) -> JointState:
        robot, data = self.robot, self.data
        return JointState(
            sim_time_s=float(data.time),
            seq=seq,
            q=data.qpos[robot.qpos_adr].tolist(),
            dq=data.qvel[robot.dof_adr].tolist(),
            tau=data.qfrc_actuator[robot.dof_adr].tolist(),
        )

    def odometry(self, seq: int) -> Odometry:
        pos, quat, lin_vel, ang_vel = read_base(self.robot, self.data)
        return Odometry(
            sim_time_s=float(self.data.time),
            seq=seq,
            pos=pos.tolist(),
            quat_wxyz=quat.tolist(),
            lin_vel_world=lin_vel.tolist(),
            ang_vel_body=ang_vel.tolist(),
        )

    def imu(self, seq: int) -> Imu:
        quat, gyro, accel = read_imu(self.robot, self.data)
        return Imu(sim_time_s=float(self.data.time), seq=seq, quat_wxyz=quat.tolist(), gyro=gyro.tolist(), accel=accel.tolist())

    def robot_info(self, keys: Keys, state_rate_hz: float, status_rate_hz: float, other: dict[Mode, Robot]) -> RobotInfo:
        """The description clients need; `other` holds the robot built in each mode (for per-mode figures)."""
        robot = self.robot
        return RobotInfo(
            robot=keys.robot,
            model=robot.name,
            schema_version=SCHEMA_VERSION,
            joint_names=robot.joint_names,
            q_min=robot.q_min.tolist(),
            q_max=robot.q_max.tolist(),
            effort_limit=robot.effort_limit.tolist(),
            velocity_limit=robot.velocity_limit.tolist(),
            default_q={mode: r.default_q.tolist() for mode, r in other.items()},
            gains={mode: Gains(kp=r.kp.tolist(), kd=r.kd.tolist()) for mode, r in other.items()},
            base_height_m={mode: r.base_height_m for mode, r in other.items()},
            mode=robot.mode,
            timestep_s=self.timestep_s,
            state_rate_hz=state_rate_hz,
            status_rate_hz=status_rate_hz,
            watchdog_timeout_s=self.watchdog_timeout_s,
            mesh_paths=tuple(robot.mesh_files),
            keys=keys.table(),
            terrain=self.terrain,
        )


def broken_warning(data: mujoco.MjData) -> str | None:
    """The first of MuJoCo's bad-state warnings raised on `data`, as a reason; None when none was."""
    for warning in BROKEN_PHYSICS_WARNINGS:
        if data.warning[warning].number > 0:
            return f"MuJoCo {warning.name} (index {data.warning[warning].lastinfo})"
    return None


def reset_height_range(robot: Robot) -> tuple[float, float]:
    """Base heights a reset may ask for in the robot's mode, m: from half the spawn height to 5 m above it."""
    spawn = robot.base_height_m
    low = RESET_HEIGHT_MIN_FACTOR * spawn if spawn > 0 else spawn - 0.5
    return low, spawn + RESET_HEIGHT_MAX_ABOVE_M
