"""The G1 walking controller (zensim loco: services/loco/controller.py) in-process with the sim's physics:
walk figures and the cost of one policy step. No network: the same controller and World (a world of one) the sim runs.

    .venv/bin/python benchmarks/loco_walk.py

Squat-to-stand, Move(0.3, 0, 0) for 10 s of sim time, stop, Move(0, 0, 0.3) for 5 s: distance, lateral
drift, heading change, drift at standstill (1 s after the stop, over 5 s); then the mean cost of
WalkPolicy.act (numpy LSTM + MLP).
"""

from __future__ import annotations

import math
import time

import numpy as np

from zensim.loco.controller import LocoController
from zensim.loco.walk_policy import NUM_OBS, WalkPolicy, load_weights
from zensim.robots import robot_files
from zensim.robots.walking import walking_for
from zensim.schemas import MotorCommand
from zensim.sim.physics import Limits
from zensim.sim.world import World


def yaw_of(quat_wxyz) -> float:
    w, x, y, z = quat_wxyz
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def main() -> None:
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    (sim,) = world.robots
    sim.watchdog_enabled = False
    found = walking_for(tuple(sim.robot.joint_names))
    assert found is not None
    walking = found[1]
    ctl = LocoController(walking)
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
    planted_at = None
    still = settled
    for _ in range(20):  # 0.1 s at a time: when the controller stops stepping, and 1 s later
        still = run(0.1)
        if planted_at is None and ctl.state.planted:
            planted_at = sim.sim_time_s
    stood = run(1.0)
    stood_later = run(5.0)
    still = stood_later
    since_stop = math.dist(settled.pos[:2], stood_later.pos[:2])
    since_span = stood_later.sim_time_s - settled.sim_time_s
    ctl.set_velocity(0, 0, 0.3, 864000, sim.sim_time_s)
    turned = run(5.0)
    heading = (yaw_of(turned.quat_wxyz) - yaw_of(still.quat_wxyz) + math.pi) % (2 * math.pi) - math.pi
    print(f"Move(0.3, 0, 0) for 10 s: {walked.pos[0] - start.pos[0]:.2f} m forward, "
          f"{walked.pos[1] - start.pos[1]:+.2f} m lateral, heading {yaw_of(walked.quat_wxyz) - yaw_of(start.quat_wxyz):+.3f} rad")
    print(f"after StopMove: planted {planted_at - (start.sim_time_s + 10.0) if planted_at else float('nan'):.2f} s after "
          f"it; pelvis drift over 5 s from 1 s after the plant: {math.dist(stood.pos[:2], stood_later.pos[:2]) * 100:.2f} cm "
          f"(from 1 s after StopMove, the plant and its sway included: "
          f"{since_stop * 100:.2f} cm over {since_span:.1f} s)")
    print(f"Move(0, 0, 0.3) for 5 s: {heading:+.2f} rad, {math.dist(still.pos[:2], turned.pos[:2]):.2f} m displacement")
    print(f"fell: {fell}")
    policy, obs = WalkPolicy(load_weights(walking.weights), walking.leg_default_q), np.random.default_rng(0).normal(size=NUM_OBS).astype(np.float32) * 0.1
    n = 5000
    t0 = time.perf_counter()
    for _ in range(n):
        policy.act(obs)
    print(f"WalkPolicy.act: {(time.perf_counter() - t0) / n * 1e6:.1f} us per step (50 Hz: "
          f"{(time.perf_counter() - t0) / n * 50 * 100:.2f} % of a core)")


if __name__ == "__main__":
    main()
