"""ctl requests that act at a sim time of their own (their `at_s`), kept until the step that starts there. No network.

Why: under lockstep a controller advances the sim while a ctl query travels and waits for the loop thread, so a
push sent "at 3 s" would land at whichever advance the loop reached first, and two runs of one scenario would
differ. A request with `at_s` is checked and accepted at once (its reply says when it will act), kept here, and
carried out by the thread that steps, right before the first step that starts at or after `at_s`: the same step
in every run, whatever the machine's load.

Times become whole steps of the world's count when a request is accepted, so nothing later depends on sums of
floats. Requests due at one step run in the order they were accepted. A reset of a robot drops what it had
waiting (a new episode; the robot's other requests are not the next episode's), a reset of the world's time
drops everything.

Everything here is for the thread holding the engine's physics lock (docs/architecture.md, "Threads").
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from zensim.schemas.messages import MAX_SCHEDULED

NO_STEP = math.inf
"""`Schedule.next_step` while nothing waits."""


class ScheduleError(ValueError):
    """A request that cannot be kept for later: its time has passed, or too many wait."""


@dataclass(order=True)
class Scheduled:
    """One request waiting for its step."""

    step: int
    """The world's step count at which it runs (before that step)."""
    order: int
    """Acceptance order: requests of one step run first come, first served."""
    robot: int = field(compare=False)
    """The index of the robot it belongs to."""
    run: Callable[[], None] = field(compare=False)
    """Carries it out; reports its own failure (a request that no longer fits when its time comes)."""


class Schedule:
    """The waiting requests of every robot of a world, soonest first."""

    def __init__(self) -> None:
        self._heap: list[Scheduled] = []
        self._accepted = 0
        self.next_step: float = NO_STEP
        """The step the soonest request waits for: the world compares its step count with this, one float
        comparison a step, and looks no further while nothing is due."""

    def add(self, robot: int, at_s: float, now_s: float, step: int, timestep_s: float,
            run: Callable[[], None]) -> int:
        """Keep `run` for the first step that starts at or after `at_s`, the world being at `now_s` after `step`
        steps; returns that step's count.

        Raises:
            ScheduleError: `at_s` has passed, or the robot has MAX_SCHEDULED requests waiting.
        """
        if at_s < now_s:
            raise ScheduleError(f"`at_s` {at_s:.6g} s has passed (sim time is {now_s:.6g} s); nothing was done")
        if self.waiting(robot) >= MAX_SCHEDULED:
            raise ScheduleError(f"{MAX_SCHEDULED} requests already wait for their time; nothing was done")
        # The step that starts at or after at_s; a hair of tolerance so that a time read off a state (a sum of
        # floats) names the step it was read at, not the next one.
        due = step + max(0, math.ceil((at_s - now_s) / timestep_s - 1e-6))
        self._accepted += 1
        heapq.heappush(self._heap, Scheduled(due, self._accepted, robot, run))
        self.next_step = self._heap[0].step
        return due

    def run_due(self, step: int) -> None:
        """Carry out every request due at or before step count `step`, in order."""
        heap = self._heap
        while heap and heap[0].step <= step:
            heapq.heappop(heap).run()
        self.next_step = heap[0].step if heap else NO_STEP

    def waiting(self, robot: int) -> int:
        """How many requests of `robot` wait."""
        return sum(1 for item in self._heap if item.robot == robot)

    def drop(self, robot: int | None = None) -> None:
        """Forget what `robot` (None: every robot) has waiting."""
        self._heap = [] if robot is None else [item for item in self._heap if item.robot != robot]
        heapq.heapify(self._heap)
        self.next_step = self._heap[0].step if self._heap else NO_STEP
