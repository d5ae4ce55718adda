"""Settings of `zensim bridge` (defaults < `ZENSIM_*` environment < `--flags`)."""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec

from zensim.common.settings import CommonSettings, zero_or_at_least

MAX_RATE_HZ = 1000.0


class BridgeSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim bridge`: joint targets in, motor commands out."""

    env_prefix: ClassVar[str] = "BRIDGE"
    rate_hz: Annotated[float, msgspec.Meta(ge=1, le=MAX_RATE_HZ)] = 100.0
    """Rate of MotorCommand on cmd/motors, Hz (1 to 1000)."""
    targets_rate_hz: Annotated[float, msgspec.Meta(ge=0, le=MAX_RATE_HZ)] = 30.0
    """Rate of the held targets on state/targets (the viewer's ghost), Hz; 0 turns it off."""
    slew_rad_s: Annotated[float, msgspec.Meta(ge=0, le=1000)] = 2.0
    """Slew limit: most a commanded joint position moves per second, rad/s; 0 turns it off."""
    info_timeout_s: Annotated[float, msgspec.Meta(ge=0.01, le=3600)] = 1.0
    """How long each query of the sim's info/robot waits before it is retried, s."""
    robot: str | None = None
    """Bundled robot (e.g. g1) to read joints, limits and gains from instead of asking the sim."""
    urdf: str | None = None
    """A URDF to read joints and limits from instead of asking the sim (gains from --control)."""
    control: str | None = None
    """A control.toml to go with --urdf or --robot."""

    def __post_init__(self) -> None:
        zero_or_at_least(self.targets_rate_hz, 1.0, "targets_rate_hz")
