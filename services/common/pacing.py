"""Wall-clock pacing of a simulation loop at a target real-time factor.

The schedule is absolute: step k is due at `origin + k * dt / rtf`, so sleep
overshoot never accumulates into drift (a loop that sleeps `dt - elapsed`
never catches up). When the loop falls far behind (a long pause, a rebuild, a
stalled machine) the debt is dropped and the schedule restarts from now,
instead of running flat out for seconds to catch up.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Final

import numpy as np

GIL_SWITCH_INTERVAL_S: Final = 0.0002
"""Longest a thread that wakes up waits for the GIL while another holds it (CPython's default: 5 ms).

Zenoh callback threads take the GIL for a few microseconds per sample; under a flood they take it back
to back, and CPython hands it to a waiting thread only after the switch interval: a loop waking every
2 ms step (the sim's physics, the Unitree adapter's DDS thread) would then wait up to 5 ms each time.
Each such service calls `sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)` at start."""


class Pacer:
    """Decides when the next fixed-size step of sim time may run.

    Args:
        step_s: sim time one step advances, s.
        rtf: target real-time factor; 0 means as fast as possible.
        max_debt_s: wall time behind schedule after which the schedule restarts.
    """

    def __init__(self, step_s: float, rtf: float, max_debt_s: float = 0.1) -> None:
        self.step_s = step_s
        self.rtf = rtf
        self.max_debt_s = max_debt_s
        self.resyncs = 0
        self._lateness_s: deque[float] = deque(maxlen=5000)
        self.restart()

    def restart(self) -> None:
        """Restart the schedule from now (after a pause, a reset or a rebuild)."""
        self._origin = time.perf_counter()
        self._steps = 0

    def wait(self) -> None:
        """Sleep until the next step is due; records how late it starts."""
        if self.rtf <= 0:
            return
        due = self._origin + self._steps * self.step_s / self.rtf
        now = time.perf_counter()
        if due - now > 0:
            time.sleep(due - now)
            now = time.perf_counter()
        lateness = now - due
        if lateness > self.max_debt_s:
            self.resyncs += 1
            self.restart()
            lateness = 0.0
        self._lateness_s.append(lateness)

    def stepped(self, n: int = 1) -> None:
        """Count `n` steps as done."""
        self._steps += n

    def jitter_p99_s(self) -> float:
        """99th percentile of step start lateness since the last call, s (then forgets)."""
        if not self._lateness_s:
            return 0.0
        value = float(np.percentile(np.fromiter(self._lateness_s, float), 99))
        self._lateness_s.clear()
        return value
