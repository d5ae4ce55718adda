"""`zensim router`: a Zenoh router as a Python session in router mode.

No `zenohd` binary is needed (none ships on PyPI or in Debian): a session
opened with mode `router` routes for every peer and client that connects.
It declares the liveliness token `zensim/{robot}/alive/router`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

import msgspec
import zenoh

from zensim.common.logs import setup_logging
from zensim.common.entry import serve
from zensim.common.settings import ZenohSettings, settings_or_exit
from zensim.schemas import Keys

logger = logging.getLogger("zensim.router")

PROG = "zensim router"


class RouterSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim router`."""

    robot_id: str = "g1"
    """Robot id whose `alive/router` token this router declares."""
    log_level: str = "INFO"
    """Python log level."""
    zenoh: ZenohSettings = ZenohSettings(mode="router", listen=("tcp/127.0.0.1:7447",))
    """Zenoh settings; mode is forced to router. Listen on tcp/0.0.0.0:7447 to accept other hosts."""


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(RouterSettings, argv, PROG)
    setup_logging(settings.log_level)
    return serve(PROG, settings, _route, zenoh_settings=msgspec.structs.replace(settings.zenoh, mode="router"))


def _route(session: zenoh.Session, settings: RouterSettings, stop: threading.Event) -> int:
    token = session.liveliness().declare_token(Keys(settings.robot_id).alive("router"))
    logger.info("router up, listening on %s", ", ".join(settings.zenoh.listen) or "zenoh defaults")
    stop.wait()
    token.undeclare()
    logger.info("router stopped")
    return 0
