"""Step time of the G1 with terrain against the flat floor, side by side (issue 29: "< 10 % of step time").

    .venv/bin/python benchmarks/terrain.py [--steps 2000] [--rounds 7]

Each case is the sim's own Simulation (services/sim/physics.py: the step the service runs, mj_step2 +
mj_step1 with the held targets), the G1 floating and holding its default pose, built once; every round
times `--steps` steps of each case in turn (cases interleaved, so the machine's load falls on all of them
alike), from the same settled state each round. The median over rounds is reported, and its ratio to flat.
Time is the thread's CPU time (time.thread_time): on a shared machine the wall clock also counts the
time other processes held the core, which swamps a 10 % difference; the wall-clock median is printed too.

Cases:
  flat      the flat floor (the baseline)
  course    a course beside the robot (slope, two flights of stairs, a 4 x 4 m rough patch at 5 cm, stepping
            stones, boxes): the terrain is in the model, the robot stands on the floor next to it
  platform  the robot stands on a box (its feet touch the terrain instead of the floor)
  rough     the robot stands on rough ground (amplitude 1 cm, 5 cm cells): its feet touch the height field
  rough-10  the same with 10 cm cells (fewer cells under each foot: fewer contacts)

Results go to stdout; docs/benchmarks.md keeps the figures.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco

from zensim.robots import robot_files
from zensim.robots.terrain import terrain_from_table
from zensim.schemas.messages import Terrain
from zensim.sim.physics import Limits, Simulation

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
CASES: dict[str, Terrain | None] = {
    "flat": None,
    "course": terrain_from_table({"features": AROUND}),
    "platform": terrain_from_table({"features": [{"type": "box", "size_m": [1, 1, 0.3], "pos": [0, 0, 0.15]}]}),
    "rough": terrain_from_table({"features": [
        {"type": "rough", "size_m": [2, 2], "amplitude_m": 0.01, "cell_m": 0.05, "seed": 3}]}),
    "rough-10": terrain_from_table({"features": [
        {"type": "rough", "size_m": [2, 2], "amplitude_m": 0.01, "cell_m": 0.1, "seed": 3}]}),
}
SETTLE_S = 1.0
"""Sim time each case stands before it is timed: the drop from the spawn height is over."""


def settled(terrain: Terrain | None) -> tuple[Simulation, mujoco.MjData]:
    sim = Simulation(robot_files("g1"), "floating", Limits(max_kp=5000, max_kd=500), 0.5, terrain=terrain)
    sim.watchdog_enabled = False  # the default pose on its gains throughout, as the watchdog holds it
    sim.step(int(SETTLE_S / sim.timestep_s))
    assert not sim.fallen(), "the robot fell while settling: the case measures nothing useful"
    snapshot = mujoco.MjData(sim.robot.model)
    mujoco.mj_copyData(snapshot, sim.robot.model, sim.data)
    return sim, snapshot


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    sims = {name: settled(terrain) for name, terrain in CASES.items()}
    times: dict[str, list[float]] = {name: [] for name in CASES}
    walls: dict[str, list[float]] = {name: [] for name in CASES}
    contacts: dict[str, int] = {}
    for _ in range(args.rounds):
        for name, (sim, snapshot) in sims.items():
            mujoco.mj_copyData(sim.data, sim.robot.model, snapshot)
            start, wall = time.thread_time(), time.perf_counter()
            sim.step(args.steps)
            times[name].append((time.thread_time() - start) / args.steps)
            walls[name].append((time.perf_counter() - wall) / args.steps)
            contacts[name] = int(sim.data.ncon)
            assert not sim.fallen(), f"{name}: the robot fell while timed"
    flat, flat_wall = statistics.median(times["flat"]), statistics.median(walls["flat"])
    print(f"{'case':<10} {'geoms':>6} {'contacts':>8} {'CPU us/step':>12} {'min':>7} {'max':>7} {'vs flat':>8} "
          f"{'wall us/step':>13} {'vs flat':>8}")
    for name, (sim, _) in sims.items():
        median, wall = statistics.median(times[name]), statistics.median(walls[name])
        print(f"{name:<10} {sim.robot.model.ngeom:>6} {contacts[name]:>8} {median * 1e6:>12.1f} "
              f"{min(times[name]) * 1e6:>7.1f} {max(times[name]) * 1e6:>7.1f} {median / flat:>8.3f} "
              f"{wall * 1e6:>13.1f} {wall / flat_wall:>8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
