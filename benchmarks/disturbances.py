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

from harness import module_at
from step_cases import arguments, print_table, settled, time_rounds
from zensim.schemas import BandRequest, PushRequest
from zensim.sim.world import World

CASES = ("none", "held force", "push", "band", "push+band")
HOWS = ("step", "advance")


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
    args = arguments(__doc__, before="services/sim/disturbances.py")
    worlds = {case: settled() for case in CASES}
    if args.before:
        before = module_at(args.before, "services/sim/disturbances.py")

        def old_disturbances(world: World) -> None:
            sim = world.robots[0]
            sim.disturbances = before.Disturbances(sim.robot, world.data)

        worlds.update({f"{case}@{args.before}": settled(old_disturbances) for case in CASES
                       if case not in ("none", "held force")})

    def run(world: World, how: str) -> int:
        if how == "step":
            for _ in range(args.steps):
                world.step(1)
        else:
            for _ in range(args.steps // 10):
                world.step(10, held=True)
        return args.steps

    times = time_rounds(worlds, HOWS, args.rounds, lambda world, case: disturb(world, case.split("@")[0]), run)
    print(f"{args.rounds} rounds of {args.steps} steps; CPU us per physics step, median (ratio to none)")
    print_table(times, list(worlds), HOWS)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
