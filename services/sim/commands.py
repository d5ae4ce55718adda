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

A sender cannot buy more decodes by claiming more sources (zenoh's source info is what the sender says it
is: 64 publishers of one client are 64 sources): each robot decodes at most MAX_DECODES_PER_TAKE commands
per take, however many sources wait (`Turns`): the source served least recently first, one whose last
command was refused after the others, the rest shed unread. So a flood costs a robot at most 2000 decodes
a second whatever it claims, and a client's steady stream keeps its turn: with 64 flooding sources and a
budget of 4, every source is served about 30 times a second at the least, a 100 Hz controller every time
it sends (it waited longer than the flooders since its last turn).

Nor can a sender starve another by claiming its source (any subscriber reads a client's zenoh source id
off its samples and can put garbage under it): newest-wins would let each garbage sample shed the good
command before it. A source contested lately (both a command accepted and one refused in the last
SUSPECT_TAKES takes, `Turns.contested`: garbage under a good client's id) does not keep its newest sample
alone but a uniform sample of SUSPECT_KEEP of those that came (`Candidates`, a reservoir the flood cannot
aim at); its turn screens them newest first by a decode alone until one is taken, within CHECK_BUDGET_S of
the thread's CPU per take for the whole intake. A source of garbage alone keeps newest-wins: it has no
good command to find, and a second look would only spend the sim's time. Beside a 10 kHz garbage flood
claiming a 100 Hz client's id that client's commands so keep applying (command age p50 ~25 ms, was ~100;
docs/benchmarks.md).

A command put on a wildcard (`zensim/*/cmd/motors`) reaches every robot of a world at once: it is refused,
never applied, and shed like the rest (the newest of a take refused and counted, the older ones shed
unread), so a wildcard flood costs each robot at most one refusal per take.
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections import defaultdict
from collections.abc import Sequence
from typing import Generic, Protocol, TypeVar

import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.schemas import Keys

logger = logging.getLogger("zensim.sim")

COMMAND_BATCH_PERIOD_S = 0.002
"""Shortest wall time between two takes of commands (one 2 ms physics step of the G1).

Each take decodes only the newest sample of each source and sheds the rest unread, so a flood from
one source costs at most one decode per take (500 a second) however fast it comes, and a command
waits at most this long plus one take's work before it is applied: within 2 physics steps. (1 ms
takes cost the command thread ~13 % of a core under a 10 kHz flood, 2 ms ~8 %, measured side by side.)"""
MAX_DECODES_PER_TAKE = 4
"""Commands a robot decodes per take at most, whatever the number of sources waiting (the rest are shed)."""
REFUSED_PENALTY_TAKES = 50
"""A source whose command was refused waits this many takes (100 ms) behind the others for its next turn."""
SUSPECT_TAKES = 500
"""Takes (about a second) a command accepted, or one refused, counts towards a source's being contested."""
SUSPECT_KEEP = 8
"""Samples of a contested source kept for its turn (a uniform sample of those that came since the last take)."""
CHECK_BUDGET_S = 0.0001
"""CPU time per take the intake thread spends on contested sources' older samples (5 % of a take period;
a source's newest sample is always tried): garbage fails its decode in ~3 us, a well-formed command in
~10-40 us. The thread's own CPU time, not the wall clock: on a loaded machine a wall-clock budget ran out
while the thread was not even running."""
MAX_SOURCES = 1024
"""Sources a robot remembers the turns of (the least recently seen is forgotten first)."""
WILDCARD = "wildcard"
"""The one 'source' of every sample put on a wildcard key (whoever sent it): refused, never applied."""
T = TypeVar("T")
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


class Turns:
    """Whose command one robot decodes when more sources wait than its budget (pure: no zenoh, no clock).

    A source's turn is the take from which it may be served again: first seen, that take; served, the
    next take; refused, REFUSED_PENALTY_TAKES later. The earliest turns go first (the source that waited
    longest); equal turns in arrival order. A fresh source so never goes before one that waited longer.
    """

    def __init__(self, budget: int = MAX_DECODES_PER_TAKE) -> None:
        self.budget = budget
        self.take = 0
        self._turn: dict[object, int] = {}
        self._accepted: dict[object, int] = {}
        """The take until which a source counts as having had a command accepted lately."""
        self._refused: dict[object, int] = {}
        """The take until which a source counts as having had a command refused lately."""

    def choose(self, sources: Sequence[object]) -> tuple[list[int], list[int]]:
        """At the start of a take: the positions in `sources` (arrival order) to decode, and those to shed."""
        self.take += 1
        if len(sources) <= self.budget:
            return list(range(len(sources))), []
        for source in sources:
            if source not in self._turn:
                self._remember(source, self.take)
        order = sorted(range(len(sources)), key=lambda i: self._turn[sources[i]])  # stable: arrival order
        return order[:self.budget], order[self.budget:]

    def served(self, source: object, accepted: bool, refused: bool | None = None) -> None:
        """A source's turn ended: a command accepted (its next turn is the next take) or none (later).

        `refused` (default: not accepted): one of its commands was refused (see `contested`)."""
        self._remember(source, self.take + (1 if accepted else REFUSED_PENALTY_TAKES))
        if refused is None:
            refused = not accepted
        if accepted:
            self._until(self._accepted, source)
        if refused:
            self._until(self._refused, source)

    def contested(self, source: object) -> bool:
        """Whether `source` had a command accepted and one refused in the last SUSPECT_TAKES takes: garbage
        under a good client's id (a source of garbage alone gains nothing from a second look)."""
        return min(self._refused.get(source, -1), self._accepted.get(source, -1)) >= self.take

    def _until(self, marks: dict[object, int], source: object) -> None:
        marks.pop(source, None)  # re-inserted last: the least recently marked is forgotten first
        marks[source] = self.take + SUSPECT_TAKES
        if len(marks) > MAX_SOURCES:
            del marks[next(iter(marks))]

    def _remember(self, source: object, turn: int) -> None:
        self._turn.pop(source, None)  # re-inserted last: the dict's order is the order sources were last seen
        self._turn[source] = turn
        if len(self._turn) > MAX_SOURCES:
            del self._turn[next(iter(self._turn))]


class Candidates(Generic[T]):
    """The samples of one source waiting for the next take (pure).

    `keep` 1: the newest only (latest wins). More: a uniform sample of `keep` of all that came (reservoir
    sampling, so which survive a flood cannot be aimed at), tried newest first.
    """

    def __init__(self, keep: int, rng: random.Random) -> None:
        self._keep = keep
        self._rng = rng
        self._seen = 0
        self._kept: list[tuple[int, T]] = []

    def add(self, sample: T) -> int:
        """Take one arrival; returns how many samples were shed for it (0 or 1)."""
        self._seen += 1
        if len(self._kept) < self._keep:
            self._kept.append((self._seen, sample))
            return 0
        slot = 0 if self._keep == 1 else self._rng.randrange(self._seen)
        if slot < self._keep:
            self._kept[slot] = (self._seen, sample)
        return 1

    def newest_first(self) -> list[T]:
        return [sample for _, sample in sorted(self._kept, key=lambda kept: kept[0], reverse=True)]

    def __len__(self) -> int:
        return len(self._kept)


class CommandTaker(Protocol):
    """What the intake needs of each robot (robot_endpoint.RobotEndpoint); its methods run on the intake's thread."""

    commands: zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]]
    """The robot's cmd/motors subscriber; its handler is the ring."""
    keys: Keys
    """keys.motors: a sample put on any other key expression (a wildcard) is refused."""

    def take_command(self, sample: zenoh.Sample) -> bool:
        """Decode, check and apply one sample; False when refused."""

    def refuse_wildcard(self, sample: zenoh.Sample) -> None:
        """Refuse one sample put on a wildcard (counted, logged at a bounded rate)."""

    def count_shed(self) -> None:
        """Count one sample shed unread (this thread is the counter's one writer)."""

    def undecodable(self, sample: zenoh.Sample) -> str | None:
        """Why a sample does not decode (None: it does), counting nothing: a contested source's older samples
        are screened so (garbage fails in ~3 us) before one is taken."""

    def refuse_undecodable(self, sample: zenoh.Sample, reason: str, count: int) -> None:
        """Count `count` screened samples refused, with the last one and its reason."""


class CommandIntake:
    """Takes every robot's command samples on one thread, until closed.

    Args:
        robots: every robot, in order.
        every_sample: take every sample in arrival order, shedding none (a robot alone under lockstep).
    """

    def __init__(self, robots: Sequence[CommandTaker], every_sample: bool = False) -> None:
        self._robots = tuple(robots)
        self._rings = tuple(robot.commands.handler for robot in robots)
        self._keys = tuple(robot.keys.motors for robot in robots)
        self._every_sample = every_sample
        self._turns = [Turns() for _ in self._rings]
        self._rng = random.Random()  # seeded from the OS: a flooder cannot predict which samples a reservoir keeps
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
        pending: dict[tuple[int, object], Candidates[zenoh.Sample]] = {}
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
                            source = source_of(sample) if exact else WILDCARD
                            key = (index, source)
                            candidates = pending.pop(key, None)  # re-inserted: keeps arrival order
                            if candidates is None:
                                contested = source != WILDCARD and self._turns[index].contested(source)
                                candidates = Candidates(SUSPECT_KEEP if contested else 1, self._rng)
                            if candidates.add(sample):
                                self._robots[index].count_shed()
                            pending[key] = candidates
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
            waiting: dict[int, list[tuple[object, Candidates[zenoh.Sample]]]] = defaultdict(list)
            for (index, source), candidates in pending.items():
                waiting[index].append((source, candidates))
            pending.clear()
            checks_end = time.thread_time() + CHECK_BUDGET_S
            for index, sources in waiting.items():
                turns = self._turns[index]
                chosen, shed = turns.choose([source for source, _ in sources])
                for position in shed:
                    for _ in range(len(sources[position][1])):
                        self._robots[index].count_shed()
                for position in chosen:
                    source, candidates = sources[position]
                    self._serve(index, source, candidates, checks_end)

    def _serve(self, index: int, source: object, candidates: Candidates[zenoh.Sample], checks_end: float) -> None:
        """One source's turn: its samples newest first until one is accepted (the rest shed unread); a
        contested source's older ones only while the take's check budget lasts."""
        robot = self._robots[index]
        accepted = refused = False
        screened: tuple[zenoh.Sample, str] | None = None
        screened_out = 0
        for tried, sample in enumerate(candidates.newest_first()):
            if accepted or (tried and time.thread_time() > checks_end):
                robot.count_shed()
                continue
            reason = robot.undecodable(sample) if tried else None  # the newest goes the whole way at once
            if reason is not None:
                screened, screened_out, refused = (sample, reason), screened_out + 1, True
            elif self._apply(index, sample, source != WILDCARD):
                accepted = True
            else:
                refused = True
        if screened is not None:
            robot.refuse_undecodable(*screened, screened_out)
        self._turns[index].served(source, accepted, refused)

    def _apply(self, index: int, sample: zenoh.Sample, exact: bool) -> bool:
        """Take (or, put on a wildcard, refuse) one sample; True when it was accepted."""
        try:
            if exact:
                return self._robots[index].take_command(sample)
            self._robots[index].refuse_wildcard(sample)
            return False
        except Exception:  # one robot's failure must not stop every robot's commands
            self._fail_log.exception("taking a command failed")
            return False

    def close(self) -> None:
        """End the thread (the rings' subscribers are undeclared after: a robot alone's recv ends then)."""
        self._stop.set()

    def join(self, timeout_s: float = 5.0) -> None:
        """Wait for the thread to end (after `close` and the subscribers' undeclare): its take in progress
        finishes first."""
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            logger.warning("the command thread did not end within %.0f s", timeout_s)
