"""The G1 locomotion controller (services/unitree/loco.py) in-process with the sim's physics: walk figures
and the cost of one policy step. No network: the same controller and World (a world of one) the sim runs.

    .venv/bin/python benchmarks/unitree_loco.py

Squat-to-stand, Move(0.3, 0, 0) for 10 s of sim time, stop, Move(0, 0, 0.3) for 5 s: distance, lateral
drift, heading change, drift at standstill; then the mean cost of WalkPolicy.act (numpy LSTM + MLP).
"""

from __future__ import annotations

import math
import time

import numpy as np

from zensim.robots import robot_files
from zensim.schemas import MotorCommand
from zensim.sim.physics import Limits
from zensim.sim.world import World
from zensim.unitree.loco import LocoController
from zensim.unitree.walk_policy import NUM_OBS, WalkPolicy


def yaw_of(quat_wxyz) -> float:
    w, x, y, z = quat_wxyz
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def main() -> None:
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    (sim,) = world.robots
    sim.watchdog_enabled = False
    ctl = LocoController()
    fell = False

    def run(seconds: float):  # noqa: ANN202
        nonlocal fell
        for seq in range(int(round(seconds / sim.timestep_s))):
            js, _odom, imu = world.reader.read(world.data, [seq])[0]
            targets = ctl.tick(js.sim_time_s, np.array(js.q), np.array(js.dq), np.array(imu.quat_wxyz),
                               np.array(imu.gyro))
            if targets is not None:
                sim.accept_command(MotorCommand(q=tuple(targets.q), dq=tuple(targets.dq), kp=tuple(targets.kp),
                                                kd=tuple(targets.kd), tau=tuple(targets.tau)))
            world.step(1)
            fell = fell or sim.fallen()
        return world.reader.read(world.data, [0])[0][1]

    run(0.5)
    ctl.set_fsm(706)
    start = run(3.0)
    ctl.set_velocity(0.3, 0, 0, 864000, sim.sim_time_s)
    walked = run(10.0)
    ctl.set_velocity(0, 0, 0, 0, sim.sim_time_s)
    settled = run(1.0)
    still = run(3.0)
    ctl.set_velocity(0, 0, 0.3, 864000, sim.sim_time_s)
    turned = run(5.0)
    heading = (yaw_of(turned.quat_wxyz) - yaw_of(still.quat_wxyz) + math.pi) % (2 * math.pi) - math.pi
    print(f"Move(0.3, 0, 0) for 10 s: {walked.pos[0] - start.pos[0]:.2f} m forward, "
          f"{walked.pos[1] - start.pos[1]:+.2f} m lateral, heading {yaw_of(walked.quat_wxyz) - yaw_of(start.quat_wxyz):+.3f} rad")
    print(f"after StopMove: {math.dist(settled.pos[:2], still.pos[:2]):.3f} m in 3 s")
    print(f"Move(0, 0, 0.3) for 5 s: {heading:+.2f} rad, {math.dist(still.pos[:2], turned.pos[:2]):.2f} m displacement")
    print(f"fell: {fell}")
    policy, obs = WalkPolicy(), np.random.default_rng(0).normal(size=NUM_OBS).astype(np.float32) * 0.1
    n = 5000
    t0 = time.perf_counter()
    for _ in range(n):
        policy.act(obs)
    print(f"WalkPolicy.act: {(time.perf_counter() - t0) / n * 1e6:.1f} us per step (50 Hz: "
          f"{(time.perf_counter() - t0) / n * 50 * 100:.2f} % of a core)")


if __name__ == "__main__":
    main()
