"""Open Zenoh sessions from `ZenohSettings`."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Mapping

import zenoh

from .settings import ZenohSettings
from .shutdown import connecting

logger = logging.getLogger(__name__)



class StartupError(RuntimeError):
    """A failure at start that the user can fix; its text names the setting and the cause."""


WAITING_LOG_PERIOD_S = 5.0
"""How often a client waiting for its router says so."""


def zenoh_config(settings: ZenohSettings, extra: Mapping[str, object] | None = None) -> zenoh.Config:
    """A zenoh.Config: the config file if given, overridden by the explicit settings, then by `extra`.

    Args:
        settings: the service's Zenoh settings.
        extra: config paths (`downsampling`) and values a service sets for itself.

    Raises:
        zenoh.ZError: the config file cannot be read or a value is refused.
    """
    conf = zenoh.Config.from_file(settings.config_file) if settings.config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.mode))
    if settings.connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    if settings.listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    if settings.mode == "client":
        # A client whose router is not up yet would fail at once; in a compose
        # stack the router may start after us, so wait for it instead.
        conf.insert_json5("connect/timeout_ms", "-1")
    if settings.mode == "router":
        # Without this a router waits 500 ms of scouting before it opens.
        conf.insert_json5("scouting/delay", "0")
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return conf


def open_session(settings: ZenohSettings, extra: Mapping[str, object] | None = None) -> zenoh.Session:
    """Open a session; close it when done (`zensim.common.entry.serve` does, in bounded time).

    A client waits for its router with no timeout, saying so every few
    seconds. The open runs on a helper thread so the main thread keeps
    running Python code, where signal handlers run: a SIGINT/SIGTERM during
    the wait exits at once.

    Raises:
        StartupError: the config file, an endpoint or a port is refused; the text names the setting.
    """
    try:
        config = zenoh_config(settings, extra)
    except zenoh.ZError as exc:
        raise StartupError(f"cannot use the zenoh config file (--zenoh-config-file / ZENSIM_ZENOH_CONFIG_FILE "
                           f"{settings.config_file}): {_first_line(exc)}") from None
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
        next_word = time.monotonic() + WAITING_LOG_PERIOD_S
        while opener.is_alive():
            opener.join(0.1)
            if opener.is_alive() and time.monotonic() >= next_word:
                where = ", ".join(settings.connect) or "the configured endpoints"
                logger.warning("waiting for the router at %s", where)
                next_word = time.monotonic() + WAITING_LOG_PERIOD_S
    finally:
        connecting.clear()
    if "error" in outcome:
        exc = outcome["error"]
        where = []
        if settings.listen:
            where.append(f"listen {', '.join(settings.listen)} (--zenoh-listen / ZENSIM_ZENOH_LISTEN)")
        if settings.connect:
            where.append(f"connect {', '.join(settings.connect)} (--zenoh-connect / ZENSIM_ZENOH_CONNECT)")
        raise StartupError(f"cannot open the zenoh session ({'; '.join(where) or 'zenoh defaults'}): "
                           f"{_first_line(exc)}") from None
    return outcome["session"]  # type: ignore[return-value]


def _first_line(exc: object) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
