"""The bridge's pure logic: one held target per joint, merged from partial inputs, made safe.

No zenoh here, so every rule can be tested without a network:

- an input naming an unknown joint is rejected whole: nothing of it is applied (a half-applied
  slider message would leave the robot in a pose nobody asked for); its shape and finiteness were
  already checked once, by the schema (JointTargets), when it was decoded;
- targets beyond the joint limits are clamped, and the clamped joints are reported;
- the commanded q moves toward the held target by at most `slew_rad_s * dt` per tick, so a
  slider jump does not throw the robot over (a PD-only robot has no balance to catch it), and
  every joint of a change arrives at the same moment (one straight line in joint space);
- when the sim starts a new episode (SimStatus.episode: a reset, a mode switch, a restart) the held
  targets become the (new) mode's default pose, since the robot was just put there and stale
  targets would yank it away.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from zensim.schemas import MODES, JointTargets, Mode, RobotInfo, short_repr

MAX_TICK_S = 0.1
"""Longest tick the slew limit accounts for: after a stall the q must not jump by seconds' worth."""


def carries_targets(tick: int, rate_hz: float, targets_rate_hz: float) -> bool:
    """Whether tick `tick` (0, 1, ...) of the `rate_hz` loop also publishes state/targets.

    The ticks are spread so that exactly `targets_rate_hz` of every `rate_hz` carry it (30 of 100
    at the defaults: 30 Hz, as the docs say; "every 3rd tick" would be 33.3 Hz); 0 turns it off.
    """
    if targets_rate_hz <= 0:
        return False
    return math.floor(tick * targets_rate_hz / rate_hz) != math.floor((tick - 1) * targets_rate_hz / rate_hz)


class UnusableRobotInfo(ValueError):
    """A robot description the bridge cannot use (no pose or gains for the current mode)."""


@dataclass(frozen=True)
class RobotModel:
    """What the bridge needs to know about the robot: joints, limits, poses and gains per mode.

    Vectors are float arrays in canonical joint order.
    """

    joint_names: tuple[str, ...]
    q_min: np.ndarray
    q_max: np.ndarray
    default_q: Mapping[str, np.ndarray]
    kp: Mapping[str, np.ndarray]
    kd: Mapping[str, np.ndarray]
    mode: Mode
    """The mode the robot is in when the description was taken."""
    run_id: str = ""
    """The sim run that described the robot (RobotInfo.run_id); empty for local files."""
    episode: str = ""
    """The sim's episode when it described the robot (RobotInfo.episode); empty for local files."""

    def __post_init__(self) -> None:
        # Shapes and finiteness were checked by the RobotInfo schema (or come from a built robot).
        if not self.has_mode(self.mode):
            raise UnusableRobotInfo(f"no default pose and gains for the current mode {self.mode!r}")

    def has_mode(self, mode: str) -> bool:
        """Whether the description carries a default pose and gains for `mode`."""
        return mode in self.default_q and mode in self.kp and mode in self.kd

    @classmethod
    def from_info(cls, info: RobotInfo) -> RobotModel:
        """The model the sim describes on info/robot.

        Raises:
            UnusableRobotInfo: no data for the current mode.
        """
        return cls(
            joint_names=tuple(info.joint_names),
            q_min=np.asarray(info.q_min, float),
            q_max=np.asarray(info.q_max, float),
            default_q={mode: np.asarray(q, float) for mode, q in info.default_q.items()},
            kp={mode: np.asarray(g.kp, float) for mode, g in info.gains.items()},
            kd={mode: np.asarray(g.kd, float) for mode, g in info.gains.items()},
            mode=info.mode,
            run_id=info.run_id,
            episode=info.episode,
        )

    @classmethod
    def from_files(cls, robot: str | None, urdf: str | None, control: str | None,
                   mode: Mode = "floating") -> RobotModel:
        """The model built from local robot files, for both modes (compiles MuJoCo twice).

        Raises:
            FileNotFoundError: an unknown robot or a missing file.
            ValueError: a robot description that does not build.
        """
        # Imported here: only this optional path needs MuJoCo.
        from zensim.robots import robot_files
        from zensim.robots.builder import build

        files = robot_files(robot, urdf=urdf, control=control)
        built = {m: build(files, m) for m in MODES}
        first = built[MODES[0]]
        return cls(
            joint_names=tuple(first.joint_names),
            q_min=np.asarray(first.q_min, float),
            q_max=np.asarray(first.q_max, float),
            default_q={m: np.asarray(r.default_q, float) for m, r in built.items()},
            kp={m: np.asarray(r.kp, float) for m, r in built.items()},
            kd={m: np.asarray(r.kd, float) for m, r in built.items()},
            mode=mode,
        )


@dataclass(frozen=True)
class Verdict:
    """What became of one input."""

    accepted: bool
    error: str | None = None
    clamped: tuple[str, ...] = ()


@dataclass
class HeldTargets:
    """Held targets for every joint and the slew-limited q commanded toward them.

    Not thread-safe: the service guards it with one lock.

    Args:
        model: the robot.
        slew_rad_s: most a commanded q moves per second, rad/s; 0 turns the limit off.
    """

    model: RobotModel
    slew_rad_s: float = 2.0
    mode: Mode = field(init=False)
    target_q: np.ndarray = field(init=False)
    target_dq: np.ndarray = field(init=False)
    q: np.ndarray = field(init=False)
    """The commanded q: slew-limited, moving toward target_q."""
    episode: str = field(init=False)
    """The sim episode the held targets belong to."""

    def __post_init__(self) -> None:
        if not (self.slew_rad_s >= 0 and math.isfinite(self.slew_rad_s)):
            raise ValueError(f"slew_rad_s must be finite and >= 0, got {self.slew_rad_s}")
        self._index = {name: i for i, name in enumerate(self.model.joint_names)}
        self.episode = self.model.episode
        self.hold_default(self.model.mode)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.model.joint_names

    def hold_default(self, mode: Mode) -> None:
        """Hold `mode`'s default pose, at once (the sim has just put the robot there)."""
        self.mode = mode
        self.target_q = self.model.default_q[mode].copy()
        self.target_dq = np.zeros_like(self.target_q)
        self.q = self.target_q.copy()

    def follow_sim(self, episode: str, mode: Mode) -> bool:
        """Hold `mode`'s default pose when the sim has started a new episode (SimStatus.episode).

        Returns:
            True when the held targets were reset.

        Raises:
            UnusableRobotInfo: the new episode is in a mode the description has no data for.
        """
        if episode == self.episode:
            return False
        if not self.model.has_mode(mode):
            raise UnusableRobotInfo(f"sim is in mode {mode!r}, which the robot description lacks")
        self.episode = episode
        self.hold_default(mode)
        return True

    def apply(self, targets: JointTargets) -> Verdict:
        """Merge a partial target into the held targets, all or nothing.

        `targets` is a JointTargets, so its shape and values are already checked (unique names,
        matching lengths, finite numbers); what is left is what only the robot knows.

        Returns:
            Rejected (nothing applied) when it names a joint the robot does not have; accepted
            otherwise, naming the joints clamped to their limits.
        """
        names = targets.names
        unknown = [name for name in names if name not in self._index]
        if unknown:
            shown = ", ".join(short_repr(name) for name in unknown[:3])
            return Verdict(False, f"unknown joint(s): {shown}" + (f" and {len(unknown) - 3} more" if len(unknown) > 3 else ""))
        idx = np.fromiter((self._index[name] for name in names), int, len(names))
        wanted = np.asarray(targets.q, float)
        held = np.clip(wanted, self.model.q_min[idx], self.model.q_max[idx])
        clamped = tuple(names[i] for i in np.flatnonzero(held != wanted))
        self.target_q[idx] = held
        self.target_dq[idx] = 0.0 if targets.dq is None else np.asarray(targets.dq, float)
        return Verdict(True, clamped=clamped)

    def step(self, dt_s: float) -> np.ndarray:
        """Advance the commanded q toward the held targets by one tick of `dt_s` seconds.

        Returns:
            The commanded q (the array itself; copy it to keep it).
        """
        if self.slew_rad_s <= 0:
            self.q[:] = self.target_q
            return self.q
        max_step = self.slew_rad_s * min(max(dt_s, 0.0), MAX_TICK_S)
        delta = self.target_q - self.q
        largest = float(np.max(np.abs(delta), initial=0.0))
        if largest <= max_step:
            self.q[:] = self.target_q  # arrived: exactly the target, not q + (target - q) rounded
        else:
            # Every joint moves by the same fraction of its way, so all arrive together: the pose
            # moves along a straight line in joint space. Clipping each joint alone let the hips and
            # ankles (0.45 rad from the squat) reach zero while the knees (0.9 rad) were still bent,
            # and the floating G1 fell over backwards.
            self.q += delta * (max_step / largest)
        return self.q

    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        """kp, kd of the current mode."""
        return self.model.kp[self.mode], self.model.kd[self.mode]
