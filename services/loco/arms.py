"""Arm commands (cmd/arms; Unitree's rt/arm_sdk) checked against the robot before the controller blends them.

Pure: no zenoh. An arm command is refused whole when it names other joints than the walking controller's
arm joints (in their order), asks a gain stiffer than the controller's own on the upper body, or a
target the sim would refuse (services/sim/physics.py: q within a full turn of the joint's range, |dq|
and |tau| at most twice the limits, fallbacks for a joint without limits). Blended into every command,
one such command would make the sim refuse the whole walk (kp 1e6 at weight 1 once made the G1 fall).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from zensim.robots.walking import Walking
from zensim.schemas import ArmCommand

from .controller import ArmBlend

FULL_TURN: Final = 2 * math.pi
LIMIT_FACTOR: Final = 2.0
FALLBACK_VELOCITY: Final = 100.0
FALLBACK_EFFORT: Final = 1000.0


@dataclass(frozen=True)
class ArmRules:
    """What an arm command may ask of the arm joints (from walking.toml and the robot's limits)."""

    names: tuple[str, ...]
    max_kp: float
    max_kd: float
    q_low: np.ndarray
    q_high: np.ndarray
    max_dq: np.ndarray
    max_tau: np.ndarray

    @classmethod
    def of(cls, walking: Walking, q_min: Sequence[float], q_max: Sequence[float], velocity_limit: Sequence[float],
           effort_limit: Sequence[float]) -> ArmRules:
        """The rules for the arm joints, from every joint's limits (canonical order)."""
        idx = walking.arms
        velocity, effort = np.asarray(velocity_limit, float)[idx], np.asarray(effort_limit, float)[idx]
        velocity = np.where(np.isfinite(velocity) & (velocity > 0), velocity, FALLBACK_VELOCITY)
        effort = np.where(np.isfinite(effort) & (effort > 0), effort, FALLBACK_EFFORT)
        return cls(tuple(walking.joints[i] for i in idx), walking.upper_kp, walking.upper_kd,
                   np.asarray(q_min, float)[idx] - FULL_TURN, np.asarray(q_max, float)[idx] + FULL_TURN,
                   LIMIT_FACTOR * velocity, LIMIT_FACTOR * effort)


def arm_blend(command: ArmCommand, rules: ArmRules) -> ArmBlend:
    """The blend of an arm command (already finite, non-negative gains, weight in 0..1: the schema's checks).

    Raises:
        ValueError: why the command is refused (the module docstring).
    """
    if tuple(command.names) != rules.names:
        raise ValueError(f"an arm command names the arm joints, in order: {', '.join(rules.names)}")
    v = {f: np.asarray(getattr(command, f), float) for f in ("q", "dq", "kp", "kd", "tau")}
    for name, limit in (("kp", rules.max_kp), ("kd", rules.max_kd)):
        if np.any(v[name] > limit):
            raise ValueError(f"{name} {float(np.max(v[name])):.4g} above {limit:g} (the controller's own upper-body {name})")
    checks = (("q", (v["q"] < rules.q_low) | (v["q"] > rules.q_high), "more than a full turn outside the joint's range"),
              ("dq", np.abs(v["dq"]) > rules.max_dq, "beyond twice the joint's velocity limit"),
              ("tau", np.abs(v["tau"]) > rules.max_tau, "beyond twice the joint's effort limit"))
    for name, bad, why in checks:
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{name} of {rules.names[i]} is {float(v[name][i]):.4g}, {why}")
    return ArmBlend(command.weight, v["q"], v["dq"], v["kp"], v["kd"], v["tau"])
