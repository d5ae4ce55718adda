"""Logging set-up, once per process, and a rate limiter for bad-input warnings."""

from __future__ import annotations

import logging
import threading
import time

import zenoh

FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def setup_logging(level: str) -> None:
    """Configure stdlib logging at `level`; zenoh's Rust logs follow RUST_LOG (default warn)."""
    logging.basicConfig(level=level.upper(), format=FORMAT)
    zenoh.init_log_from_env_or("warn")


class RateLimitedLog:
    """Log at most one line per `period_s` per limiter, counting what it held back.

    A flood of malformed inputs, or of requests that each deserve a line, must not turn into a
    flood of log lines. Every per-request line in zensim goes through one of these. Safe to call
    from any thread.
    """

    def __init__(self, logger: logging.Logger, period_s: float = 1.0) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last = -float("inf")
        self._suppressed = 0
        self._lock = threading.Lock()

    def warning(self, msg: str, *args: object) -> None:
        self.log(logging.WARNING, msg, *args)

    def info(self, msg: str, *args: object) -> None:
        self.log(logging.INFO, msg, *args)

    def exception(self, msg: str, *args: object) -> None:
        """An error line with the traceback of the exception being handled (a bug, but one per period)."""
        self.log(logging.ERROR, msg, *args, exc_info=True)

    def log(self, level: int, msg: str, *args: object, exc_info: bool = False) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._last < self._period_s:
                self._suppressed += 1
                return
            suppressed, self._suppressed, self._last = self._suppressed, 0, now
        if suppressed:
            msg = f"{msg} (and {suppressed} more like it held back)"
        self._logger.log(level, msg, *args, exc_info=exc_info)
