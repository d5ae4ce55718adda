"""What randomisation at reset costs (issue 29 item 4): a reset, and a command landing, nominal vs a variant.

    .venv/bin/python benchmarks/variants.py [--rounds 15] [--n 200]

The sim's own World of the G1 floating (services/sim/world.py). Each round times, cases interleaved:

  reset     Simulation.reset with no variant, then with a variant of every factor (friction, masses,
            centres of mass, motor strength: mj_setConst on scratch data), n of each
  command   a whole-robot command accepted and one step run (the targets land in the actuators: a variant's
            motor strength multiplies them), n of each, nominal and with a variant

Time is the thread's CPU time (time.thread_time), median over rounds, per reset or per command + step.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

from zensim.robots import robot_files
from zensim.schemas import MotorCommand, Randomize, ResetRequest
from zensim.sim.physics import Limits
from zensim.sim.world import World

VARIANT = Randomize(seed=7, friction=(0.5, 1.5), mass=(0.8, 1.2), com_offset_m=0.02, motor_strength=(0.7, 1.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--n", type=int, default=200)
    args = parser.parse_args()
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    (sim,) = world.robots
    q = sim.robot.default_q
    commands = [MotorCommand(q=(q + 0.001 * (k % 7)).tolist()) for k in range(args.n)]
    times: dict[str, list[float]] = {name: [] for name in ("reset nominal", "reset variant", "command nominal",
                                                            "command variant")}

    def timed(name: str, work: Callable[[int], object]) -> None:
        start = time.thread_time()
        for k in range(args.n):
            work(k)
        times[name].append((time.thread_time() - start) / args.n * 1e6)

    def command(k: int) -> None:
        sim.accept_command(commands[k])
        world.step(1)

    for _ in range(args.rounds):
        timed("reset nominal", lambda k: sim.reset(ResetRequest()))
        timed("reset variant", lambda k: sim.reset(ResetRequest(randomize=VARIANT)))
        sim.reset()
        timed("command nominal", command)
        sim.reset(ResetRequest(randomize=VARIANT))
        timed("command variant", command)
    base = {"reset": statistics.median(times["reset nominal"]), "command": statistics.median(times["command nominal"])}
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:16s} {median:9.1f} us  x{median / base[name.split()[0]]:.2f}")


if __name__ == "__main__":
    main()
