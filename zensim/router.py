"""`zensim router`: a Zenoh router as a Python session in router mode.

No `zenohd` binary is needed (none ships on PyPI or in Debian): a session
opened with mode `router` routes for every peer and client that connects.
It declares the liveliness tokens `zensim/{robot}/alive/router` and `zensim/@router/alive` (the
router's own key, which every robot's viewer watches: topics.ROUTER_ALIVE).

It also guards the input keys: per client link, how fast samples may be put
on `zensim/*/cmd/**`, and how large a payload on those keys may be. Zenoh's own downsampling and low-pass
filter do it, in Rust, before a flooding client's excess costs the sim a
single Python instruction. The size limit is on by default. The rate limit is
off by default: per link, one client's flood never eats another client's
budget, but zenoh's downsampling drops any sample that arrives sooner than
1/rate after the previous one, and two commands of a 500 Hz controller can
arrive in one batch (measured: 2 of 336 lost at 500 Hz with a 2 kHz limit).
Turn it on, well above the controllers' rate, where untrusted clients share
the router (docs/protocol.md, "Bounds").

It also bounds the handshake queue. A TCP connection that never finishes
zenoh's handshake holds one of zenoh's pending-accept slots until the accept
timeout (zenoh's defaults: 100 slots, 10 s), so ~100 silent connections locked
every new session out, and a crashed service could not rejoin. The router
raises the slots and shortens the timeout (`accept_pending`, `accept_timeout_ms`)
and lifts its open-file limit to fit them. Zenoh has no per-source limit of its
own; docs/security.md gives the firewall rule that adds one (for zenohd too).
"""

from __future__ import annotations

import json
import logging
import resource
import threading
from collections.abc import Sequence
from typing import Annotated, ClassVar

import msgspec
import zenoh

from zensim.common.logs import setup_logging
from zensim.common.entry import fail, serve
from zensim.common.secure import SecureConfigError
from zensim.common.session import zenoh_config
from zensim.common.settings import CommonSettings, ZenohSettings, settings_or_exit, zero_or_at_least
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
    """Largest payload a client may put on zensim/*/cmd/**; 0: no limit. (ctl/** queries are capped by the sim, which answers an oversize one with an error: a query dropped here would get no reply at all.)"""
    accept_pending: Annotated[int, msgspec.Meta(ge=16, le=65536)] = 4096
    """Connections that may be mid-handshake at once (zenoh's default 100 let ~100 silent ones lock everyone out)."""
    accept_timeout_ms: Annotated[int, msgspec.Meta(ge=100, le=60_000)] = 1000
    """A connection that has not finished the zenoh handshake by then is closed (zenoh's default: 10 s)."""

    def __post_init__(self) -> None:
        zero_or_at_least(self.cmd_rate_limit_hz, 1.0, "cmd_rate_limit_hz")


def handshake_limits(settings: RouterSettings) -> dict[str, object]:
    """Zenoh's accept queue: how many connections may be mid-handshake, and for how long."""
    return {"transport/unicast/accept_pending": settings.accept_pending,
            "transport/unicast/accept_timeout": settings.accept_timeout_ms}


def raise_open_files_limit(wanted: int) -> int:
    """Lift the soft open-file limit towards `wanted` (within the hard limit); returns the limit in force.

    Each pending handshake is a socket: with the common soft limit of 1024 a flood would hit EMFILE
    long before the accept queue fills.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
    if target > soft:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            return target
        except (ValueError, OSError):
            pass
    return soft


def input_limits(settings: RouterSettings) -> dict[str, object]:
    """The router's guards on the input keys, ingress only: a per-link rate on puts, a size limit.

    Zenoh's `downsampling` keeps at most `freq` samples per second per link and rule; its
    `low_pass_filter` drops payloads over `size_limit`. Both run in the router, in Rust. Queries
    are neither rate- nor size-limited here: a query the router drops gets no reply at all, and every
    ctl query must get exactly one (the sim checks the size before decoding and answers an oversize or
    bad one itself, cheaply, off the physics thread).
    """
    config: dict[str, object] = {}
    if settings.input_size_limit_bytes:
        config["low_pass_filter"] = [{"id": "zensim-inputs", "flows": ["ingress"], "messages": ["put"],
                                      "key_exprs": [f"{ROOT}/*/cmd/**"], "size_limit": settings.input_size_limit_bytes}]
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
    open_files = raise_open_files_limit(settings.accept_pending + 1024)  # the queue, plus sessions and the rest
    if open_files < settings.accept_pending + 64:
        logger.warning("open files are limited to %d: fewer than --accept-pending %d handshakes can wait",
                       open_files, settings.accept_pending)
    return serve(PROG, settings, lambda session, settings, stop: _route(session, settings, stop, listening),
                 role="router", zenoh_settings=zenoh_settings,
                 extra_config={**input_limits(settings), **handshake_limits(settings)})


def _route(session: zenoh.Session, settings: RouterSettings, stop: threading.Event, listening: list[str]) -> int:
    # Two tokens: `zensim/{robot}/alive/router` for its own robot id (as before), and one key of the
    # router itself that every robot's viewer watches, whichever robot id the router was started with.
    tokens = [session.liveliness().declare_token(Keys(settings.robot_id).alive("router")),
              session.liveliness().declare_token(topics.ROUTER_ALIVE.full_key())]
    logger.info("router up, listening on %s", ", ".join(listening))
    # No token undeclared by hand: the tokens go with the session, which serve() closes in bounded time.
    # (Three CI runs saw `zensim up` kill this router 10 s after its SIGTERM. The cause was the signal handler,
    # which set `stop` on this thread while the thread held the event's lock: common/shutdown.py.)
    stop.wait()
    logger.info("router stopped (%d tokens go with the session)", len(tokens))
    return 0
