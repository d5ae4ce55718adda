"""`zensim router`: a Zenoh router as a Python session in router mode.

No `zenohd` binary is needed (none ships on PyPI or in Debian): a session
opened with mode `router` routes for every peer and client that connects.
It declares the liveliness token `zensim/{robot}/alive/router`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence

import msgspec

from zensim.common.logs import setup_logging
from zensim.common.secure import SecureConfigError
from zensim.common.session import open_session, zenoh_config
from zensim.common.settings import ZenohSettings, describe, settings_or_exit
from zensim.common.shutdown import stop_on_signals
from zensim.schemas import Keys

logger = logging.getLogger("zensim.router")
ACL_AUDIT_LOG = "warn,zenoh::net::routing::interceptor::access_control=trace"
"""RUST_LOG that makes the router log every access decision, `is unauthorized` for each denied message
(docs/security.md): zenoh logs them only at trace level, one line per message, so it is opt-in."""


class RouterSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim router`."""

    robot_id: str = "g1"
    """Robot id whose `alive/router` token this router declares."""
    log_level: str = "INFO"
    """Python log level."""
    zenoh: ZenohSettings = ZenohSettings(mode="router")
    """Zenoh settings; mode is forced to router. It listens on tcp/127.0.0.1:7447 (with --secure-dir: the
    folder's tls/ endpoint) unless told; listen on tcp/0.0.0.0:7447 to accept other hosts."""


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(RouterSettings, argv, "zensim router")
    setup_logging(settings.log_level)
    zenoh_settings = msgspec.structs.replace(settings.zenoh, mode="router")
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))
    try:
        listening = json.loads(zenoh_config(zenoh_settings, role="router").get_json("listen/endpoints"))
    except SecureConfigError as exc:
        logger.error("%s", exc)
        return 2
    with open_session(zenoh_settings, role="router") as session:
        token = session.liveliness().declare_token(Keys(settings.robot_id).alive("router"))
        logger.info("router up, listening on %s", ", ".join(listening))
        stop.wait()
        token.undeclare()
    logger.info("router stopped")
    return 0
