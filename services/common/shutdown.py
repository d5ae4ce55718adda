"""SIGINT/SIGTERM handling: the first signal asks the loops to stop, a second forces the exit.

The signal is acted on by a thread of its own, not by a Python signal handler. Python runs a handler on
the main thread, between two bytecodes, wherever that thread is; a main thread that polls
`stop.wait(t)` spends part of each poll holding the event's lock (a plain, non-reentrant lock), and a
handler that called `stop.set()` there waited for that lock, held by its own thread, for ever: three CI
runs saw `zensim up` kill a router still running 10 s after its SIGTERM, and a main thread that polls
`stop.wait(0)` hung in about one SIGTERM of two (tests/test_shutdown.py). So Python's C-level handler
writes the signal's number to a socket (`signal.set_wakeup_fd`, async-signal-safe), and a daemon thread
reads it and does the work: logs, sets the event, or exits. That thread waits at most the microseconds
the main thread holds the lock, and it acts even while the main thread is inside zenoh's Rust code.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading

logger = logging.getLogger(__name__)

connecting = threading.Event()
"""Set while a zenoh session is being opened (see common.session.open_session)."""

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_stop: threading.Event | None = None
"""The event the latest stop_on_signals() returned: the one a signal sets."""
_wakeup: socket.socket | None = None
"""The socket Python's C handler writes each signal's number to; open for the life of the process."""


def stop_on_signals() -> threading.Event:
    """Catch SIGINT and SIGTERM (Docker's stop) and return the event they set. Call from the main thread."""
    global _stop
    _stop = threading.Event()
    if _wakeup is None:
        _start_watcher()
    return _stop


def _start_watcher() -> None:
    global _wakeup
    reader, _wakeup = socket.socketpair()
    _wakeup.setblocking(False)  # set_wakeup_fd requires it: the C handler must never block
    signal.set_wakeup_fd(_wakeup.fileno(), warn_on_full_buffer=False)
    for signum in _STOP_SIGNALS:
        # A Python handler must be installed for the C handler to write to the socket; it does nothing
        # itself (see the module's docstring for why).
        signal.signal(signum, _ignore_here)
    threading.Thread(target=_watch, args=(reader,), name="zensim-signals", daemon=True).start()


def _ignore_here(_signum: int, _frame: object) -> None:
    """The Python-level handler: the watcher thread acts on the signal."""


def _watch(reader: socket.socket) -> None:
    while signums := reader.recv(64):
        for signum in signums:
            if signum in _STOP_SIGNALS:
                _on_stop_signal(signal.Signals(signum))


def _on_stop_signal(signum: signal.Signals) -> None:
    stop = _stop
    assert stop is not None  # set before the watcher starts
    if stop.is_set():
        logger.warning("second %s: exiting now", signum.name)
        os._exit(1)
    logger.info("%s received: stopping", signum.name)
    stop.set()
    if connecting.is_set():
        # Still inside zenoh.open (a client waiting for its router): no loop will poll the
        # event and there is nothing to clean up yet.
        logger.info("stopped before the zenoh session opened")
        os._exit(0)
