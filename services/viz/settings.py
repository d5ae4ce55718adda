"""Settings of `zensim viz` (defaults < `ZENSIM_*` environment < `--flags`)."""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec

from zensim.common.settings import CommonSettings


class VizSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim viz`: the web viewer with joint sliders."""

    env_prefix: ClassVar[str] = "VIZ"

    host: str = "127.0.0.1"
    """Address the web page is served on; 0.0.0.0 serves every interface (as in a container)."""
    port: Annotated[int, msgspec.Meta(ge=0, le=65535)] = 7000
    """TCP port of the web page (0: any free port, logged at start)."""
    urdf: str | None = None
    """A local URDF to draw (meshes resolved beside it) instead of fetching info/urdf from the sim."""
    rate_hz: Annotated[float, msgspec.Meta(ge=1, le=240)] = 60.0
    """Most pose updates per second sent to a browser; each browser gets only the newest pose when ready."""
    ghost: bool = True
    """Draw the translucent commanded pose (state/targets)."""
    ghost_offset_m: tuple[float, ...] = (0.0, 0.9, 0.0)
    """Where the ghost stands relative to the robot, x,y,z in m, world frame (default: beside it; 0,0,0: over it)."""
    query_timeout_s: Annotated[float, msgspec.Meta(ge=0.01, le=3600)] = 5.0
    """Timeout of each zenoh get (description, ctl requests), s."""
    allowed_hosts: tuple[str, ...] = ()
    """Extra Host names the page answers to, comma-separated (loopback names, IP addresses and --host always;
    * any); other names are refused against DNS rebinding."""
    token: str | None = None
    """Access token required when the page is reachable beyond loopback (default: a random one, printed at
    start as a URL); set it for compose."""
    viewer_token: str | None = None
    """A second access token, for pages that may watch, not drive (sliders, buttons, keys, gamepad refused);
    giving one makes a token needed on loopback too."""
    published_on: str | None = None
    """Where the page is reachable from outside when that is not --host (compose passes ZENSIM_BIND);
    anything but loopback requires the token."""
    world: str | None = None
    """A world's id (`zensim sim --world`): show every robot of that world at its place; the panel acts on the one picked."""
