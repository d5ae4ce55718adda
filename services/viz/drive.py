"""Driving the robot from the page (keys, gamepad): what goes out on `cmd/velocity` and `cmd/remote`, and
how often. Pure logic, no zenoh: the service puts what `DriveGate` lets through.

Every page showing a robot may drive it, and a person holding a key makes the browser repeat it (the
page sends only changes and a keep-alive, but a page can be buggy or hostile, and many pages may be
open): the puts to one robot are paced by a token bucket shared by all its pages. What comes faster is
shed, latest wins: a newer input replaces the one waiting, which is counted, and the one waiting goes
out as soon as the bucket allows (`flush`, every tick of the viz), so the last input, a stop included,
is never lost.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from zensim.common.token_bucket import TokenBucket
from zensim.schemas import RemoteState, VelocityCommand

PUTS_PER_S: Final = 30.0
"""Most velocity puts per second to one robot, all pages together (the walking policy runs at 50 Hz of
sim time, the page's keep-alive is 10 Hz: a person never needs more)."""
PUT_BURST: Final = 6.0
"""Puts allowed back to back (a key pressed, released and another pressed in one frame)."""
PAGE_TIMEOUT_S: Final = 1.0
"""The sim time a page's command holds (VelocityCommand.timeout_s): the page repeats a held key every
100 ms of wall time; under the lockstep clock sim time runs several times faster than that, so the
default 0.5 s could lapse between two repeats. A page that dies leaves a robot that stops within it."""


@dataclass(frozen=True)
class Drive:
    """One input from a page: the velocity to walk at and the remote as the page's keys or gamepad hold it."""

    velocity: VelocityCommand
    remote: RemoteState


class DriveGate:
    """Paces one robot's drive puts: at most `rate` a second (bursts of `burst`), latest wins.

    Args:
        rate: puts per second.
        burst: puts allowed back to back.
        clock: seconds, monotonic (tests may pass their own).
    """

    def __init__(self, rate: float = PUTS_PER_S, burst: float = PUT_BURST,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rate = rate
        self._bucket = TokenBucket(rate, burst, clock)
        self.waiting: Drive | None = None
        """An input that came faster than the rate: the next to go out (replaced by a newer one)."""
        self.received = 0
        """Inputs offered by pages."""
        self.sent = 0
        """Inputs let through (put)."""
        self.shed = 0
        """Inputs replaced unsent by a newer one (latest wins)."""

    def offer(self, drive: Drive) -> Drive | None:
        """A page's input: returned when it may go out now, else kept (replacing the one waiting)."""
        self.received += 1
        if self.waiting is None and self._bucket.take():
            self.sent += 1
            return drive
        if self.waiting is not None:
            self.shed += 1
        self.waiting = drive
        return None

    def flush(self) -> Drive | None:
        """The input waiting, when the rate now lets it out."""
        if self.waiting is None or not self._bucket.take():
            return None
        drive, self.waiting = self.waiting, None
        self.sent += 1
        return drive

    def counts(self) -> dict[str, int]:
        return {"received": self.received, "sent": self.sent, "shed": self.shed}
