"""Typed control configuration of a robot (`control.toml`), and its resolution onto joints.

`control.toml` carries what the URDF cannot: PD gains per mode, rotor armature, the default pose,
spawn heights, contact and solver settings. It is the data form of the ROS seed's controllers.yaml and
launch arguments. Joint groups are glob patterns over joint names, not positional lists, so a file
survives joint reordering and serves both our G1 and the official URDF. A URDF without a control file
gets `ControlConfig()` (all defaults) and gains derived from its effort limits.
"""

from __future__ import annotations

import fnmatch
import logging
from pathlib import Path
from collections.abc import Sequence
from typing import Annotated, Literal, TypeVar

import msgspec

logger = logging.getLogger(__name__)

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]


class ControlConfigError(ValueError):
    """A control file that cannot be read, decoded or applied; the message names the file and field."""


class StrictTable(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Base for every table in a robot's TOML files (control.toml, walking.toml): a typo is an error, not a
    silently ignored key."""


class JointGains(StrictTable, frozen=True):
    """PD gains for the joints matching `joints` (Unitree LowCmd kp/kd)."""

    joints: list[str]
    """Glob patterns over joint names."""
    kp: NonNegative
    """Stiffness, N m/rad (N/m for prismatic joints)."""
    kd: NonNegative
    """Damping, N m s/rad."""


class JointValue(StrictTable, frozen=True):
    """A scalar for the joints matching `joints` (armature)."""

    joints: list[str]
    """Glob patterns over joint names."""
    value: NonNegative
    """The value, in the unit of the table that holds it."""


class ModeConfig(StrictTable, frozen=True):
    """Settings of one mode: floating (free base on the floor) or fixed (base welded in the air)."""

    base_height_m: Positive | None = None
    """Pelvis height at spawn (floating) or the welded height (fixed). None: from the model's lowest point."""
    gravity: bool = True
    """Gravity on; the fixed mode turns it off so the welded robot is a joint test bench."""
    gains: list[JointGains] = []
    """PD gains per joint group; first match wins. Unmatched joints get gains from their effort limit."""


class ModelConfig(StrictTable, frozen=True):
    """Simulation settings that complete the URDF into a MuJoCo model."""

    base_link: str | None = None
    """The floating base link; None: the URDF's root link."""
    imu_link: str | None = None
    """Link that carries the IMU site; None: the base link."""
    imu_site: str = "imu"
    """Name of the MuJoCo site the IMU sensors are attached to."""
    timestep_s: Positive = 0.002
    """Physics step, seconds."""
    integrator: Literal["implicitfast", "implicit", "euler", "rk4"] = "implicitfast"
    """MuJoCo integrator; implicitfast integrates the PD damping implicitly (stable at kd 50)."""
    self_collision: bool = False
    """False: robot geoms collide with the floor only (see control.toml for why)."""
    floor_friction: NonNegative = 1.0
    """Sliding friction of the floor plane."""
    foot_links: list[str] = []
    """Glob patterns of links whose geoms get `foot_friction`."""
    foot_friction: NonNegative = 1.0
    """Sliding friction of the foot geoms (a contact uses the larger of the pair)."""
    mass_floor_kg: NonNegative = 0.0
    """MuJoCo compiler boundmass: lower bound on every body's mass, kg."""
    inertia_floor_kg_m2: NonNegative = 0.0
    """MuJoCo compiler boundinertia: lower bound on every body's principal inertia, kg m^2."""
    fall_tilt_rad: Positive = 1.0
    """Base tilt from upright above which the robot counts as fallen, rad."""


DEFAULT_ARMATURE_KG_M2: float = 0.01
"""Armature for joints no [[armature]] group matches: a small rotor inertia that steadies stiff PD."""


class ControlConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Everything in a robot's control.toml. All fields have defaults so any URDF can run without one."""

    model: ModelConfig = ModelConfig()
    """Simulation settings."""
    armature: list[JointValue] = []
    """Rotor armature per joint group, kg m^2; first match wins."""
    pose: dict[str, float] = {}
    """Default joint positions by glob pattern, rad; first match wins; unlisted joints are 0."""
    floating: ModeConfig = ModeConfig()
    """The floating mode."""
    fixed: ModeConfig = ModeConfig(gravity=False)
    """The fixed mode (gravity off by default)."""


def load_control(path: Path | None) -> ControlConfig:
    """Read and validate a control file.

    Args:
        path: The control.toml; None gives the defaults.

    Returns:
        The decoded configuration.

    Raises:
        ControlConfigError: The file is missing, is not TOML, or has an unknown field or wrong type;
            the message names the file and the field path (e.g. `$.floating.gains[0].kp`).
    """
    if path is None:
        return ControlConfig()
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ControlConfigError(f"cannot read control file {path}: {exc}") from exc
    try:
        return msgspec.toml.decode(data, type=ControlConfig)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise ControlConfigError(f"{path}: {exc}") from exc


V = TypeVar("V")


def first_match(name: str, patterns_in_order: Sequence[tuple[Sequence[str], V]]) -> V | None:
    """Return the value of the first group whose patterns match `name`, or None."""
    for patterns, value in patterns_in_order:
        if any(fnmatch.fnmatchcase(name, p) for p in patterns):
            return value
    return None


def unmatched_patterns(config: ControlConfig, joint_names: list[str] | tuple[str, ...]) -> list[str]:
    """Patterns in the control file that match no joint: a lint for typos and foreign files."""
    groups: list[list[str]] = [g.joints for g in config.armature]
    groups += [g.joints for g in config.floating.gains] + [g.joints for g in config.fixed.gains]
    groups.append(list(config.pose))
    return sorted({p for g in groups for p in g if not fnmatch.filter(joint_names, p)})
