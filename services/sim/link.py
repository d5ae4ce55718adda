"""Link faults of one robot: its motor commands delayed by whole physics steps, some dropped. No network.

The link sits between the sim's checks and the actuators (physics.py): a command that passes the checks
enters it; `drop_probability` loses it there (counted, never applied), `command_delay_steps` k holds it until
the step k steps after the one it was accepted before: accepted when the robot has taken s steps, it is
first applied by step s + k (k = 0: step s, the next, as without the fault). So under lockstep with one
step per advance, its first effect shows k states after the one it would show in without the delay.

The link keeps order (a command never overtakes an older one, even when the delay was just shortened), and a
reset empties it (a new episode: the commands in flight are lost, the robot holds its reset pose). Commands
already in flight when the fault is set or cleared keep the step they were due at.

Determinism: one uniform draw per command accepted while `drop_probability` > 0, from a PCG64 generator
seeded at `set` with the request's seed (a stream of its own: the sensor noise's draws, on another thread,
do not move it). Under lockstep commands arrive in a fixed order, so the same seed and commands drop the same
ones.

Threads: `send` runs on whichever thread accepts a command, `due` on the thread that steps; the caller
(Simulation) holds its command lock for both.
"""

from __future__ import annotations

from collections import deque
from typing import Generic, Literal, TypeVar

import numpy as np

from zensim.schemas import LinkFaults

T = TypeVar("T")
Sent = Literal["now", "held", "dropped"]

DROP_STREAM = 1
"""Mixed into the seed of the drops' generator, so that it is not the sensor noise's (faults.py) sequence."""


class Link(Generic[T]):
    """The commands in flight to one robot, and what the link fault does to them."""

    def __init__(self) -> None:
        self.dropped = 0
        """Commands dropped since start."""
        self._delay = 0
        self._drop = 0.0
        self._rng = np.random.Generator(np.random.PCG64())
        self._in_flight: deque[tuple[int, T]] = deque()
        """(the step a command is due at, the command), oldest first; due steps never decrease."""

    def set(self, faults: LinkFaults | None, seed: int) -> None:
        """Make `faults` the link's (None: a perfect link); the drops start over from `seed`."""
        self._delay = 0 if faults is None else faults.command_delay_steps
        self._drop = 0.0 if faults is None else faults.drop_probability
        self._rng = np.random.Generator(np.random.PCG64([seed, DROP_STREAM]))

    def send(self, command: T, step: int) -> Sent:
        """Put `command`, accepted when the robot has taken `step` steps, on the link: `dropped` (never to be
        applied), `held` (in flight: `due` gives it at its step), or `now` (no delay and nothing in flight ahead
        of it: the caller applies it at once, as without the fault)."""
        if self._drop > 0.0 and self._rng.random() < self._drop:
            self.dropped += 1
            return "dropped"
        if not self._delay and not self._in_flight:
            return "now"
        due = step + self._delay
        if self._in_flight:  # order kept: never due before a command ahead of it
            due = max(due, self._in_flight[-1][0])
        self._in_flight.append((due, command))
        return "held"

    def busy(self) -> bool:
        """Whether commands are in flight (any thread: a read of the deque's length)."""
        return bool(self._in_flight)

    def due(self, step: int) -> T | None:
        """The newest command due by step `step` (those before it are overwritten by it unseen), taken off the
        link; None when none is due."""
        newest = None
        in_flight = self._in_flight
        while in_flight and in_flight[0][0] <= step:
            newest = in_flight.popleft()[1]
        return newest

    def empty(self) -> None:
        """Lose every command in flight (a reset)."""
        self._in_flight.clear()
