"""What reading a robot description costs: the one URDF reader and the viewer's forward kinematics.

    .venv/bin/python benchmarks/description.py [--urdf PATH] [--rounds 50]

Times `zensim.robots.description.load_description` (yourdfpy behind the safe XML check; run once per
description by the builder and the viewer) and `Kinematics.transforms` (the viewer's numpy forward
kinematics, run for every drawn frame) on the bundled G1, or on PATH (e.g. Unitree's own URDF).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from zensim.robots import robot_files
from zensim.robots.description import load_description

with warnings.catch_warnings():  # meshcat imports pyzmq's deprecated ioloop
    warnings.simplefilter("ignore", DeprecationWarning)
    from zensim.viz.scene import Kinematics, movable_joints


def per_call_ms(call, rounds: int) -> float:
    call()
    start = time.perf_counter()
    for _ in range(rounds):
        call()
    return 1e3 * (time.perf_counter() - start) / rounds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--urdf", type=Path, default=None, help="a URDF (default: the bundled G1)")
    parser.add_argument("--rounds", type=int, default=50)
    args = parser.parse_args()
    path = args.urdf or robot_files("g1").urdf
    description = load_description(path)
    kinematics = Kinematics(description, [j.name for j in movable_joints(description)])
    q = np.random.default_rng(0).uniform(-0.5, 0.5, len(kinematics.joint_order))
    parse_ms = per_call_ms(lambda: load_description(path), args.rounds)
    fk_ms = per_call_ms(lambda: kinematics.transforms(q, np.eye(4)), 20 * args.rounds)
    print(f"{path.name}: {len(description.links)} links, {len(description.actuated_joints)} actuated joints")
    print(f"  load_description {parse_ms:.2f} ms | forward kinematics of every link {fk_ms:.3f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
