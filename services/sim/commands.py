"""Every robot's motor commands, taken on one thread: the one command intake of the sim.

Commands reach each robot through a small ring kept by zenoh (in Rust, robot_endpoint.py): when a flood
outruns this thread, the oldest samples are dropped there, before they cost the GIL anything. This
thread empties the rings and hands each robot the newest command of each source at most once every
COMMAND_BATCH_PERIOD_S (one 2 ms physics step of the G1), shedding the older ones unread and counting
them (`shed_commands`): latest wins at the physics step, so a command with a newer one from the same
source behind it would be overwritten before any step saw it. A flood so costs at most one decode per
source and take (500 a second), and a good client's command is applied within 2 steps.

One thread for every robot of a world, not one per robot: 32 threads waking 100 times a second each to
take the GIL for one command cost more CPU than the commands themselves (their waits for the GIL:
CPython makes a waiting thread ask again every switch interval, 0.2 ms in the sim). A robot alone's
thread sleeps in zenoh's ring until a command comes, so an idle robot's first command is taken at once.

Under the lockstep clock of a robot alone every command advances, in arrival order: none is shed.

A command put on a wildcard (`zensim/*/cmd/motors`) reaches every robot of a world at once: it is refused,
never applied, and shed like the rest (the newest of a take refused and counted, the older ones shed
unread), so a wildcard flood costs each robot at most one refusal per take.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence

import zenoh

from zensim.common.logs import RateLimitedLog

logger = logging.getLogger("zensim.sim")

COMMAND_BATCH_PERIOD_S = 0.002
"""Shortest wall time between two takes of commands (one 2 ms physics step of the G1).

Each take decodes only the newest sample of each source and sheds the rest unread, so a flood from
one source costs at most one decode per take (500 a second) however fast it comes, and a command
waits at most this long plus one take's work before it is applied: within 2 physics steps. (1 ms
takes cost the command thread ~13 % of a core under a 10 kHz flood, 2 ms ~8 %, measured side by side.)"""
WILDCARD = "wildcard"
"""The one 'source' of every sample put on a wildcard key (whoever sent it): refused, never applied."""
COMMAND_POLL_S = 0.0005
"""How often a robot alone's command thread empties zenoh's ring while it waits for the next take (5
samples of a 10 kHz flood: few enough that the ring holds on to no receive buffers)."""


def source_of(sample: zenoh.Sample) -> object:
    """Who sent a sample: the publisher's id when it sets zenoh's source info, else None (one anonymous source)."""
    info = sample.source_info
    if info is None:
        return None
    source = info.source_id
    return (str(source.zid), source.eid)


class CommandIntake:
    """Takes every robot's command samples on one thread, until closed.

    Args:
        rings: each robot's ring (the handler of its cmd/motors subscriber), in order.
        keys: each robot's cmd/motors key: a sample put on any other key expression (a wildcard) is refused.
        take: decodes, checks and applies one sample of robot `index` (on this thread).
        refuse: refuses one sample of robot `index` put on a wildcard (counted, logged at a bounded rate).
        shed: counts one sample of robot `index` shed unread (this thread is the counter's one writer).
        every_sample: take every sample in arrival order, shedding none (a robot alone under lockstep).
    """

    def __init__(self, rings: Sequence[zenoh.handlers.Handler[zenoh.Sample]], keys: Sequence[str],
                 take: Callable[[int, zenoh.Sample], None], refuse: Callable[[int, zenoh.Sample], None],
                 shed: Callable[[int], None], every_sample: bool = False) -> None:
        self._rings = tuple(rings)
        self._keys = tuple(keys)
        self._take = take
        self._refuse = refuse
        self._shed = shed
        self._every_sample = every_sample
        self._stop = threading.Event()
        self._fail_log = RateLimitedLog(logger)
        self._thread = threading.Thread(target=self._run, name="sim-commands", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        # recv() on the handler, not the subscriber: undeclaring a subscriber that another thread is
        # blocked in is refused ("Already borrowed"); the handler's recv just ends with ZError.
        # Samples leave zenoh's ring at once (a sample kept there keeps its receive buffer alive: the RSS
        # grew by 20 MB under a flood when the ring was left to fill between takes); only the newest of
        # each source waits here, for the next take.
        pending: dict[tuple[int, object], zenoh.Sample] = {}
        alone = len(self._rings) == 1
        wait_s = COMMAND_POLL_S if alone else COMMAND_BATCH_PERIOD_S
        next_take = 0.0
        while not self._stop.is_set():
            try:
                for index, (ring, own_key) in enumerate(zip(self._rings, self._keys)):
                    # A robot alone sleeps in its ring while nothing waits here: its first command comes at once.
                    sample = ring.recv() if alone and not pending else ring.try_recv()
                    while sample is not None:
                        exact = str(sample.key_expr) == own_key
                        if self._every_sample:
                            self._apply(index, sample, exact)
                        else:
                            key = (index, source_of(sample) if exact else WILDCARD)
                            if pending.pop(key, None) is not None:  # re-inserted: keeps arrival order
                                self._shed(index)
                            pending[key] = sample
                        sample = ring.try_recv()
            except zenoh.ZError:  # undeclared at shutdown
                return
            if alone and not pending:
                continue
            now = time.monotonic()
            if now < next_take or not pending:
                self._stop.wait(min(next_take - now, wait_s) if pending else wait_s)
                continue
            next_take = max(next_take + COMMAND_BATCH_PERIOD_S, now) if not alone else now + COMMAND_BATCH_PERIOD_S
            for (index, source), sample in pending.items():
                self._apply(index, sample, source != WILDCARD)
            pending.clear()

    def _apply(self, index: int, sample: zenoh.Sample, exact: bool) -> None:
        try:
            if exact:
                self._take(index, sample)
            else:
                self._refuse(index, sample)
        except Exception:  # one robot's failure must not stop every robot's commands
            self._fail_log.exception("taking a command failed")

    def close(self) -> None:
        """End the thread (the rings' subscribers are undeclared after: a robot alone's recv ends then)."""
        self._stop.set()

    def join(self) -> None:
        self._thread.join(1.0)
