"""Open Zenoh sessions from `ZenohSettings`."""

from __future__ import annotations

import json
import threading

import zenoh

from .settings import ZenohSettings
from .shutdown import connecting


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """A zenoh.Config: the config file if given, overridden by the explicit settings."""
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
    return conf


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """Open a session; use it as a context manager so it is always closed.

    A client waits for its router with no timeout. The open runs on a helper
    thread so the main thread keeps running Python code, where signal
    handlers run: a SIGINT/SIGTERM during the wait exits at once.
    """
    config = zenoh_config(settings)
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
        while opener.is_alive():
            opener.join(0.1)
    finally:
        connecting.clear()
    if "error" in outcome:
        raise outcome["error"]  # type: ignore[misc]
    return outcome["session"]  # type: ignore[return-value]
