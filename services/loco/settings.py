"""Settings of `zensim loco` (defaults < `ZENSIM_*` environment < `--flags`)."""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec

from zensim.common.settings import CommonSettings
from zensim.schemas.messages import LocoVerb


class LocoSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim loco`: velocity and walking verbs in, motor commands out."""

    env_prefix: ClassVar[str] = "LOCO"
    status_rate_hz: Annotated[float, msgspec.Meta(ge=0.1, le=100)] = 10.0
    """Rate of the walking controller's state on state/loco, Hz (also sent at each change)."""
    info_timeout_s: Annotated[float, msgspec.Meta(ge=0.01, le=3600)] = 1.0
    """How long each query of the sim's info/robot waits before it is retried, s."""
    start: LocoVerb | None = None
    """A walking verb run as soon as the robot is known (`walk`: stand up, then walk on cmd/velocity, for
    front ends that only send velocities: ROS's /cmd_vel); empty: passive until the first request."""
