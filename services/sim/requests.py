"""ctl requests on their way from zenoh's callback threads to the thread that owns the physics.

A callback checks and decodes a query, then hands it over here and returns at once: it never
waits for the loop (a waiting callback holds one of zenoh's threads, and queries queue behind it
where nobody can see or bound them). The loop thread takes the requests one by one between two
steps, runs them and replies itself.

Two bounds keep a request from doing harm when it comes late:
- at most `max_pending` wait at once; one more is answered `busy` at once and never runs;
- a request the loop cannot start within `start_timeout_s` is answered and dropped, not run: its
  client has most likely given up (zenoh's get() waits 10 s by default, the viewer 5 s), and a
  reset that lands seconds after its client stopped waiting is a surprise, not a service.
Zenoh does not tell a queryable when the querier stopped waiting, so the start timeout stands in
for it; a client that waits less than that may still see its request run after it gave up.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from zensim.common.logs import RateLimitedLog
from zensim.common.queryable import TypedQuery
from zensim.schemas import CtlReply, bounded

logger = logging.getLogger("zensim.sim")

MAX_PENDING = 16
"""ctl requests that may wait for the loop at once; the next one is answered busy."""
START_TIMEOUT_S = 2.0
"""Longest a request may wait for the loop to start it; later it is dropped, not run."""
T = TypeVar("T")
failures = RateLimitedLog(logger)
"""Tracebacks of requests that raised (a bug in the sim, but one any client can set off again and again)."""


def run_guarded(action: Callable[[], T], what: str, failed: Callable[[str], T]) -> T:
    """Run a request's action; an exception becomes `failed(reason)`, its traceback logged at a bounded rate.

    A failed request must not take down the thread that ran it (the loop, or a callback thread) nor
    leave its client without an answer.
    """
    try:
        return action()
    except Exception as exc:
        failures.exception("%s failed", what)
        return failed(bounded(f"{type(exc).__name__}: {exc}"))


@dataclass
class Request:
    """One checked ctl query, waiting for the loop thread."""

    query: TypedQuery
    """Answered (in its own format, a refusal counted) once the action ran, or when it will not run."""
    run: Callable[[], CtlReply]
    """The action; runs on the loop thread, with the physics lock held."""
    received: float = field(default_factory=time.monotonic)


class Requests:
    """A bounded queue of ctl requests with a start deadline.

    Args:
        busy: the reply for a request that is not run (its text says why).
        wake: set when a request is queued (the loop waits on one event for every queue it serves).
        max_pending: requests that may wait at once.
        start_timeout_s: longest wait before a request is dropped.
    """

    def __init__(self, busy: Callable[[str], CtlReply], wake: threading.Event, max_pending: int = MAX_PENDING,
                 start_timeout_s: float = START_TIMEOUT_S) -> None:
        self._busy = busy
        self._wake = wake
        self._queue: queue.Queue[Request] = queue.Queue(max_pending)
        self.start_timeout_s = start_timeout_s

    def submit(self, request: Request) -> None:
        """From a callback: queue `request`, or answer it busy at once when too many wait."""
        try:
            self._queue.put_nowait(request)
            self._wake.set()
        except queue.Full:
            self._not_run(request, f"busy: {self._queue.maxsize} ctl requests are waiting; nothing was done, "
                                   "send it again")

    def run_next(self, run: Callable[[Request], CtlReply]) -> bool:
        """On the loop thread: run (through `run`) the next request, if one waits.

        Returns:
            True when a request was taken (run or dropped), False when none waits.
        """
        try:
            request = self._queue.get_nowait()
        except queue.Empty:
            return False
        waited = time.monotonic() - request.received
        if waited > self.start_timeout_s:
            self._not_run(request, f"the sim loop could not start this request within {self.start_timeout_s:g} s "
                                   f"(it waited {waited:.1f} s behind others); nothing was done")
        else:
            self._finish(request, run_guarded(lambda: run(request), "a ctl request", self._busy))
        return True

    def close(self, reason: str) -> None:
        """Answer whatever still waits, so no client hangs on a closing sim."""
        while True:
            try:
                request = self._queue.get_nowait()
            except queue.Empty:
                return
            self._not_run(request, reason)

    def _not_run(self, request: Request, reason: str) -> None:
        self._finish(request, self._busy(reason))

    @staticmethod
    def _finish(request: Request, message: CtlReply) -> None:
        try:
            request.query.reply(message)  # the final reply: the client's get() ends now
        except Exception:  # a reply that cannot go out must not take the loop down
            failures.exception("answering a ctl request")
