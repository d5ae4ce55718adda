"""The one shape of every long-running command: settings -> session -> run -> exit code.

    main(argv) -> settings_or_exit -> setup_logging -> serve(prog, settings, run)

`serve` turns every startup failure the user can fix (a file, a port, an
endpoint, a Zenoh config) into one line on stderr naming the cause and exit
code 2, never a traceback, and bounds the shutdown: a session whose router is
frozen or gone takes zenoh 10 s to close, so the close gets `CLOSE_TIMEOUT_S`
and the process leaves after that either way (SIGTERM exits 0 within 2 s).
"""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Protocol, TypeVar

import zenoh

from .session import StartupError, open_session
from .settings import ZenohSettings, describe
from .shutdown import stop_on_signals

logger = logging.getLogger(__name__)

__all__ = ["CLOSE_TIMEOUT_S", "StartupError", "close_within", "fail", "serve"]

CLOSE_TIMEOUT_S = 1.0
"""Longest the zenoh session may take to close at shutdown."""


class HasZenoh(Protocol):
    @property
    def zenoh(self) -> ZenohSettings: ...  # read-only: the settings are frozen structs


S = TypeVar("S", bound=HasZenoh)
Run = Callable[[zenoh.Session, S, threading.Event], int]


def fail(prog: str, message: str) -> int:
    """Say why the command cannot start, in one line, and return exit code 2."""
    print(f"{prog}: {message}", file=sys.stderr)
    return 2


def serve(prog: str, settings: S, run: Run, role: str, zenoh_settings: ZenohSettings | None = None,
          extra_config: Mapping[str, object] | None = None) -> int:
    """Open the session, call `run(session, settings, stop)` until SIGINT/SIGTERM, close in bounded time.

    Args:
        prog: the command's name, for messages (`zensim sim`).
        settings: the service's settings, logged once.
        run: the service; returns its exit code and raises StartupError for what the user can fix.
        role: whose credentials the session uses when the settings name a secure folder
            (router, sim, bridge, viz, ...; docs/security.md).
        zenoh_settings: the session's settings when they differ from `settings.zenoh` (the router).
        extra_config: zenoh config paths the service sets for itself (the router's rate limits).

    Returns:
        The exit code: run's, or 2 for a startup failure.
    """
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))  # type: ignore[arg-type]
    try:
        session = open_session(zenoh_settings or settings.zenoh, role=role, extra=extra_config)
    except StartupError as exc:
        return fail(prog, str(exc))
    try:
        return run(session, settings, stop)
    except StartupError as exc:
        return fail(prog, str(exc))
    finally:
        close_within(session, CLOSE_TIMEOUT_S)


def close_within(session: zenoh.Session, timeout_s: float) -> None:
    """Close the session, giving up after `timeout_s` (the process is about to exit anyway)."""
    closer = threading.Thread(target=session.close, name="zenoh-close", daemon=True)
    closer.start()
    closer.join(timeout_s)
    if closer.is_alive():
        logger.warning("the zenoh session did not close within %.1f s (router frozen or gone?): leaving anyway",
                       timeout_s)
