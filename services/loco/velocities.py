"""Velocity commands that hold from a sim time of their own (VelocityCommand.at_s), kept until then. No network.

Why: a command put while a lockstep controller runs is taken at whichever tick it happens to arrive before, so
two runs of one scenario would start walking at different instants. One with `at_s` is kept here and taken at
the first tick at or after `at_s`, the same tick in every run. The controller's ticks are sim time (one per
state under lockstep), so nothing here reads a clock.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

from zensim.schemas import VelocityCommand
from zensim.schemas.messages import MAX_SCHEDULED


@dataclass(order=True)
class _Waiting:
    at_s: float
    order: int
    command: VelocityCommand = field(compare=False)


class ScheduledVelocities:
    """The velocity commands waiting for their `at_s`, soonest first (first come, first served at one time)."""

    def __init__(self) -> None:
        self._waiting: list[_Waiting] = []
        self._accepted = 0

    def __len__(self) -> int:
        return len(self._waiting)

    def add(self, command: VelocityCommand) -> bool:
        """Keep `command` (its `at_s` set) for later; False when MAX_SCHEDULED already wait (it is not kept)."""
        assert command.at_s is not None
        if len(self._waiting) >= MAX_SCHEDULED:
            return False
        self._accepted += 1
        bisect.insort(self._waiting, _Waiting(command.at_s, self._accepted, command))
        return True

    def due(self, now_s: float) -> list[VelocityCommand]:
        """The commands due at `now_s` (their `at_s` at or before it, within a hair: a time read off a state is a
        sum of floats), in order, taken off the list."""
        if not self._waiting or self._waiting[0].at_s > now_s + 1e-9:
            return []
        cut = bisect.bisect_right([w.at_s for w in self._waiting], now_s + 1e-9)
        taken, self._waiting = self._waiting[:cut], self._waiting[cut:]
        return [w.command for w in taken]

    def clear(self) -> None:
        """Forget them all (sim time went back: a new episode)."""
        self._waiting.clear()
