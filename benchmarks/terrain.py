"""Step time of the G1 with terrain against the flat floor, side by side (issue 29: "< 10 % of step time").

    .venv/bin/python benchmarks/terrain.py [--steps 2000] [--rounds 15] [--cases flat,slope,...]

Each case is the sim's own World of one G1 (services/sim/world.py: the step the service runs, mj_step2 +
mj_step1 with the held targets), floating and holding its default pose on its gains, built once and settled
for 1 s; every round times `--steps` steps of each case in turn (cases interleaved, so the machine's load
falls on all of them alike), from the same settled state each round. Time is the thread's CPU time
(time.thread_time): on a shared machine the wall clock also counts the time other processes held the core,
which swamps a 10 % difference. Medians over rounds, and each case's ratio to flat (and the ratio of the
fastest rounds, `min`, the least disturbed by the machine's other work).

Where the time goes, from MuJoCo's own profiler (mjData.timer over the timed steps): broad and narrow phase of
the collision pass, making the constraints (Jacobians of every contact row) and solving them, each as its share
of MuJoCo's whole step timer times the CPU time per step (the timers read the wall clock, which on a loaded
machine counts waiting too: their shares hold, their sums do not); with the contacts (ncon) and constraint rows
(nefc) at the last step.

Cases:
  flat       the flat floor (the baseline)
  course     a course beside the robot (slope, two flights of stairs, a 4 x 4 m rough patch at 5 cm, stepping
             stones, boxes): the terrain is in the model, the robot stands on the floor next to it
  platform   the robot stands on a box (its feet touch the terrain instead of the floor)
  stairs     the robot stands on a stair's tread (the second of a flight of 0.12 m steps, 0.3 m deep)
  slope      the robot stands across a 3 degree incline (its feet on a convex mesh)
  rough      the robot stands on rough ground (amplitude 1 cm, 5 cm cells): its feet touch the height field
  rough-10   the same with 10 cm cells (fewer cells under each foot: fewer contacts)
  rough-fine the same with 2 cm cells

`--before REV` adds each case again with the terrain put into the model as robots/terrain.py's add_to_spec did
at the git revision REV (loaded from `git show`), in the same rounds: before and after side by side.

Results go to stdout; docs/benchmarks.md keeps the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import mujoco

from harness import module_at
from zensim.robots import robot_files
from zensim.robots import terrain as terrain_module
from zensim.robots.terrain import terrain_from_table
from zensim.schemas import MotorCommand
from zensim.schemas.messages import Terrain
from zensim.sim.physics import Limits
from zensim.sim.world import World

AROUND = [
    {"type": "slope", "angle_deg": 10, "length_m": 3, "width_m": 2, "top_m": 1, "at": [2, 0]},
    {"type": "stairs", "step_height_m": 0.12, "step_depth_m": 0.3, "count": 6, "at": [0, 1.5], "direction_deg": 90},
    {"type": "stairs", "step_height_m": 0.12, "step_depth_m": 0.3, "count": 6, "way": "down", "at": [0, -1.5],
     "direction_deg": -90},
    {"type": "rough", "size_m": [4, 4], "amplitude_m": 0.05, "cell_m": 0.05, "seed": 1, "at": [-3.5, 0]},
    {"type": "stones", "rows": 6, "columns": 2, "at": [6, 2]},
    {"type": "box", "size_m": [1, 1, 0.2], "pos": [6, -2, 0.1]},
    {"type": "box", "size_m": [0.5, 0.5, 0.5], "pos": [-1.5, 2.5, 0.25], "rpy_deg": [0, 0, 30]},
]


def _rough(cell_m: float) -> Terrain:
    return terrain_from_table({"features": [
        {"type": "rough", "size_m": [2, 2], "amplitude_m": 0.01, "cell_m": cell_m, "seed": 3}]})


CASES: dict[str, Terrain | None] = {
    "flat": None,
    "course": terrain_from_table({"features": AROUND}),
    "platform": terrain_from_table({"features": [{"type": "box", "size_m": [1, 1, 0.3], "pos": [0, 0, 0.15]}]}),
    # The robot at x = 0 stands on the second tread, x in [-0.15, 0.15] (0.24 m up), its feet within it.
    "stairs": terrain_from_table({"features": [
        {"type": "stairs", "step_height_m": 0.12, "step_depth_m": 0.3, "count": 4, "at": [-0.45, 0]}]}),
    # Across the incline: holding its flat-ground pose with no balance controller, the G1 stands on 3 degrees
    # across it (and 2 facing up it); it falls over from 3 degrees facing up it, and 5 across it.
    "slope": terrain_from_table({"features": [{"type": "slope", "angle_deg": 3, "length_m": 3, "width_m": 3,
                                               "top_m": 1, "at": [0, -1.5], "direction_deg": 90}]}),
    "rough": _rough(0.05),
    "rough-10": _rough(0.1),
    "rough-fine": _rough(0.02),
}
SETTLE_S = 1.0
"""Sim time each case stands before it is timed: the drop from the spawn height is over."""
STAGES = {
    "broad": mujoco.mjtTimer.mjTIMER_COL_BROAD,
    "narrow": mujoco.mjtTimer.mjTIMER_COL_NARROW,
    "make": mujoco.mjtTimer.mjTIMER_POS_MAKE,
    "solve": mujoco.mjtTimer.mjTIMER_CONSTRAINT,
}
"""MuJoCo's profiler stages reported (mjData.timer): collision broad and narrow phase, constraint making, solver."""


def terrain_at(rev: str) -> ModuleType:
    """robots/terrain.py as it was at git revision `rev`, imported as a module of its own."""
    return module_at(rev, "robots/terrain.py")


@contextlib.contextmanager
def building_with(module: ModuleType | None) -> Iterator[None]:
    """Models built meanwhile get their terrain from `module`'s add_to_spec (None: the current one)."""
    current = terrain_module.add_to_spec
    if module is not None:
        terrain_module.add_to_spec = module.add_to_spec
    try:
        yield
    finally:
        terrain_module.add_to_spec = current


def settled(terrain: Terrain | None) -> tuple[World, mujoco.MjData]:
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9, terrain=terrain)
    (sim,) = world.robots
    sim.accept_command(MotorCommand(q=sim.robot.default_q.tolist()))  # held throughout (no watchdog: 1e9 s)
    world.step(int(SETTLE_S / world.timestep_s))
    assert not world.fallen(world.take([0]))[0], "the robot fell while settling: the case measures nothing useful"
    snapshot = mujoco.MjData(world.model)
    mujoco.mj_copyData(snapshot, world.model, world.data)
    return world, snapshot


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: " + ", ".join(CASES))
    parser.add_argument("--before", metavar="REV", help="also build each case with robots/terrain.py of REV")
    args = parser.parse_args()
    names = ["flat", *[name for name in args.cases.split(",") if name != "flat"]]
    worlds = {name: settled(CASES[name]) for name in names}
    if args.before:
        before = terrain_at(args.before)
        with building_with(before):
            worlds.update({f"{name}@{args.before}": settled(CASES[name]) for name in names if name != "flat"})
        names = list(worlds)
    times: dict[str, list[float]] = {name: [] for name in names}
    stages: dict[str, dict[str, list[float]]] = {name: {stage: [] for stage in STAGES} for name in names}
    contacts: dict[str, tuple[int, int]] = {}
    for _ in range(args.rounds):
        for name, (world, snapshot) in worlds.items():
            mujoco.mj_copyData(world.data, world.model, snapshot)
            for timer in world.data.timer:
                timer.duration, timer.number = 0.0, 0
            start = time.thread_time()
            world.step(args.steps)
            cpu = (time.thread_time() - start) / args.steps
            times[name].append(cpu)
            whole = world.data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
            for stage, which in STAGES.items():
                stages[name][stage].append(world.data.timer[which].duration / whole * cpu)
            contacts[name] = (int(world.data.ncon), int(world.data.nefc))
            assert not world.fallen(world.take([0]))[0], f"{name}: the robot fell while timed"
    flat = statistics.median(times["flat"])
    print(f"{args.rounds} rounds of {args.steps} steps; CPU us per physics step, median; MuJoCo's stages (us per step)")
    width = max(map(len, names))
    print(f"{'case':<{width}} {'geoms':>5} {'ncon':>4} {'nefc':>4} {'us/step':>8} {'vs flat':>7} {'min':>6} "
          + " ".join(f"{stage:>6}" for stage in STAGES))
    for name, (world, _) in worlds.items():
        median = statistics.median(times[name])
        print(f"{name:<{width}} {world.model.ngeom:>5} {contacts[name][0]:>4} {contacts[name][1]:>4} {median * 1e6:>8.1f} "
              f"{median / flat:>7.3f} {min(times[name]) / min(times['flat']):>6.3f} "
              + " ".join(f"{statistics.median(stages[name][stage]) * 1e6:>6.1f}" for stage in STAGES))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
