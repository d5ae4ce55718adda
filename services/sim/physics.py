"""The robot's physics, with no network: commands in, states out.

`Simulation` owns one compiled robot and its MjData. It validates motor
commands against the robot, holds the newest one and applies it at every
step, runs the command watchdog, detects falls, and turns MuJoCo's arrays
into wire messages. The service (service.py) only moves bytes; tests and
benchmarks drive this class directly.

Threading: `accept_command` runs on zenoh's callback thread while the loop
steps; the command is merged under a lock into a fresh set of arrays and
swapped in whole, so a step never sees half of a command.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from zensim.robots import RobotFiles
from zensim.robots.builder import (
    Mode,
    Robot,
    apply_motor_command,
    base_tilt_rad,
    build,
    read_base,
    read_imu,
    reset,
)
from zensim.schemas import (
    SCHEMA_VERSION,
    Gains,
    Imu,
    JointState,
    Keys,
    MotorCommand,
    Odometry,
    ResetRequest,
    RobotInfo,
)

logger = logging.getLogger(__name__)


class CommandError(ValueError):
    """A command that does not fit the robot (unknown joint, wrong length, gain out of bounds)."""


@dataclass(frozen=True)
class MotorTargets:
    """A complete command for every joint, canonical order (what the actuators get each step)."""

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray

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
    """

    def __init__(
        self,
        files: RobotFiles,
        mode: Mode,
        limits: Limits,
        watchdog_timeout_s: float,
        timestep_s: float | None = None,
    ) -> None:
        self.files = files
        self.limits = limits
        self.watchdog_timeout_s = watchdog_timeout_s
        self._timestep_override = timestep_s
        self._lock = threading.Lock()
        self.rejected = 0
        self.clamped = 0
        self.last_error: str | None = None
        self.resets = 0
        self._last_command_wall: float | None = None
        self.watchdog_enabled = True
        """False under the lockstep clock: time stands still between commands, so silence is no fault."""
        self._load(mode)
        self.reset()
        self.resets = 0

    # --- model -----------------------------------------------------------

    def _load(self, mode: Mode) -> None:
        robot = build(self.files, mode)
        if self._timestep_override:
            robot.model.opt.timestep = self._timestep_override
        self.robot = robot
        self.data = mujoco.MjData(robot.model)
        self._index = {name: i for i, name in enumerate(robot.joint_names)}
        self._applied: MotorTargets | None = None
        self.steps = 0

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
        if request.mode is not None and request.mode != self.mode:
            self._load(request.mode)
            q = self._pose_from(request)
        reset(self.robot, self.data, q, request.base_height_m)
        with self._lock:
            self._targets = MotorTargets.hold(self.robot, q)
            self._last_command_wall = None
        self.steps = 0
        self.resets += 1
        self._apply(self._targets)
        mujoco.mj_forward(self.robot.model, self.data)

    def _pose_from(self, request: ResetRequest) -> np.ndarray:
        q = self.robot.default_q.copy()
        if request.q is None:
            return q
        if request.names is None:
            if len(request.q) != self.robot.nu:
                raise CommandError(f"`q` has {len(request.q)} values, the robot has {self.robot.nu} joints")
            q[:] = request.q
        else:
            q[self._indices(request.names)] = request.q
        return np.clip(q, self.robot.q_min, self.robot.q_max)

    # --- commands --------------------------------------------------------

    def _indices(self, names: tuple[str, ...]) -> np.ndarray:
        unknown = [name for name in names if name not in self._index]
        if unknown:
            raise CommandError(f"unknown joint(s): {', '.join(unknown)}")
        return np.fromiter((self._index[name] for name in names), int, len(names))

    def accept_command(self, command: MotorCommand) -> int:
        """Validate `command` against the robot and make it the one applied from the next step on.

        A partial command (with `names`) changes only those joints. Nothing is
        changed when any part is invalid.

        Returns:
            The number of joints whose target was clamped to the joint limits.

        Raises:
            CommandError: unknown joints, wrong vector length, gains out of bounds.
        """
        robot = self.robot
        if command.names is None:
            if len(command.q) != robot.nu:
                raise CommandError(f"`q` has {len(command.q)} values, the robot has {robot.nu} joints")
            idx = np.arange(robot.nu)
        else:
            idx = self._indices(command.names)
        q = np.asarray(command.q, float)
        kp = robot.kp[idx] if command.kp is None else np.asarray(command.kp, float)
        kd = robot.kd[idx] if command.kd is None else np.asarray(command.kd, float)
        if np.any(kp > self.limits.max_kp):
            raise CommandError(f"`kp` above the limit {self.limits.max_kp}")
        if np.any(kd > self.limits.max_kd):
            raise CommandError(f"`kd` above the limit {self.limits.max_kd}")
        clipped = np.clip(q, robot.q_min[idx], robot.q_max[idx])
        n_clamped = int(np.count_nonzero(clipped != q))
        with self._lock:
            if robot is not self.robot:  # the model was rebuilt meanwhile
                raise CommandError("the model changed while the command was checked; send it again")
            base = self._targets
            new = MotorTargets(base.q.copy(), base.dq.copy(), base.kp.copy(), base.kd.copy(), base.tau.copy())
            new.q[idx] = clipped
            new.dq[idx] = 0.0 if command.dq is None else command.dq
            new.kp[idx] = kp
            new.kd[idx] = kd
            new.tau[idx] = 0.0 if command.tau is None else command.tau
            self._targets = new
            self._last_command_wall = time.monotonic()
        if n_clamped:
            self.clamped += 1
        return n_clamped

    def reject(self, reason: str) -> None:
        """Count a rejected command (decode or validation failure)."""
        self.rejected += 1
        self.last_error = reason

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
        if getattr(self, "_safe", None) is None or self._safe[0] is not self.robot:
            self._safe = (self.robot, MotorTargets.hold(self.robot, self.robot.default_q))
        return self._safe[1]

    # --- stepping --------------------------------------------------------

    def _apply(self, targets: MotorTargets) -> None:
        apply_motor_command(self.robot, self.data, targets.q, targets.dq, targets.kp, targets.kd, targets.tau)
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
        model, data = self.robot.model, self.data
        for _ in range(n):
            targets = self.targets()
            if targets is not self._applied:
                self._apply(targets)
            mujoco.mj_step2(model, data)
            mujoco.mj_step1(model, data)
        self.steps += n

    def diverged(self) -> bool:
        """True when MuJoCo hit NaN/huge accelerations since the last reset.

        MuJoCo then silently resets mjData to the model's reference pose (not
        the default pose, gains not held); the service follows up with a real
        reset and says so, instead of streaming a teleported robot.
        """
        return self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0

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
        )
