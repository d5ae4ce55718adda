"""Open Zenoh sessions from `ZenohSettings`.

Secure defaults (docs/security.md): nothing listens beyond loopback and no
multicast scouting runs unless the settings ask for it. Services started by
hand on one machine with no endpoints still meet: a peer first tries to
listen on the local meeting point `tcp/127.0.0.1:7447` (where `zensim router`
listens by default); if that port is taken (a router, or another service
came first) it listens on a free loopback port and connects there instead.
Zenoh's gossip then links the peers to each other directly, so they keep
talking when the meeting-point holder exits.

With `secure_dir` the session loads the role's config made by `zensim secure
init` (TLS, password, client certificate) and joins the router as a client.

Every failure the user can fix (a config file, a port, an endpoint, a secure
folder) is raised as `StartupError` naming the setting, for a one-line exit.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Mapping

import zenoh

from .secure import SecureConfigError, password_printing_directive, role_config
from .settings import LOCAL_ROUTER_ENDPOINT, ZenohSettings
from .shutdown import connecting

logger = logging.getLogger(__name__)


class StartupError(RuntimeError):
    """A failure at start that the user can fix; its text names the setting and the cause."""


LOCAL_MEETING_ENDPOINT = LOCAL_ROUTER_ENDPOINT
"""Where peers with no endpoints meet on one machine (the default `zensim router` endpoint)."""
LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"
WAITING_LOG_PERIOD_S = 5.0
"""How often a client waiting for its router says so."""


def zenoh_config(settings: ZenohSettings, role: str = "viewer", meet_here: bool = False,
                 extra: Mapping[str, object] | None = None) -> zenoh.Config:
    """A zenoh.Config: the config file (or the secured role's) if given, overridden by the explicit settings.

    Args:
        settings: the service's zenoh settings.
        role: whose credentials to load from `settings.secure_dir` (router, sim, bridge, viz, operator, viewer).
        meet_here: a peer with no endpoints listens on the local meeting point itself
            instead of connecting to it (see the module docstring).
        extra: config paths (`downsampling`) and values a service sets for itself.

    Raises:
        SecureConfigError: the secure folder lacks the role's config, or an endpoint is not `tls/`.
        zenoh.ZError: the config file cannot be read or a value is refused.
    """
    mode = settings.mode
    if settings.secure_dir:
        if settings.config_file:
            raise SecureConfigError("give either --secure-dir or --zenoh-config-file, not both")
        conf = role_config(settings.secure_dir, role)
        # Access control is enforced by the router: every other secured session is its client,
        # never a peer that others could reach around it.
        mode = "router" if role == "router" else "client"
        plain = [e for e in (*settings.connect, *settings.listen) if not e.startswith("tls/")]
        if plain:
            raise SecureConfigError(f"secured links use tls/ endpoints, not {', '.join(plain)}")
    else:
        conf = zenoh.Config.from_file(settings.config_file) if settings.config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    connect, listen = list(settings.connect), list(settings.listen)
    if settings.config_file and not listen and not says_listen(conf):
        # A config file (for TLS, timeouts, a router's address...) that does not say `listen` itself must
        # not turn the loopback default into zenoh's own, every interface: the same defaults as without one.
        listen = {"peer": [LOOPBACK_ANY_PORT], "router": [LOCAL_MEETING_ENDPOINT]}.get(mode, [])
    if not settings.config_file and not settings.secure_dir:
        if mode == "peer" and not connect and not listen:
            listen, connect = ([LOCAL_MEETING_ENDPOINT], []) if meet_here else ([LOOPBACK_ANY_PORT], [LOCAL_MEETING_ENDPOINT])
        elif mode == "peer" and not listen:
            listen = [LOOPBACK_ANY_PORT]  # zenoh's own default is every interface
        elif mode == "client" and not connect:
            connect = [LOCAL_MEETING_ENDPOINT]
        elif mode == "router" and not listen:
            listen = [LOCAL_MEETING_ENDPOINT]
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    if mode == "client":
        # A client whose router is not up yet would fail at once; in a compose
        # stack the router may start after us, so wait for it instead.
        conf.insert_json5("connect/timeout_ms", "-1")
    if mode == "router":
        # Without this a router waits 500 ms of scouting before it opens.
        conf.insert_json5("scouting/delay", "0")
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return conf


def says_listen(conf: zenoh.Config) -> bool:
    """Whether `conf` (read from a file) sets `listen/endpoints` itself, rather than keeping zenoh's defaults."""
    return conf.get_json("listen/endpoints") != zenoh.Config().get_json("listen/endpoints")


def endpoints(conf: zenoh.Config) -> str:
    """What a session of `conf` listens on and connects to, in words for the start log."""
    mode = json.loads(conf.get_json("mode"))
    words = []
    for what in ("listen", "connect"):
        value = json.loads(conf.get_json(f"{what}/endpoints"))
        if isinstance(value, dict):  # zenoh's per-mode default
            value = value.get(mode, [])
        words.append(f"{'listening on' if what == 'listen' else 'connecting to'} {', '.join(value) or 'nothing'}")
    return f"zenoh {mode}: " + "; ".join(words)


def _uses_meeting_point(settings: ZenohSettings) -> bool:
    return (settings.mode == "peer" and not settings.connect and not settings.listen
            and not settings.config_file and not settings.secure_dir)


def open_session(settings: ZenohSettings, role: str = "viewer", claim_meeting_point: bool = True,
                 extra: Mapping[str, object] | None = None, timeout_s: float | None = None) -> zenoh.Session:
    """Open a session; close it when done (`zensim.common.entry.serve` does, in bounded time).

    A client waits for its router with no timeout, saying so every few
    seconds. The open runs on a helper thread so the main thread keeps
    running Python code, where signal handlers run: a SIGINT/SIGTERM during
    the wait exits at once.

    Args:
        settings: the zenoh settings.
        role: the credentials to use when `settings.secure_dir` is set.
        claim_meeting_point: a peer with no endpoints may become the local meeting point; a short-lived
            tool (`zensim check`) must not, or a router started meanwhile could not bind it.
        extra: config paths and values the service sets for itself (the router's input limits).
        timeout_s: give up after this long (a tool with a deadline, `zensim check`); None waits for the router.

    Raises:
        StartupError: the config file, the secure folder, an endpoint or a port is refused, or no router
            answered within `timeout_s`; the text names the setting.
    """
    leak = password_printing_directive(os.environ.get("RUST_LOG", "")) if settings.secure_dir else None
    if leak and role != "router":  # the router's config names users.txt, never a password
        raise StartupError(f"RUST_LOG={leak} would print this service's password in clear (zenoh logs a session's "
                           "whole config at debug level): with --secure-dir raise only the modules you need "
                           "(docs/security.md)")
    if claim_meeting_point and _uses_meeting_point(settings):
        config = _config(settings, role, True, extra)
        try:
            session = _open(settings, config)
            logger.info("%s (the local meeting point)", endpoints(config))
            return session
        except StartupError:
            logger.info("zenoh: %s is taken (a router or another service): joining it", LOCAL_MEETING_ENDPOINT)
    config = _config(settings, role, False, extra)
    session = _open(settings, config, timeout_s)
    logger.info("%s", endpoints(config))
    return session


def _config(settings: ZenohSettings, role: str, meet_here: bool, extra: Mapping[str, object] | None) -> zenoh.Config:
    try:
        return zenoh_config(settings, role, meet_here, extra)
    except SecureConfigError as exc:
        raise StartupError(f"cannot use the secure folder (--secure-dir / ZENSIM_SECURE_DIR "
                           f"{settings.secure_dir}): {exc}") from None
    except zenoh.ZError as exc:
        raise StartupError(f"cannot use the zenoh config file (--zenoh-config-file / ZENSIM_ZENOH_CONFIG_FILE "
                           f"{settings.config_file}): {_first_line(exc)}") from None


def _open(settings: ZenohSettings, config: zenoh.Config, timeout_s: float | None = None) -> zenoh.Session:
    outcome: dict[str, object] = {}

    def open_in_thread() -> None:
        try:
            outcome["session"] = zenoh.open(config)
        except Exception as exc:  # handed to the main thread below
            outcome["error"] = exc

    connecting.set()
    try:
        opener = threading.Thread(target=open_in_thread, name="zenoh-open", daemon=True)
        opener.start()
        started = time.monotonic()
        next_word = started + WAITING_LOG_PERIOD_S
        while opener.is_alive():
            opener.join(0.1)
            if opener.is_alive() and timeout_s is not None and time.monotonic() - started >= timeout_s:
                # The opener thread is a daemon: left behind, it ends with the process.
                where = ", ".join(settings.connect) or LOCAL_MEETING_ENDPOINT
                raise StartupError(f"no zenoh router answered at {where} within {timeout_s:g} s")
            if opener.is_alive() and time.monotonic() >= next_word:
                where = ", ".join(settings.connect) or LOCAL_MEETING_ENDPOINT
                logger.warning("waiting for the router at %s", where)
                next_word = time.monotonic() + WAITING_LOG_PERIOD_S
    finally:
        connecting.clear()
    if "error" in outcome:
        given = []
        if settings.listen:
            given.append(f"listen {', '.join(settings.listen)} (--zenoh-listen / ZENSIM_ZENOH_LISTEN)")
        if settings.connect:
            given.append(f"connect {', '.join(settings.connect)} (--zenoh-connect / ZENSIM_ZENOH_CONNECT)")
        raise StartupError(f"cannot open the zenoh session ({'; '.join(given) or 'zenoh defaults'}): "
                           f"{_first_line(outcome['error'])}") from None
    return outcome["session"]  # type: ignore[return-value]


def _first_line(exc: object) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
