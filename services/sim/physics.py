"""One robot's physics, with no network: its commands, its watchdog, its own soundness and fall.

A `Simulation` is one robot of a World (world.py: the one MjModel/MjData and the one step, for one
robot or many). It validates motor commands against the robot, holds the newest one and gives it to
the actuators before each step the world runs, runs the command watchdog, resets the robot's own pose,
and says whether the robot's own state is sound and whether it fell. States are read for every robot
at once by the world's reader (world_states.py). No network here: tests and benchmarks drive a World.

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
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np

from zensim.robots import RobotFiles
from zensim.robots.builder import Mode, ModeFigures, Robot
from zensim.schemas import (
    SCHEMA_VERSION,
    bounded,
    short_repr,
    Gains,
    Keys,
    MotorCommand,
    ResetRequest,
    RobotInfo,
)
from zensim.schemas.messages import Terrain

from .disturbances import Disturbances
from .faults import Faults
from .link import Link
from .mjdata import actuator_index, actuator_values, base_tilt_rad, reset, write_actuators
from .variants import Variants

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
    """One robot of a World, driven by motor commands.

    Args:
        files: the robot's URDF and control file.
        robot: the robot in the world's model.
        data: the world's MjData (every robot of the world shares it).
        limits: bounds on commanded gains.
        watchdog_timeout_s: wall-clock silence after which the default pose is held.
        terrain: the world's ground (robots/terrain.py), for the robot's description; None: flat.
    """

    def __init__(self, files: RobotFiles, robot: Robot, data: mujoco.MjData, limits: Limits,
                 watchdog_timeout_s: float, terrain: Terrain | None = None) -> None:
        self.files = files
        self.terrain = terrain
        self.limits = limits
        self.watchdog_timeout_s = watchdog_timeout_s
        self._lock = threading.Lock()
        self.rejected = 0
        self.clamped = 0
        self.last_error: str | None = None
        self.resets = 0
        self.physics_resets = 0
        """Resets that followed broken physics."""
        self.last_reset_reason: str | None = None
        self.fallen_since: float | None = None
        """Sim time the current fall began (auto_reset_on_fall), None while upright."""
        self._last_command_wall: float | None = None
        self._watchdog_on = False
        """The watchdog's verdict at the last apply_targets that checked it (or reset, or a command)."""
        self.watchdog_enabled = True
        """False under the lockstep clock: time stands still between commands, so silence is no fault."""
        self.disturbances = Disturbances(robot, data)
        """Pushes and the elastic band (ctl/push, ctl/band): forces applied before each step."""
        self.faults = Faults(robot, data)
        """Motor and sensor faults (ctl/faults): in the actuators' figures and in what the states report."""
        self.link: Link[MotorTargets] = Link()
        """The link faults (ctl/faults `link`): accepted commands delayed or dropped on their way to the actuators."""
        self.attach(robot, data)
        self.reset()
        self.resets = 0

    # --- model -----------------------------------------------------------

    def attach(self, robot: Robot, data: mujoco.MjData) -> None:
        """Drive `robot` in `data` from now on (at start, and when a world of one is rebuilt in another mode);
        reset() then puts it in its default pose."""
        self.data = data
        self.robot = robot
        self.disturbances.attach(robot, data)  # a rebuild: the pushes end, the band keeps its setting
        self.variants = Variants(robot, self.disturbances.bodies)
        """The variant of the robot drawn at reset (ctl/reset `randomize`): a new model starts nominal."""
        self.faults.attach(robot, data)  # a rebuild: the faults stay, written into the new model
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

    def check_reset(self, request: ResetRequest, mode: ModeFigures | None = None) -> np.ndarray:
        """The pose a reset asks for, checked against the robot (and the height against `mode`'s figures when
        it switches mode): nothing changes here.

        Raises:
            CommandError: unknown joints, a wrong length, a pose far out of range, an absurd height.
        """
        q = self._pose_from(request)
        self._check_height(request, self.robot.base_height_m if mode is None else mode.base_height_m)
        return q

    def reset(self, request: ResetRequest | None = None) -> None:
        """Reset to the default pose, or the pose and height in `request` (its mode is the world's business:
        World.rebuild switches a world of one before this runs).

        Raises:
            CommandError: the request names unknown joints or has the wrong length.
        """
        request = request or ResetRequest()
        q = self.check_reset(request)  # checked before anything changes
        self.variants.apply(request.randomize)  # the model first: the data's reset runs mj_forward on it
        self.faults.limits_changed()  # a weak motor's peak is the variant's peak scaled
        reset(self.robot, self.data, q, request.base_height_m)
        with self._lock:
            self._targets = self._newest = MotorTargets.hold(self.robot, q)
            self.link.empty()  # a new episode: the commands in flight are lost with the last one
            self._last_command_wall = None
        self._watchdog_on = self.watchdog_engaged()
        self.steps = 0
        self.resets += 1
        self.fallen_since = None
        self.disturbances.clear_pushes()  # a new episode: no push of the last one acts on; the band holds on
        self.faults.relock()  # the faults stay; a locked joint is held in the new pose
        self.faults.new_episode()  # the drift, state delay and dropouts start over
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

    def _check_height(self, request: ResetRequest, spawn_height_m: float) -> None:
        """Refuse a reset height no robot stands at: buried in the floor or far up in the air."""
        if request.base_height_m is None:
            return
        low, high = reset_height_range(spawn_height_m)
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
            checked = self.check_command(command)
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
                base = self._newest  # the newest to arrive, in flight or applied: the link keeps their order
                q, dq, kp_all, kd_all, tau = base.q.copy(), base.dq.copy(), base.kp.copy(), base.kd.copy(), base.tau.copy()
                q[idx] = clipped
                dq[idx] = 0.0 if command.dq is None else command.dq
                kp_all[idx] = kp
                kd_all[idx] = kd
                tau[idx] = 0.0 if command.tau is None else command.tau
                whole = MotorTargets(q, dq, kp_all, kd_all, tau)  # complete before it is made: it derives from them
            sent = self.link.send(whole, self.steps)
            if sent == "dropped":  # lost on the link: never reaches the robot (nor its watchdog)
                return n_clamped
            self._newest = whole
            if sent == "now":
                self._targets = whole
            self._last_command_wall = time.monotonic()
            self._watchdog_on = False
            if n_clamped:
                self.clamped += 1
        return n_clamped

    def check_command(self, command: MotorCommand) -> Checked:
        """accept_command's checks alone: raise CommandError when `command` does not fit the robot, change
        nothing. The result (the robot checked against, the joints a command addresses, its targets clamped to
        the joint limits, its gains, how many targets were clamped), given to accept_command, spares it checking
        again (world_endpoint.py checks every robot's command before it applies any)."""
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

    def reject(self, reason: str, count: int = 1) -> None:
        """Count `count` rejected commands (decode or validation failures; the reason is the last's); any thread."""
        text = bounded(reason)
        with self._lock:
            self.rejected += count
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

    # --- stepping --------------------------------------------------------

    def _apply(self, targets: MotorTargets) -> None:
        neg_kp, neg_kd, ctrl = targets.actuators
        strength = self.variants.strength
        if strength is not None:  # a variant's weaker or stronger motors: the whole torque scales (variants.py)
            neg_kp, neg_kd, ctrl = neg_kp * strength, neg_kd * strength, ctrl * strength
        # Then the faults' (a weak motor scales what the variant's gives; a limp one gives nothing).
        write_actuators(self.robot, self.data, self._actuators, *self.faults.scale_actuators(neg_kp, neg_kd, ctrl))
        self._applied = targets

    def faults_changed(self) -> None:
        """(physics lock held) The faults changed: the link takes its new faults, the actuators get the held
        targets again, through the motor faults."""
        state = self.faults.state
        with self._lock:
            self.link.set(None if state is None else state.link, 0 if state is None else state.seed)
        self._apply(self._safe if self._watchdog_on else self._targets)

    def apply_targets(self, check_watchdog: bool = True, ahead: int = 0) -> None:
        """Give the actuators the current targets, when they changed since the last step (the world calls it
        before each step it runs: the actuators keep their ctrl and gains between steps, so targets are
        written only when they changed, a new command or the watchdog engaging or letting go).

        `check_watchdog` False keeps the watchdog's last verdict instead of reading the clock: a world
        of many robots asks it once per state period, not once per robot and step. A command accepted
        meanwhile lets go of the watchdog at once (accept_command clears the verdict).

        `ahead`: the steps the world has run since `steps` was last counted (World.step counts them after a
        batch); a delayed command due by the step about to run takes effect now.
        """
        if self.link.busy():
            with self._lock:
                due = self.link.due(self.steps + ahead)
                if due is not None:
                    self._targets = due
        if check_watchdog:
            self._watchdog_on = self.watchdog_engaged()
        targets = self._safe if self._watchdog_on else self._targets
        if targets is not self._applied:
            self._apply(targets)

    def broken(self) -> str | None:
        """Why this robot's own state cannot be trusted any more, or None while it is sound.

        A state can be finite and still impossible: a robot launched out of the floor at 500 m/s.
        MuJoCo's own guards (broken_warning) are the world's, as its data is: World.broken checks both.
        """
        data, robot = self.data, self.robot
        qpos, qvel = (data.qpos, data.qvel) if robot.slot is None else (data.qpos[robot.slot.qpos], data.qvel[robot.slot.dof])
        # A NaN or an infinity anywhere makes the sum one (so does a sum past 1e308: broken too); one reduction
        # each, not isfinite's array and all's (a robot alone checks this at every state).
        if not math.isfinite(float(qpos.sum()) + float(qvel.sum())):
            return "a non-finite position or velocity"
        if robot.free_qpos_adr >= 0:
            height = float(data.qpos[robot.free_qpos_adr + 2])
            vx, vy, vz = data.qvel[robot.free_dof_adr:robot.free_dof_adr + 3].tolist()
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            if speed > MAX_BASE_SPEED_M_S:
                return f"the base moves at {speed:.3g} m/s (more than {MAX_BASE_SPEED_M_S:g})"
            if height > robot.base_height_m + MAX_BASE_RISE_M:
                return f"the base is {height:.3g} m high (spawned at {robot.base_height_m:.3g})"
        return None

    def fallen(self) -> bool:
        return self.mode == "floating" and base_tilt_rad(self.robot, self.data) > self.robot.control.model.fall_tilt_rad

    # --- messages --------------------------------------------------------

    def robot_info(self, keys: Keys, state_rate_hz: float, status_rate_hz: float,
                   other: dict[Mode, ModeFigures]) -> RobotInfo:
        """The description clients need; `other` holds the robot's figures in each mode."""
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
            variant=self.variants.variant,
            fall_tilt_rad=robot.control.model.fall_tilt_rad if robot.mode == "floating" else None,
        )


def broken_warning(data: mujoco.MjData) -> str | None:
    """The first of MuJoCo's bad-state warnings raised on `data`, as a reason; None when none was."""
    for warning in BROKEN_PHYSICS_WARNINGS:
        if data.warning[warning].number > 0:
            return f"MuJoCo {warning.name} (index {data.warning[warning].lastinfo})"
    return None


def reset_height_range(spawn: float) -> tuple[float, float]:
    """Base heights a reset may ask for, m, from the mode's spawn height: from half of it to 5 m above it."""
    low = RESET_HEIGHT_MIN_FACTOR * spawn if spawn > 0 else spawn - 0.5
    return low, spawn + RESET_HEIGHT_MAX_ABOVE_M
