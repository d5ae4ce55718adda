"""`zensim router`: a Zenoh router as a Python session in router mode.

No `zenohd` binary is needed (none ships on PyPI or in Debian): a session
opened with mode `router` routes for every peer and client that connects.
It declares the liveliness tokens `zensim/{robot}/alive/router` and `zensim/@router/alive` (the
router's own key, which every robot's viewer watches: topics.ROUTER_ALIVE).

It also guards the input keys: per client link, how fast samples may be put
on `zensim/*/cmd/**`, and how large a payload on those keys and on
`zensim/*/ctl/**` queries may be. Zenoh's own downsampling and low-pass
filter do it, in Rust, before a flooding client's excess costs the sim a
single Python instruction. The size limit is on by default. The rate limit is
off by default: per link, one client's flood never eats another client's
budget, but zenoh's downsampling drops any sample that arrives sooner than
1/rate after the previous one, and two commands of a 500 Hz controller can
arrive in one batch (measured: 2 of 336 lost at 500 Hz with a 2 kHz limit).
Turn it on, well above the controllers' rate, where untrusted clients share
the router (docs/protocol.md, "Bounds").
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Sequence
from typing import Annotated, ClassVar

import msgspec
import zenoh

from zensim.common.logs import setup_logging
from zensim.common.entry import fail, serve
from zensim.common.secure import SecureConfigError
from zensim.common.session import zenoh_config
from zensim.common.settings import CommonSettings, ZenohSettings, settings_or_exit
from zensim.schemas import ROOT, Keys, topics

logger = logging.getLogger("zensim.router")
ACL_AUDIT_LOG = "warn,zenoh::net::routing::interceptor::access_control=trace"
"""RUST_LOG that makes the router log every access decision, `is unauthorized` for each denied message
(docs/security.md): zenoh logs them only at trace level, one line per message, so it is opt-in."""

PROG = "zensim router"


class RouterSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim router`."""

    env_prefix: ClassVar[str] = "ROUTER"
    zenoh: ZenohSettings = ZenohSettings(mode="router")
    """Zenoh settings; mode is forced to router. It listens on tcp/127.0.0.1:7447 (with --secure-dir: the
    folder's tls/ endpoint) unless told; listen on tcp/0.0.0.0:7447 to accept other hosts."""
    cmd_rate_limit_hz: Annotated[float, msgspec.Meta(ge=0, le=1_000_000)] = 0.0
    """Per client link, most samples per second on zensim/*/cmd/**; 0: no limit. Zenoh drops a sample that comes sooner than 1/rate after the last one, so set it well above your controllers' rate."""
    input_size_limit_bytes: Annotated[int, msgspec.Meta(ge=0)] = 65536
    """Largest payload a client may put on zensim/*/cmd/** or send with a zensim/*/ctl/** query; 0: no limit."""


def input_limits(settings: RouterSettings) -> dict[str, object]:
    """The router's guards on the input keys, ingress only: a per-link rate on puts, a size limit.

    Zenoh's `downsampling` keeps at most `freq` samples per second per link and rule; its
    `low_pass_filter` drops payloads over `size_limit`. Both run in the router, in Rust. Queries
    are not rate-limited: a query the router drops gets no reply at all, and every ctl query
    must get exactly one (the sim answers bad ones itself, cheaply, off the physics thread).
    """
    config: dict[str, object] = {}
    inputs = [f"{ROOT}/*/cmd/**", f"{ROOT}/*/ctl/**"]
    if settings.input_size_limit_bytes:
        config["low_pass_filter"] = [{"id": "zensim-inputs", "flows": ["ingress"], "messages": ["put", "query"],
                                      "key_exprs": inputs, "size_limit": settings.input_size_limit_bytes}]
    rules = []
    if settings.cmd_rate_limit_hz:
        rules.append({"id": "zensim-cmd", "flows": ["ingress"], "messages": ["put", "delete"],
                      "rules": [{"key_expr": f"{ROOT}/*/cmd/**", "freq": settings.cmd_rate_limit_hz}]})
    if rules:
        config["downsampling"] = rules
    return config


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(RouterSettings, argv, PROG)
    setup_logging(settings.log_level)
    zenoh_settings = msgspec.structs.replace(settings.zenoh, mode="router")
    try:
        listening = json.loads(zenoh_config(zenoh_settings, role="router").get_json("listen/endpoints"))
    except SecureConfigError as exc:
        return fail(PROG, f"cannot use the secure folder (--secure-dir / ZENSIM_SECURE_DIR): {exc}")
    return serve(PROG, settings, lambda session, settings, stop: _route(session, settings, stop, listening),
                 role="router", zenoh_settings=zenoh_settings, extra_config=input_limits(settings))


def _route(session: zenoh.Session, settings: RouterSettings, stop: threading.Event, listening: list[str]) -> int:
    # Two tokens: `zensim/{robot}/alive/router` for its own robot id (as before), and one key of the
    # router itself that every robot's viewer watches, whichever robot id the router was started with.
    tokens = [session.liveliness().declare_token(Keys(settings.robot_id).alive("router")),
              session.liveliness().declare_token(topics.ROUTER_ALIVE.full_key())]
    logger.info("router up, listening on %s", ", ".join(listening))
    stop.wait()
    for token in tokens:
        token.undeclare()
    logger.info("router stopped")
    return 0
