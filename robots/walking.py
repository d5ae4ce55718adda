"""A robot's walking controller settings (`walking.toml` beside its control.toml), resolved onto its joints.

`zensim loco` reads this file: which joints the robot must have, the walking policy's joints, stance,
gains and weights, the ramps that stand the robot up and sit it down, the damp gains and the velocity
limits. The numbers are the robot's, not the code's: a robot folder without a walking.toml has no
walking controller. Joint groups are glob patterns over joint names (first match wins), as in
control.toml.

What the robot's control.toml already says is read from there, not copied: the squat the ramps go to is
the sim's spawn pose (`[pose]`), and a joint no ramp gain group matches ramps with the floating mode's gains.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Final

import msgspec
import numpy as np

from . import BUNDLED_DIR, CONTROL_FILE, bundled_robots
# A gain group is control.toml's (JointGains): the ramps fall back on control.toml's floating gains, one list.
from .control import ControlConfigError, JointGains, NonNegative, Positive, StrictTable, first_match, load_control

WALKING_FILE: Final = "walking.toml"


class WalkingConfigError(ValueError):
    """A walking.toml that cannot be read, decoded or applied; the message names the file and field."""


class DampGroup(StrictTable, frozen=True):
    joints: list[str]
    """Glob patterns over joint names."""
    kd: NonNegative
    """Damping, N m s/rad."""


class PolicyConfig(StrictTable, frozen=True):
    weights: str
    """The policy's weights (.npz), relative to walking.toml's folder."""
    period_s: Positive
    """Sim time between two policy steps, s."""
    joints: list[str]
    """The joints the policy drives, in its action order."""
    default_q: list[float]
    """Their stance, rad (the policy's action 0)."""
    kp: list[NonNegative]
    """Their stiffness while walking, N m/rad."""
    kd: list[NonNegative]
    """Their damping while walking, N m s/rad."""


class WalkConfig(StrictTable, frozen=True):
    upper_kp: NonNegative
    """Stiffness of every joint outside the policy while walking (held at 0 rad), N m/rad."""
    upper_kd: NonNegative
    """Their damping, N m s/rad."""
    max_velocity: Annotated[list[Positive], msgspec.Meta(min_length=3, max_length=3)]
    """Largest |vx| m/s, |vy| m/s, |wz| rad/s walked at; commands are clipped to them."""
    heading_kp: NonNegative
    """Heading hold gain, 1/s (yaw rate per rad of heading error while walking straight)."""
    heading_max_wz: NonNegative
    """Largest yaw rate the heading hold asks, rad/s."""
    settle_s: NonNegative
    """Sim time at zero velocity before the robot stops stepping, s."""
    plant_s: Positive
    """Sim time of the ramp from the last step to the stance, s."""


class RampConfig(StrictTable, frozen=True):
    squat_s: Positive
    """Sim time from wherever the robot is to the squat (the first leg of a stand-up), s."""
    stand_up_s: Positive
    """Sim time from the squat to the stance (or from anywhere to the squat), s."""
    gains: list[JointGains] = []
    """Gains while ramping and holding a pose; first match wins, then control.toml's floating gains."""


class WalkingFile(StrictTable, frozen=True):
    """Everything in walking.toml."""

    joints: list[str]
    """The robot's joints, canonical order: the controller runs only on a robot with exactly these."""
    arm_joints: list[str]
    """Patterns: the joints an arm command may blend over the controller's targets."""
    policy: PolicyConfig
    walk: WalkConfig
    ramp: RampConfig
    damp: list[DampGroup]
    """Damp's kd per joint group (kp 0); first match wins."""
    arm_keep_gains: list[str] = []
    """Patterns: of those, the ones that keep the controller's gains in a blend."""


@dataclass(frozen=True)
class Walking:
    """walking.toml resolved onto the robot's joints: vectors in canonical order, ready to use."""

    joints: tuple[str, ...]
    legs: np.ndarray
    """Indices of the policy's joints, in its action order."""
    leg_default_q: np.ndarray
    leg_kp: np.ndarray
    leg_kd: np.ndarray
    period_s: float
    weights: Path
    stand_q: np.ndarray
    """Every joint: the policy's stance on its joints, 0 elsewhere."""
    squat_q: np.ndarray
    walk_kp: np.ndarray
    walk_kd: np.ndarray
    ramp_kp: np.ndarray
    ramp_kd: np.ndarray
    damp_kd: np.ndarray
    arms: np.ndarray
    """Indices of the joints an arm command may blend."""
    arm_keep_gains: np.ndarray
    """Of `arms` (a boolean per arm joint): the joints that keep the controller's gains."""
    max_velocity: np.ndarray
    heading_kp: float
    heading_max_wz: float
    settle_s: float
    plant_s: float
    squat_s: float
    stand_up_s: float

    @property
    def upper_kp(self) -> float:
        """The stiffest gain on an arm joint while walking (an arm command may ask no more)."""
        return float(np.max(self.walk_kp[self.arms])) if len(self.arms) else 0.0

    @property
    def upper_kd(self) -> float:
        return float(np.max(self.walk_kd[self.arms])) if len(self.arms) else 0.0


def load_walking(path: Path) -> Walking:
    """Read and resolve a walking.toml (and the control.toml beside it, for the squat and the ramp gains).

    Raises:
        WalkingConfigError: unreadable, not TOML, an unknown field or wrong type, or inconsistent
            (policy vectors of different lengths, a policy joint the robot lacks); the message names the file.
    """
    try:
        raw = msgspec.toml.decode(Path(path).read_bytes(), type=WalkingFile)
        control = load_control(Path(path).parent / CONTROL_FILE)
    except (OSError, ControlConfigError) as exc:
        raise WalkingConfigError(f"cannot read {path} and its {CONTROL_FILE}: {exc}") from exc
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise WalkingConfigError(f"{path}: {exc}") from exc
    joints = tuple(raw.joints)
    p = raw.policy
    if not (len(p.joints) == len(p.default_q) == len(p.kp) == len(p.kd)):
        raise WalkingConfigError(f"{path}: policy joints, default_q, kp and kd differ in length")
    missing = [j for j in p.joints if j not in joints]
    if missing:
        raise WalkingConfigError(f"{path}: policy joints not among `joints`: {missing}")
    n = len(joints)
    legs = np.array([joints.index(j) for j in p.joints], int)
    stand = np.zeros(n)
    stand[legs] = p.default_q
    squat = np.array([first_match(j, [([k], v) for k, v in control.pose.items()]) or 0.0 for j in joints])

    def per_joint(groups: list, field: str) -> np.ndarray:
        values = [first_match(j, [(g.joints, getattr(g, field)) for g in groups]) for j in joints]
        unset = [j for j, v in zip(joints, values) if v is None]
        if unset:
            raise WalkingConfigError(f"{path}: no {field} for {unset}")
        return np.array(values, float)

    ramp_gains = raw.ramp.gains + list(control.floating.gains)

    walk_kp = np.full(n, raw.walk.upper_kp)
    walk_kd = np.full(n, raw.walk.upper_kd)
    walk_kp[legs], walk_kd[legs] = p.kp, p.kd
    arms = np.array([i for i, j in enumerate(joints) if any(fnmatch.fnmatchcase(j, g) for g in raw.arm_joints)], int)
    keep = np.array([any(fnmatch.fnmatchcase(joints[i], g) for g in raw.arm_keep_gains) for i in arms], bool)
    return Walking(
        joints=joints, legs=legs, leg_default_q=np.array(p.default_q, float), leg_kp=np.array(p.kp, float),
        leg_kd=np.array(p.kd, float), period_s=p.period_s, weights=Path(path).parent / p.weights,
        stand_q=stand, squat_q=squat, walk_kp=walk_kp, walk_kd=walk_kd,
        ramp_kp=per_joint(ramp_gains, "kp"), ramp_kd=per_joint(ramp_gains, "kd"),
        damp_kd=per_joint(raw.damp, "kd"), arms=arms, arm_keep_gains=keep,
        max_velocity=np.array(raw.walk.max_velocity, float), heading_kp=raw.walk.heading_kp,
        heading_max_wz=raw.walk.heading_max_wz, settle_s=raw.walk.settle_s, plant_s=raw.walk.plant_s,
        squat_s=raw.ramp.squat_s, stand_up_s=raw.ramp.stand_up_s,
    )


def walking_for(joint_names: tuple[str, ...] | list[str]) -> tuple[str, Walking] | None:
    """The bundled robot whose walking.toml drives a robot with exactly these joints, or None.

    A robot is matched by its joints, not by its name: the sim may run the official URDF under the id
    `g1`, and what the controller needs is the joint order it was written for.
    """
    for name in bundled_robots():
        path = BUNDLED_DIR / name / WALKING_FILE
        if path.is_file():
            walking = load_walking(path)
            if walking.joints == tuple(joint_names):
                return name, walking
    return None
