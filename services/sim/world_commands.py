"""Every robot's motor commands in a world, taken on one thread.

A robot alone has a command thread of its own (service.py `_drain_commands`), which sleeps in zenoh's
ring until a command comes. A world of 32 robots commanded at 100 Hz had 32 such threads, each waking
100 times a second to take the GIL for one command: their waits for the GIL (CPython makes a waiting
thread ask for it again every switch interval, 0.2 ms in the sim) cost more CPU than the commands
themselves, and the loop thread had to share the GIL with all of them. Here one thread empties every
robot's ring each COMMAND_BATCH_PERIOD_S (2 ms, one physics step: when a robot alone takes its commands
too) and applies the newest command of each source per robot, shedding the rest unread, as a robot
alone does. An empty take costs about 0.1 us a robot.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence

import zenoh

from zensim.common.logs import RateLimitedLog

from .service import COMMAND_BATCH_PERIOD_S, SimService, source_of

logger = logging.getLogger("zensim.sim")


class WorldCommands:
    """Takes the commands of every robot of a world on one thread, until closed."""

    def __init__(self, robots: Sequence[SimService]) -> None:
        self._robots = tuple(robots)
        self._stop = threading.Event()
        self._fail_log = RateLimitedLog(logger)
        self._thread = threading.Thread(target=self._run, name="world-commands", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        # Latest wins at the physics step, per robot and source (service.py `_drain_commands` says why).
        pending: dict[tuple[int, object], zenoh.Sample] = {}
        rings = [robot.commands.handler for robot in self._robots]
        next_take = time.monotonic()
        while not self._stop.is_set():
            try:
                for index, (robot, ring) in enumerate(zip(self._robots, rings)):
                    sample = ring.try_recv()
                    while sample is not None:
                        key = (index, source_of(sample))
                        if pending.pop(key, None) is not None:
                            robot.shed_commands += 1  # this thread is its one writer
                        pending[key] = sample
                        sample = ring.try_recv()
            except zenoh.ZError:  # undeclared at shutdown
                return
            for (index, _source), sample in pending.items():
                try:
                    self._robots[index].on_command(sample)
                except Exception:  # one robot's failure must not stop every robot's commands
                    self._fail_log.exception("taking a command failed")
            pending.clear()
            next_take += COMMAND_BATCH_PERIOD_S
            now = time.monotonic()
            if next_take < now:  # late (a loaded machine): take again at once, then every period from now
                next_take = now
            self._stop.wait(next_take - now)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
