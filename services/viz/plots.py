"""The plot panel's data: joint position, commanded target and torque over the last seconds of sim time.

Pure logic, no zenoh and no tornado: the service feeds it every joint state and every command it
sees and asks it for what each browser has not had yet.

Each browser picks a few joints (`{"type": "plot", "joints": [...]}`, checked by panel.py) and gets
batches of only those joints, about ten a second, and a next batch only after the previous one was
written: a slow page gets bigger batches, not a queue. Samples are thinned to one per
`MIN_SAMPLE_DT_S` of sim time, so a sim running 50x real time costs the page no more than one in
real time. The page draws with plotly.js (served from the plotly wheel): no axes drawn by hand.

The commanded target of a joint is the newest value for it on cmd/motors (what the sim gets, from the
bridge or a policy) or on state/targets (what the bridge holds), whichever came last.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

WINDOW_S: Final = 10.0
"""Sim time a browser can plot back."""
MIN_SAMPLE_DT_S: Final = 0.01
"""Sim time between kept samples (100 Hz): finer than a page can show in a 10 s window."""
MAX_SAMPLES: Final = int(WINDOW_S / MIN_SAMPLE_DT_S) + 50
MAX_PLOT_JOINTS: Final = 6
"""Joints one page may plot at once."""


@dataclass(frozen=True)
class Sample:
    index: int
    sim_time_s: float
    q: tuple[float, ...]
    tau: tuple[float, ...]
    target: tuple[float | None, ...]


@dataclass
class Subscription:
    """What one browser plots and how far it has been sent."""

    indices: tuple[int, ...]
    names: tuple[str, ...]
    sent_index: int = -1
    busy: bool = False
    epoch: int = -1


@dataclass
class PlotFeed:
    """A ring of thinned joint samples with the commanded targets held at each."""

    joint_names: tuple[str, ...] = ()
    samples: deque[Sample] = field(default_factory=lambda: deque(maxlen=MAX_SAMPLES))
    epoch: int = 0
    """Counts restarts of the timeline (a reset, a new robot): pages clear their plots."""
    _target: list[float | None] = field(default_factory=list)
    _next_index: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def set_joints(self, names: Sequence[str]) -> None:
        """A new robot description: start over with its joints."""
        with self._lock:
            self.joint_names = tuple(names)
            self._target = [None] * len(self.joint_names)
            self.samples.clear()
            self.epoch += 1

    def on_command(self, names: Sequence[str] | None, q: Sequence[float]) -> None:
        """A command (all joints in canonical order when `names` is None, else those named)."""
        with self._lock:
            if names is None:
                if len(q) == len(self._target):
                    self._target = list(q)
                return
            index = {n: i for i, n in enumerate(self.joint_names)}
            for name, value in zip(names, q):
                i = index.get(name)
                if i is not None:
                    self._target[i] = value

    def on_state(self, sim_time_s: float, q: Sequence[float], tau: Sequence[float]) -> None:
        with self._lock:
            if len(q) != len(self.joint_names) or len(tau) != len(q):
                return
            last = self.samples[-1].sim_time_s if self.samples else None
            if last is not None and sim_time_s < last:  # a reset: time starts over
                self.samples.clear()
                self.epoch += 1
            elif last is not None and sim_time_s - last < MIN_SAMPLE_DT_S - 1e-9:
                return
            self._next_index += 1
            self.samples.append(Sample(self._next_index, sim_time_s, tuple(q), tuple(tau), tuple(self._target)))

    def subscribe(self, names: Sequence[str]) -> Subscription:
        index = {n: i for i, n in enumerate(self.joint_names)}
        return Subscription(indices=tuple(index[n] for n in names), names=tuple(names))

    def batch(self, sub: Subscription) -> dict[str, Any] | None:
        """The samples `sub` has not had yet, as the page's JSON message; None when there are none."""
        with self._lock:
            clear = sub.epoch != self.epoch
            if clear:
                sub.epoch, sub.sent_index = self.epoch, -1
            new = [s for s in self.samples if s.index > sub.sent_index]
        if not new and not clear:
            return None
        if new:
            sub.sent_index = new[-1].index
        return {
            "type": "plot",
            "clear": clear,
            "joints": list(sub.names),
            "t": [s.sim_time_s for s in new],
            "q": [[s.q[i] for s in new] for i in sub.indices],
            "target": [[s.target[i] for s in new] for i in sub.indices],
            "tau": [[s.tau[i] for s in new] for i in sub.indices],
        }
