"""The token bucket every edge sheds a flood with: at most a rate on average, a burst at once.

The ROS 2 gateway's commands, the viz's page messages and drive puts, and the Unitree adapter's RPC
requests all pace with it: more than the bucket holds is refused (or held) by the caller, never queued here.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class TokenBucket:
    """At most `rate_hz` takes a second on average, `burst` at once; `take()` says whether one more fits now.

    Thread-safe: zenoh's and rospy's callbacks may take from one bucket on several threads.

    Args:
        rate_hz: takes a second, on average.
        burst: takes allowed back to back after a quiet spell (the bucket starts full).
        clock: seconds, monotonic (tests may pass their own).
    """

    def __init__(self, rate_hz: float, burst: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate_hz = rate_hz
        self.burst = float(burst)
        self._clock = clock
        self._tokens = float(burst)
        self._at = clock()
        self._lock = threading.Lock()

    def take(self) -> bool:
        with self._lock:
            now = self._clock()
            self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate_hz)
            self._at = now
            if self._tokens >= 1.0:
                self._tokens -= 1.0
                return True
            return False
