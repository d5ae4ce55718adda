"""SIGINT/SIGTERM handling: the first signal asks the loops to stop, a second forces the exit."""

from __future__ import annotations

import logging
import os
import signal
import threading

logger = logging.getLogger(__name__)

connecting = threading.Event()
"""Set while a zenoh session is being opened (see common.session.open_session)."""


def stop_on_signals() -> threading.Event:
    """Install handlers for SIGINT and SIGTERM (Docker's stop) and return the stop event."""
    stop = threading.Event()

    def handle(signum: int, _frame: object) -> None:
        if stop.is_set():
            logger.warning("second %s: exiting now", signal.Signals(signum).name)
            os._exit(1)
        logger.info("%s received: stopping", signal.Signals(signum).name)
        stop.set()
        if connecting.is_set():
            # Still inside zenoh.open (a client waiting for its router): no loop will poll the
            # event and there is nothing to clean up yet.
            logger.info("stopped before the zenoh session opened")
            os._exit(0)

    signal.signal(signal.SIGINT, handle)
    signal.signal(signal.SIGTERM, handle)
    return stop
