"""Measure the robot figures quoted in docs/robots.md: standing, fixed-mode tracking, step time.

    python benchmarks/robot_figures.py            # our G1
    ZENSIM_OFFICIAL_G1=/path/to/g1_description python benchmarks/robot_figures.py   # and the official

A dev script: prints a report (stdout is its product).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import mujoco
import numpy as np

from zensim.robots import RobotFiles, robot_files
from zensim.robots.builder import build
from zensim.sim.mjdata import apply_motor_command, base_tilt_rad, read_base, reset, warnings_of

STAND_S = 30.0
SETTLE_S = 2.0


def standing(files: RobotFiles) -> str:
    """Pelvis height/tilt over STAND_S in the squat with default gains, and the mj_step time."""
    robot = build(files, "floating")
    data = mujoco.MjData(robot.model)
    reset(robot, data)
    rows = []
    steps = round(STAND_S / robot.model.opt.timestep)
    step_time = 0.0
    for i in range(steps):
        t0 = time.perf_counter()
        mujoco.mj_step(robot.model, data)
        step_time += time.perf_counter() - t0
        if i % 10 == 0:
            mujoco.mj_forward(robot.model, data)
            rows.append((data.time, read_base(robot, data)[0][2], base_tilt_rad(robot, data)))
    a = np.array(rows)
    late = a[a[:, 0] > SETTLE_S]
    return (f"  pelvis z min/max {a[:, 1].min():.4f}/{a[:, 1].max():.4f} m (after {SETTLE_S:g} s: "
            f"{late[:, 1].min():.4f}/{late[:, 1].max():.4f}); tilt max {a[:, 2].max():.4f} rad "
            f"(after {SETTLE_S:g} s: {late[:, 2].max():.4f}); final z {a[-1, 1]:.4f}\n"
            f"  mj_step {step_time / steps * 1e6:.1f} us ({steps / step_time:.0f} steps/s, "
            f"{STAND_S / step_time:.0f}x real time), contacts {data.ncon}, warnings {warnings_of(data) or 'none'}")


def tracking(files: RobotFiles, seeds: int = 3) -> str:
    """Fixed mode: step targets at 30-70 % of each joint's range; max error over time."""
    robot = build(files, "fixed")
    data = mujoco.MjData(robot.model)
    lines = []
    for seed in range(seeds):
        reset(robot, data)
        target = robot.q_min + (robot.q_max - robot.q_min) * np.random.default_rng(seed).uniform(0.3, 0.7, robot.nu)
        apply_motor_command(robot, data, target, np.zeros(robot.nu), robot.kp, robot.kd, np.zeros(robot.nu))
        settled, errors = None, {}
        for _ in range(round(10.0 / robot.model.opt.timestep)):
            mujoco.mj_step(robot.model, data)
            err = float(np.abs(data.qpos[robot.qpos_adr] - target).max())
            settled = None if err > 0.01 else (settled or data.time)
            for mark in (1.0, 2.0, 5.0, 10.0):
                if abs(data.time - mark) < 1e-9:
                    errors[mark] = err
        lines.append(f"  seed {seed}: max |q - target| at 1/2/5/10 s: "
                     + " / ".join(f"{errors[m]:.4f}" for m in sorted(errors))
                     + f" rad; within 0.01 rad from {settled:.2f} s" if settled else " (never settled)")
    return "\n".join(lines)


def main() -> None:
    """Print the figures for our G1 and, when ZENSIM_OFFICIAL_G1 is set, the official one."""
    variants = {"ours (robots/unitree_g1)": robot_files("g1")}
    official = os.environ.get("ZENSIM_OFFICIAL_G1")
    if official:
        variants["official (meshes)"] = robot_files("g1", urdf=Path(official) / "g1_29dof.urdf")
    for label, files in variants.items():
        t0 = time.perf_counter()
        build(files, "floating")
        print(f"{label}: compile {time.perf_counter() - t0:.3f} s")
        print(f" floating, default gains, squat, {STAND_S:g} s:")
        print(standing(files))
        print(" fixed mode tracking:")
        print(tracking(files))


if __name__ == "__main__":
    main()
