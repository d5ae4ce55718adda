"""Logging set-up, once per process, and a rate limiter for bad-input warnings."""

from __future__ import annotations

import logging
import time

import zenoh

FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def setup_logging(level: str) -> None:
    """Configure stdlib logging at `level`; zenoh's Rust logs follow RUST_LOG (default warn)."""
    logging.basicConfig(level=level.upper(), format=FORMAT)
    zenoh.init_log_from_env_or("warn")


class RateLimitedLog:
    """Log at most one line per `period_s` per limiter, counting what it held back.

    A flood of malformed inputs must not turn into a flood of log lines.
    """

    def __init__(self, logger: logging.Logger, period_s: float = 1.0) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last = -float("inf")
        self._suppressed = 0

    def warning(self, msg: str, *args: object) -> None:
        now = time.monotonic()
        if now - self._last < self._period_s:
            self._suppressed += 1
            return
        if self._suppressed:
            msg = f"{msg} (and {self._suppressed} more like it held back)"
        self._logger.warning(msg, *args)
        self._last = now
        self._suppressed = 0
