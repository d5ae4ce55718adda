"""Settings of `zensim unitree` (defaults < `ZENSIM_*` environment < `--flags`)."""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec

from zensim.common.settings import CommonSettings


class UnitreeSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim unitree`: Unitree's DDS LowCmd/LowState on one side, zensim's keys on the other."""

    env_prefix: ClassVar[str] = "UNITREE"
    domain_id: Annotated[int, msgspec.Meta(ge=0, le=232)] = 1
    """DDS domain id, as the SDK's ChannelFactoryInitialize(domain, ...): the robot uses 0, unitree_mujoco 1."""
    interface: str = "lo"
    """Network interface DDS runs on (lo, eth0, ...); empty lets Cyclone DDS choose."""
    open_edge: bool = False
    """With --secure-dir, let DDS run on an interface other than `lo` anyway: DDS has no authentication
    here, so anyone who reaches it drives the robot (docs/security.md)."""
    mode_machine: Annotated[int, msgspec.Meta(ge=0, le=255)] = 0
    """Robot type code reported in LowState_.mode_machine (controllers echo it back; zensim ignores it)."""
    status_rate_hz: Annotated[float, msgspec.Meta(ge=0.1, le=100)] = 2.0
    """Rate of the adapter's status on state/unitree, Hz."""
    info_timeout_s: Annotated[float, msgspec.Meta(ge=0.01, le=3600)] = 1.0
    """How long each query of the sim's info/robot waits before it is retried, s."""
