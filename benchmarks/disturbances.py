"""Step time of the G1 with a push or the elastic band acting against none, side by side (issue 29 item 2).

    .venv/bin/python benchmarks/disturbances.py [--steps 2000] [--rounds 15]

Each case is the sim's own World (services/sim/world.py: the step the service runs) of the G1 floating and
holding its default pose on its gains, settled for 1 s. The disturbances are kept small, so that the robot
stands on the same contacts in every case and the figures measure what the disturbances cost, not a
different pose: a push of 20 N on the pelvis that acts throughout, and the band on, 2.2 m long, taut above
the standing robot (a pull of about 12 N). Every round times `--steps` steps of each case in turn (cases
interleaved, so the machine's load falls on all alike), from the same settled state, two ways:

  step      World.step(1) per step: the real-time loop
  advance   World.step(10, held=True) per lockstep advance: undisturbed, MuJoCo runs the 10 steps in one call
            (mj_step nstep); disturbed, they run one by one, the force worked out before each

One more case splits what the band costs: "held force" writes the band's pull at the settled state into
xfrc_applied once and leaves the band off, so MuJoCo applies the same force at every step with no Python per
step and, under lockstep, the advance stays one MuJoCo call. band - held force: working the force out at every
step (and, in an advance, stepping one by one); held force - none: the force itself, in the physics.

Time is the thread's CPU time (time.thread_time); medians over rounds, and each case's ratio to none.
`--before REV` adds each disturbed case again with services/sim/disturbances.py as it was at the git revision
REV (loaded from `git show`, put on the robot in place of the current one), in the same rounds: before and
after side by side, under the same load.
Results go to stdout; docs/benchmarks.md keeps the figures.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import mujoco

from zensim.robots import robot_files
from zensim.schemas import BandRequest, MotorCommand, PushRequest
from zensim.sim.physics import Limits
from zensim.sim.world import World

SETTLE_S = 1.0
CASES = ("none", "held force", "push", "band", "push+band")


def disturbances_at(rev: str) -> ModuleType:
    """services/sim/disturbances.py as it was at git revision `rev`, imported as a module of its own."""
    root = Path(__file__).resolve().parent.parent
    text = subprocess.run(["git", "show", f"{rev}:services/sim/disturbances.py"], cwd=root, check=True,
                          capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "disturbances_before.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("disturbances_before", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def settled(before: ModuleType | None = None) -> tuple[World, mujoco.MjData]:
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    (sim,) = world.robots
    if before is not None:
        sim.disturbances = before.Disturbances(sim.robot, world.data)
    sim.accept_command(MotorCommand(q=sim.robot.default_q.tolist()))
    world.step(int(SETTLE_S / world.timestep_s))
    snapshot = mujoco.MjData(world.model)
    mujoco.mj_copyData(snapshot, world.model, world.data)
    return world, snapshot


def disturb(world: World, case: str) -> None:
    """Put the case's disturbances on (from the settled state: no push acts, the band is off)."""
    disturbances = world.robots[0].disturbances
    disturbances.clear_pushes()
    disturbances.band(BandRequest(verb="on" if "band" in case or case == "held force" else "off", length_m=2.2))
    if case == "held force":  # the band's pull now, held: written once, no Disturbances at any step
        disturbances.apply()
        force = disturbances.band_force
        disturbances.band(BandRequest(verb="off"))
        disturbances.clear_pushes()  # clears the row and forgets it: written again below, nothing clears it then
        world.data.xfrc_applied[world.robots[0].robot.base_body_id, :3] = force
    if "push" in case:
        disturbances.push(PushRequest(direction=(1, 0, 0), magnitude_n=20, duration_s=10))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--before", metavar="REV", help="also run the disturbed cases with disturbances.py of REV")
    args = parser.parse_args()
    cases = {case: settled() for case in CASES}
    if args.before:
        before = disturbances_at(args.before)
        cases.update({f"{case}@{args.before}": settled(before) for case in CASES if case not in ("none", "held force")})
    times: dict[tuple[str, str], list[float]] = {(case, how): [] for case in cases for how in ("step", "advance")}
    for _ in range(args.rounds):
        for how in ("step", "advance"):
            for case, (world, snapshot) in cases.items():
                mujoco.mj_copyData(world.data, world.model, snapshot)
                disturb(world, case.split("@")[0])
                start = time.thread_time()
                if how == "step":
                    for _ in range(args.steps):
                        world.step(1)
                else:
                    for _ in range(args.steps // 10):
                        world.step(10, held=True)
                times[case, how].append((time.thread_time() - start) / args.steps * 1e6)
                assert not world.fallen(world.take([0]))[0], f"{case}: the robot fell; the case measures nothing"
    print(f"{args.rounds} rounds of {args.steps} steps; CPU us per physics step, median (ratio to none)")
    width = max(map(len, cases))
    print(f"{'case':<{width}} {'step':>16} {'advance':>16}")
    for case in cases:
        cells = []
        for how in ("step", "advance"):
            median = statistics.median(times[case, how])
            base = statistics.median(times["none", how])
            cells.append(f"{median:7.1f} ({median / base:4.2f})")
        print(f"{case:<{width}} {cells[0]:>16} {cells[1]:>16}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
