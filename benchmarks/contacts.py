"""What foot contacts (state/contacts) cost: the step and the states at 500 Hz, with and without, side by side.

    .venv/bin/python benchmarks/contacts.py [--steps 2000] [--rounds 11]

Two G1s standing (floating, default pose, settled 1 s), each a World of one as the sim runs it:
  with      the model as the sim builds it: each foot carries its two MuJoCo contact sensors, and the
            state reader reads four messages (JointState, Odometry, Imu, Contacts)
  without   the same model with the foot sensors taken out before compiling: three messages, as before

Per round and case (interleaved, so the machine's load falls on both alike), from the same settled state:
`--steps` steps timed alone (mj_step2 + mj_step1: World.step), then `--steps` steps each followed by a
state, as at `--state-rate-hz 500` (every 2 ms step publishes): World.take, the reader's messages and a
msgpack encode of each (what the sim's publisher puts). Time is the thread's CPU time (time.thread_time):
on a shared machine the wall clock counts other processes' turns. Medians over rounds; docs/benchmarks.md
keeps the figures.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import mujoco
import msgspec

from zensim.robots import builder, robot_files
from zensim.sim.physics import Limits
from zensim.sim.world import World

SETTLE_STEPS = 500


def world(with_contacts: bool) -> World:
    """A settled G1 alone; without contacts: its foot sensors deleted from the spec before the compile."""
    original = builder._prepare

    def without_feet(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 (the builder's own signature)
        prepared = original(*args, **kwargs)
        for foot in prepared.foot_links:
            for suffix in (builder.FOOT_NET_SUFFIX, builder.FOOT_POINTS_SUFFIX):
                prepared.spec.delete(prepared.spec.sensor(foot + suffix))
        prepared.foot_links = ()
        return prepared

    if not with_contacts:
        builder._prepare = without_feet
    try:
        made = World.alone("g1", robot_files("g1"), "floating", Limits(max_kp=5000, max_kd=500), 0.5)
    finally:
        builder._prepare = original
    made.robots[0].watchdog_enabled = False
    made.step(SETTLE_STEPS)
    return made


def timed(run: Callable[[], None]) -> float:
    start = time.thread_time()
    run()
    return time.thread_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=11)
    args = parser.parse_args()
    encoder = msgspec.msgpack.Encoder()
    cases = {"without": world(False), "with": world(True)}
    saved = {name: (mujoco.MjData(w.model), w) for name, w in cases.items()}
    for name, (copy, w) in saved.items():
        mujoco.mj_copyData(copy, w.model, w.data)
    step_us: dict[str, list[float]] = {name: [] for name in cases}
    state_us: dict[str, list[float]] = {name: [] for name in cases}

    for _ in range(args.rounds):
        for name, w in cases.items():
            start_data = saved[name][0]
            mujoco.mj_copyData(w.data, w.model, start_data)
            step_us[name].append(timed(lambda: w.step(args.steps)) / args.steps * 1e6)
            mujoco.mj_copyData(w.data, w.model, start_data)

            kept = 4 if name == "with" else 3  # without: no Contacts message, as before

            def step_and_publish(w: World = w, kept: int = kept) -> None:
                for seq in range(args.steps):
                    w.step(1)
                    for states in w.reader.messages(w.take([seq])):
                        for message in states[:kept]:
                            encoder.encode(message)

            both = timed(step_and_publish) / args.steps * 1e6
            state_us[name].append(both)

    print(f"G1 standing, {args.steps} steps x {args.rounds} rounds, CPU us (medians)")
    base_step, base_all = statistics.median(step_us["without"]), statistics.median(state_us["without"])
    print(f"{'case':<8} {'step':>8} {'x':>6} {'step+state':>11} {'x':>6} {'state alone':>12}")
    for name in cases:
        step, both = statistics.median(step_us[name]), statistics.median(state_us[name])
        print(f"{name:<8} {step:8.1f} {step / base_step:6.3f} {both:11.1f} {both / base_all:6.3f} {both - step:12.1f}")
    contacts = cases["with"].reader.messages(cases["with"].take([0]))[0].contacts
    print(f"contacts message: {len(encoder.encode(contacts))} bytes msgpack, {len(msgspec.json.encode(contacts))} JSON")


if __name__ == "__main__":
    main()
