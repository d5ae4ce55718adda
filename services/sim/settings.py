"""Settings of `zensim sim` (env `ZENSIM_*` < flags)."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import msgspec

from zensim.common.settings import CommonSettings, zero_or_at_least
from zensim.schemas.messages import Mode


class SimSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim sim`: the MuJoCo physics service."""

    env_prefix: ClassVar[str] = "SIM"
    world: str | None = None
    """A world file (TOML) of several robots in one MuJoCo world; its robots replace --robot-id, --robot, --urdf."""
    robot: str = "unitree_g1"
    """Bundled robot to simulate (unitree_g1, alias g1); ignored when --urdf is given."""
    urdf: str | None = None
    """Path of any URDF to simulate instead (meshes resolve beside it)."""
    control: str | None = None
    """Control file for the URDF (default: control.toml beside it, else built-in defaults)."""
    mode: Mode = "floating"
    """floating (free base, gravity) or fixed (base welded in the air, gravity off)."""
    timestep_s: Annotated[float, msgspec.Meta(ge=1e-4, le=0.05)] | None = None
    """Physics step, s (default: the control file's, 0.002)."""
    rtf: Annotated[float, msgspec.Meta(ge=0, le=1000)] = 1.0
    """Target real-time factor; 0 runs as fast as possible."""
    state_rate_hz: Annotated[float, msgspec.Meta(ge=1, le=10_000)] = 100.0
    """Rate of state/joints, state/odom, state/imu and state/contacts in sim time, Hz (at most the physics rate)."""
    state_clock: Literal["sim", "wall"] = "sim"
    """Clock of state_rate_hz: sim (one state per 1/rate of sim time) or wall (per 1/rate of wall time)."""
    status_rate_hz: Annotated[float, msgspec.Meta(ge=0.1, le=1000)] = 10.0
    """Rate of state/sim in wall time, Hz."""
    watchdog_timeout_s: Annotated[float, msgspec.Meta(ge=0.01, le=3600)] = 0.5
    """Wall time without a motor command after which the default pose is held, s."""
    auto_reset_on_fall: bool = False
    """Reset to the default pose after the robot has been fallen for fall_reset_delay_s."""
    fall_reset_delay_s: Annotated[float, msgspec.Meta(ge=0, le=3600)] = 1.0
    """Sim time a fall lasts before the automatic reset, s."""
    max_kp: Annotated[float, msgspec.Meta(gt=0, le=1e6)] = 5000.0
    """Largest accepted kp in a motor command, N m/rad."""
    max_kd: Annotated[float, msgspec.Meta(gt=0, le=1e5)] = 500.0
    """Largest accepted kd in a motor command, N m s/rad."""
    paused: bool = False
    """Start paused (step with ctl/step, go with ctl/resume)."""
    clock: Literal["realtime", "lockstep"] = "realtime"
    """realtime (paced by rtf) or lockstep (each motor command advances lockstep_steps, then time stands still)."""
    lockstep_steps: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 10
    """Lockstep: physics steps each motor command advances (10 = 20 ms at the G1's 2 ms step)."""
    terrain: str | None = None
    """A terrain file (TOML: slopes, stairs, rough ground, stepping stones, boxes; services/sim/README.md); default flat."""
    band: bool = False
    """Start with the elastic band on (ctl/band): each floating robot hangs from a point above its spawn place."""

    def __post_init__(self) -> None:
        zero_or_at_least(self.rtf, 0.01, "rtf")
