"""What the benchmarks that time the G1's step under cases side by side share (disturbances.py, faults.py).

Each case is the sim's own World (services/sim/world.py: the step the service runs) of the G1 floating and
holding its default pose on its gains, settled for SETTLE_S. Every round restores each case to that settled
state, sets the case up and times it, the cases interleaved so that the machine's load falls on all alike;
time is the thread's CPU time (time.thread_time). The table gives medians over rounds and each case's ratio
to the first case (none).

Benchmarks run as scripts (`python benchmarks/<name>.py`), so this folder is on sys.path and
`from step_cases import ...` needs nothing else.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Sequence

import mujoco

from zensim.robots import robot_files
from zensim.schemas import MotorCommand
from zensim.sim.physics import Limits
from zensim.sim.world import World

SETTLE_S = 1.0

Times = dict[tuple[str, str], list[float]]
"""(case, how) -> CPU microseconds per unit (a physics step, a state read), one per round."""


def arguments(doc: str, hows: Sequence[str] = (), before: str = "") -> argparse.Namespace:
    """The command line every step-case benchmark takes: `--steps` per case and round, `--rounds`; with `hows`,
    also `--hows`, the ways to time (a comma-separated subset); with `before` (what it runs at another revision),
    also `--before REV`."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=15)
    if before:
        parser.add_argument("--before", metavar="REV", help=f"also run {before} as it was at git revision REV")
    if hows:
        parser.add_argument("--hows", default=",".join(hows),
                            help=f"what to time, of {', '.join(hows)} (read alone: many reads in little time)")
    args = parser.parse_args()
    if hows and not set(args.hows.split(",")) <= set(hows):
        parser.error(f"--hows: of {', '.join(hows)}; got {args.hows}")
    return args


def settled(prepare: Callable[[World], None] | None = None) -> tuple[World, mujoco.MjData]:
    """A G1 world holding its default pose, settled, and a copy of its settled state to restore; `prepare` runs on
    the new world first (to put another revision's module in place)."""
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    if prepare is not None:
        prepare(world)
    (sim,) = world.robots
    sim.accept_command(MotorCommand(q=sim.robot.default_q.tolist()))
    world.step(int(SETTLE_S / world.timestep_s))
    snapshot = mujoco.MjData(world.model)
    mujoco.mj_copyData(snapshot, world.model, world.data)
    return world, snapshot


def time_rounds(worlds: dict[str, tuple[World, mujoco.MjData]], hows: Sequence[str], rounds: int,
                set_up: Callable[[World, str], None], run: Callable[[World, str], int]) -> Times:
    """Each round, each way (`hows`) of each case in turn, timed from the settled state.

    Args:
        worlds: each case's world and its settled state (`settled()`).
        hows: the ways each case is timed.
        rounds: how many times each is timed.
        set_up: puts a case on a world restored to its settled state (not timed).
        run: runs one way on the world (timed); returns the units it did, to time one unit.

    Returns:
        Each case's and way's CPU microseconds per unit, one per round.

    Raises:
        AssertionError: a case's robot fell (the case would measure a fallen robot, not the case).
    """
    times: Times = {(case, how): [] for case in worlds for how in hows}
    for _ in range(rounds):
        for how in hows:
            for case, (world, snapshot) in worlds.items():
                mujoco.mj_copyData(world.data, world.model, snapshot)
                set_up(world, case)
                start = time.thread_time()
                units = run(world, how)
                times[case, how].append((time.thread_time() - start) / units * 1e6)
                assert not world.fallen(world.take([0]))[0], f"{case}: the robot fell; the case measures nothing"
    return times


def print_table(times: Times, cases: Sequence[str], hows: Sequence[str]) -> None:
    """A row per case: each way's median and, in brackets, its ratio to the first case's."""
    width = max(10, *map(len, cases))
    print(f"{'case':<{width}} " + " ".join(f"{how:>16}" for how in hows))
    for case in cases:
        cells = []
        for how in hows:
            median = statistics.median(times[case, how])
            base = statistics.median(times[cases[0], how])
            cells.append(f"{median:7.1f} ({median / base:4.2f})")
        print(f"{case:<{width}} " + " ".join(f"{cell:>16}" for cell in cells))
