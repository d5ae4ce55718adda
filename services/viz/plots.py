"""The plot panel's data: joint position, commanded target and torque over the last seconds of sim time.

Pure logic, no zenoh and no tornado: the service feeds it every joint state and every command it
sees and asks it for what each browser has not had yet.

Each browser picks a few joints (`{"type": "plot", "joints": [...]}`, checked by panel.py) and gets
batches of only those joints, about ten a second, and a next batch only after the previous one was
written: a slow page gets bigger batches, not a queue. Samples are thinned to one per
`MIN_SAMPLE_DT_S` of sim time, so a sim running 50x real time costs the page no more than one in
real time. The page draws with plotly.js (served from the plotly wheel): no axes drawn by hand.

The commanded target of a joint is placed on the sim-time axis, and each sample gets the target in
effect at its own sim time (looked up when it is sent, so a target that arrives after its states
still lands on them):
- state/applied (AppliedCommand, from a lockstep sim: commands on cmd/motors and ctl/advance alike,
  and from `zensim replay` of such a run) says the sim time it took effect at: exact. While these
  come, they are the only source, as the others carry no sim time.
- cmd/motors (what the sim gets, from the bridge or a policy) and state/targets (what the bridge
  holds, also replayed from a recording) carry none: each takes effect just after the newest state's
  sim time when it arrives, which under a real-time sim is within a state period of the truth.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
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
APPLIED_GRACE_S: Final = 0.1
"""Wall time a sample waits before it is sent while targets come from state/applied: a lockstep sim
publishes an advance's states just before its state/applied, on another key (another zenoh thread
here), so the target of the newest state may be a moment behind it."""


@dataclass(frozen=True)
class Sample:
    index: int
    sim_time_s: float
    q: tuple[float, ...]
    tau: tuple[float, ...]
    arrived: float = 0.0
    """Wall time (monotonic) the state arrived."""


Targets = tuple[float | None, ...]


@dataclass
class TargetTimeline:
    """The whole target vector from each sim time on: change points, sorted by sim time."""

    times: list[float] = field(default_factory=list)
    values: list[Targets] = field(default_factory=list)

    def at(self, sim_time_s: float) -> Targets | None:
        """The targets in effect at `sim_time_s` (None before the first)."""
        i = bisect.bisect_right(self.times, sim_time_s) - 1
        return self.values[i] if i >= 0 else None

    def newest(self) -> Targets | None:
        return self.values[-1] if self.values else None

    def set(self, sim_time_s: float, values: Targets) -> None:
        """`values` from `sim_time_s` on (until the next change point)."""
        i = bisect.bisect_left(self.times, sim_time_s)
        if i < len(self.times) and self.times[i] == sim_time_s:
            self.values[i] = values
        else:
            self.times.insert(i, sim_time_s)
            self.values.insert(i, values)

    def forget_before(self, sim_time_s: float) -> None:
        """Drop change points no sample at or after `sim_time_s` needs (the one in effect then stays)."""
        i = bisect.bisect_right(self.times, sim_time_s) - 1
        if i > 0:
            del self.times[:i], self.values[:i]

    def restart(self) -> None:
        """Time starts over (a reset): the targets held last stay in effect from the new start."""
        last = self.newest()
        self.times, self.values = ([float("-inf")], [last]) if last is not None else ([], [])


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
    _targets: TargetTimeline = field(default_factory=TargetTimeline)
    _timed: bool = False
    """True once state/applied came in this epoch: targets with a sim time; the untimed ones are ignored."""
    _newest_state_s: float = float("-inf")
    _next_index: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock)
    grace_s: float = APPLIED_GRACE_S

    def set_joints(self, names: Sequence[str]) -> None:
        """A new robot description: start over with its joints."""
        with self._lock:
            self.joint_names = tuple(names)
            self._targets = TargetTimeline()
            self._timed = False
            self._newest_state_s = float("-inf")
            self.samples.clear()
            self.epoch += 1

    def on_command(self, names: Sequence[str] | None, q: Sequence[float]) -> None:
        """A command without a sim time (cmd/motors, state/targets): in effect from the newest state on.

        All joints in canonical order when `names` is None, else those named.
        """
        with self._lock:
            if not self._timed:  # just after the newest state: the states that follow show it
                self._merge(math.nextafter(self._newest_state_s, math.inf), names, q)

    def on_applied(self, sim_time_s: float, names: Sequence[str] | None, q: Sequence[float]) -> None:
        """A command the sim applied from `sim_time_s` on (state/applied): placed exactly.

        The state at `sim_time_s` itself came from the command before (AppliedCommand.sim_time_s is
        the time before its steps), so it takes effect just after."""
        with self._lock:
            if not self._timed:  # from now on only these: drop what the untimed ones guessed
                self._timed = True
                self._targets = TargetTimeline()
            self._merge(math.nextafter(sim_time_s, math.inf), names, q)

    def _merge(self, sim_time_s: float, names: Sequence[str] | None, q: Sequence[float]) -> None:
        n = len(self.joint_names)
        before = self._targets.at(sim_time_s) or (None,) * n
        merged: Targets
        if names is None:
            if len(q) != n:
                return
            merged = tuple(q)
        else:
            merged_list: list[float | None] = list(before)
            index = {name: i for i, name in enumerate(self.joint_names)}
            for name, value in zip(names, q):
                i = index.get(name)
                if i is not None:
                    merged_list[i] = value
            merged = tuple(merged_list)  # None: a joint no command has named yet
        self._targets.set(sim_time_s, merged)

    def on_state(self, sim_time_s: float, q: Sequence[float], tau: Sequence[float]) -> None:
        with self._lock:
            if len(q) != len(self.joint_names) or len(tau) != len(q):
                return
            last = self.samples[-1].sim_time_s if self.samples else None
            if sim_time_s < self._newest_state_s:  # a reset: time starts over
                self.samples.clear()
                self._targets.restart()
                self._timed = False
                self.epoch += 1
                last = None
            self._newest_state_s = sim_time_s
            if last is not None and sim_time_s - last < MIN_SAMPLE_DT_S - 1e-9:
                return
            self._next_index += 1
            self.samples.append(Sample(self._next_index, sim_time_s, tuple(q), tuple(tau), time.monotonic()))
            self._targets.forget_before(self.samples[0].sim_time_s)

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
            if self._timed:  # wait for the targets of the newest states (APPLIED_GRACE_S)
                settled = time.monotonic() - self.grace_s
                new = [s for s in new if s.arrived <= settled]
            none = (None,) * len(self.joint_names)
            targets = [self._targets.at(s.sim_time_s) or none for s in new]
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
            "target": [[t[i] for t in targets] for i in sub.indices],
            "tau": [[s.tau[i] for s in new] for i in sub.indices],
        }
