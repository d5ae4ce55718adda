"""Should the sim work the feet's contact figures out itself? MuJoCo's contact sensors against a numpy pass.

    .venv/bin/python benchmarks/foot_contacts_pass.py [--counts 1,4,8,16,32] [--steps 300] [--rounds 3]

The feet's figures in state/contacts come from MuJoCo's contact sensors (robots/builder.py), which match every
sensor against every contact of the world: feet x contacts, the square of the robots. The alternative measured
here works them out in one pass over the contact list (`foot_figures`: mj_contactForce's pyramid decode, the
contact frame's turn, the sums in contact order), linear in the contacts but some 50 numpy calls. It gives the
netforce sensor's figures to the bit: checked at every sensed step of the run.

For each robot count, G1s standing 2 m apart in one world (as many_robots.py), settled; from the same state,
interleaved, `--steps` steps of mj_step2 + mj_step1 (World.step's pair) each way:

  unsensed   MuJoCo's sensors off (mjDSBL_SENSOR), as the world's steps between states
  MuJoCo     sensors on: the feet's contact sensors (and the IMU's and base's, a few us)
  pass       sensors off, the numpy pass right after mj_step2 (where the contacts and forces are the step's)

CPU time of the thread, medians over rounds; the extras are what each way adds to a sensed step.
docs/benchmarks.md ("One engine") keeps the figures and the decision.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import mujoco
import numpy as np

from zensim.robots import builder, robot_files
from zensim.robots.builder import FOOT_NET_SUFFIX
from zensim.sim.physics import Limits
from zensim.sim.world import World

SETTLE_STEPS = 500
SENSORS_OFF = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)


def standing_world(robots: int) -> World:
    side = math.ceil(math.sqrt(robots))
    placements = [builder.Placement(f"g{k}_", robot_files("g1"), (2.0 * (k % side), 2.0 * (k // side)), 0.0)
                  for k in range(robots)]
    world = World("w", [f"g{k}" for k in range(robots)], [p.files for p in placements],
                  builder.build_world(placements, "floating"), Limits(max_kp=5000, max_kd=500), 0.5, "floating")
    for sim in world.robots:
        sim.watchdog_enabled = False
    world.step(SETTLE_STEPS)
    return world


class FootPass:
    """Each foot's [contacts found, force (world frame, exerted by the foot)] from the contact list."""

    def __init__(self, world: World) -> None:
        model = world.model
        feet = [(sim.robot, link) for sim in world.robots for link in sim.robot.foot_links]
        self.count = len(feet)
        self.foot_of_body = np.full(model.nbody, -1)
        for row, (robot, link) in enumerate(feet):
            sensor = int(np.nonzero(model.sensor_adr == robot.sensor_slices[link + FOOT_NET_SUFFIX].start)[0][0])
            self.foot_of_body[model.sensor_objid[sensor]] = row
        self.net = np.stack([np.arange(robot.sensor_slices[link + FOOT_NET_SUFFIX].start,
                                       robot.sensor_slices[link + FOOT_NET_SUFFIX].stop) for robot, link in feet])
        self.geom_body = model.geom_bodyid.copy()
        assert model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL

    def figures(self, data: mujoco.MjData) -> np.ndarray:
        """(right after an acceleration stage) The G1's case: pyramidal cones of condim 3, as MuJoCo's sensor."""
        out = np.zeros((self.count, 4))
        contacts = data.contact
        feet = self.foot_of_body[self.geom_body[contacts.geom]]
        ids, side = np.nonzero(feet >= 0)  # row-major: in contact order, as the sensor sums them
        if not len(ids):
            return out
        foot = feet[ids, side]
        address = contacts.efc_address[ids]
        assert (contacts.dim[ids] == 3).all() and (address >= 0).all()
        edges = data.efc_force[address[None, :] + np.arange(4)[:, None]]
        friction = contacts.friction[ids]
        normal = edges[0] + edges[1] + edges[2] + edges[3]  # mju_decodePyramid, term by term
        tangent1 = (edges[0] - edges[1]) * friction[:, 0]
        tangent2 = (edges[2] - edges[3]) * friction[:, 1]
        frame = contacts.frame[ids]
        sign = 1.0 - 2.0 * side  # the force on geom2 is the one geom1 exerts: the foot's is its opposite
        out[:, 0] = np.bincount(foot, minlength=self.count)
        for axis in range(3):  # mju_mulMatTVec3's products in its order; bincount sums in contact order
            world = frame[:, axis] * normal + frame[:, 3 + axis] * tangent1 + frame[:, 6 + axis] * tangent2
            out[:, 1 + axis] = np.bincount(foot, sign * world, self.count)
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--counts", default="1,4,8,16,32")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"G1s standing 2 m apart, {args.steps} steps x {args.rounds} rounds, CPU us per step (medians)")
    print("| G1s | contacts | unsensed | sensed, MuJoCo's sensors | sensors off + the pass | MuJoCo's extra "
          "| the pass's extra | pass = sensor, steps |")
    print("|---|---|---|---|---|---|---|---|")
    for count in [int(c) for c in args.counts.split(",")]:
        world = standing_world(count)
        model, data, opt = world.model, world.data, world.model.opt
        foot_pass = FootPass(world)
        start = mujoco.MjData(model)
        mujoco.mj_copyData(start, model, data)
        seen = {"unsensed": [], "mujoco": [], "pass": []}
        same = checked = 0
        for _ in range(args.rounds):
            for way in seen:
                mujoco.mj_copyData(data, model, start)
                sensed = way == "mujoco"
                opt.disableflags = (opt.disableflags & ~SENSORS_OFF) if sensed else (opt.disableflags | SENSORS_OFF)
                began = time.thread_time()
                for _ in range(args.steps):
                    mujoco.mj_step2(model, data)
                    if way == "pass":
                        foot_pass.figures(data)
                    mujoco.mj_step1(model, data)
                seen[way].append((time.thread_time() - began) / args.steps * 1e6)
                if sensed:  # the pass against the sensors, on the state the sensed steps left
                    mujoco.mj_copyData(data, model, start)
                    for _ in range(20):
                        mujoco.mj_step2(model, data)
                        checked += 1
                        same += np.array_equal(foot_pass.figures(data), data.sensordata[foot_pass.net])
                        mujoco.mj_step1(model, data)
        opt.disableflags &= ~SENSORS_OFF
        unsensed, by_mujoco, by_pass = (statistics.median(seen[w]) for w in ("unsensed", "mujoco", "pass"))
        print(f"| {count} | {data.ncon} | {unsensed:.1f} | {by_mujoco:.1f} | {by_pass:.1f} | {by_mujoco - unsensed:.1f} "
              f"| {by_pass - unsensed:.1f} | {same} of {checked} |")


if __name__ == "__main__":
    main()
