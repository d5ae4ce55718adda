"""Step time and state-read time of the G1 with faults active against none, side by side (issue 29 item 3).

    .venv/bin/python benchmarks/faults.py [--steps 2000] [--rounds 15] [--hows step,advance,read]

Each case is the sim's own World (services/sim/world.py: the step the service runs) of the G1 floating and
holding its default pose on its gains, settled for 1 s, then given the case's faults:

  none      no fault
  motors    a weak left knee (torque_scale 0.9), a locked left elbow, a limp left wrist: faults written into
            the model once (services/sim/faults.py), nothing per step
  sensors   an encoder offset, IMU noise and bias, joint q and dq noise: added at each state read
  all       both
  link      a command delay of 10 steps (ctl/faults' link): each command is held in flight for 10 steps, and a
            lockstep advance runs its 10 steps one at a time (a command lands mid-advance)
  drift     the IMU's orientation drifting at 0.01 rad/s about z: one quaternion product per state read
  dropout   dropouts (probability 0.05 per state, 10 ms each): one uniform draw per state read, 1 in 4 withheld
  delay     a state delay of 10 steps (link.state_delay_steps): each state read kept in a ring of 3, the one
            two reads back handed out (its JointState and Imu restamped)

Every round times, from the same settled state and with the cases interleaved (the machine's load falls on
all alike), `--steps` steps two ways and the state reads of them; every case is sent the held pose as a new
command every 10 steps (a 100 Hz controller, as the course's lockstep advances are), timed with the steps:

  step      World.step(1) per step: the real-time loop
  advance   World.step(10, held=True) per lockstep advance (MuJoCo runs the 10 steps in one call)
  read      World.reader.read per state (the one state reader: take the arrays, add the sensor faults, build
            JointState, Odometry, Imu, Contacts): once per 5 steps at 100 Hz states

The state reads move the clock on by 5 steps each (`data.time`, nothing else: the same figures), so a
delay's ring turns as in a run. Time is the thread's CPU time (time.thread_time); medians over rounds, and each case's ratio to none.
Results go to stdout; docs/benchmarks.md keeps the figures.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco

from zensim.robots import robot_files
from zensim.schemas import FaultsRequest, JointFault, LinkFaults, MotorCommand, SensorFaults
from zensim.sim.physics import Limits
from zensim.sim.world import World

SETTLE_S = 1.0
CASES = ("none", "motors", "sensors", "all", "link", "drift", "dropout", "delay")
COMMAND_EVERY = 10
"""Steps between two commands (20 ms: a 100 Hz controller; a lockstep advance of the course)."""
LINK = LinkFaults(command_delay_steps=10)
MOTORS = (JointFault(joint="left_knee_joint", torque_scale=0.9), JointFault(joint="left_elbow_joint", locked=True),
          JointFault(joint="left_wrist_roll_joint", limp=True))
OFFSET = (JointFault(joint="right_knee_joint", encoder_offset_rad=0.02),)
DRIFT = SensorFaults(orientation_drift_rad_s=0.01)
DROPOUT = SensorFaults(dropout_probability=0.05, dropout_s=0.01)
DELAY = LinkFaults(state_delay_steps=10)
SENSORS = SensorFaults(gyro_noise_std_rad_s=0.005, gyro_bias_rad_s=(0.01, 0.0, 0.0), accel_noise_std_m_s2=0.05,
                       accel_bias_m_s2=(0.0, 0.1, 0.0), q_noise_std_rad=0.001, dq_noise_std_rad_s=0.02)


def settled() -> tuple[World, mujoco.MjData]:
    world = World.alone("bench", robot_files("g1"), "floating", Limits(5000, 500), 1e9)
    (sim,) = world.robots
    sim.accept_command(MotorCommand(q=sim.robot.default_q.tolist()))
    world.step(int(SETTLE_S / world.timestep_s))
    snapshot = mujoco.MjData(world.model)
    mujoco.mj_copyData(snapshot, world.model, world.data)
    return world, snapshot


def inject(world: World, case: str) -> None:
    """Put the case's faults on (from the settled state)."""
    joints = (MOTORS if case in ("motors", "all") else ()) + (OFFSET if case in ("sensors", "all") else ())
    sensors = SENSORS if case in ("sensors", "all") else {"drift": DRIFT, "dropout": DROPOUT}.get(case)
    link = {"link": LINK, "delay": DELAY}.get(case)
    sim = world.robots[0]
    sim.faults.request(FaultsRequest(verb="set", joints=joints, sensors=sensors, seed=1, link=link)
                       if joints or sensors or link else FaultsRequest(verb="clear"))
    sim.faults_changed()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--hows", default="step,advance,read",
                        help="what to time, of step, advance, read (read alone: many reads in little time)")
    args = parser.parse_args()
    cases = {case: settled() for case in CASES}
    hows = tuple(args.hows.split(","))
    if not set(hows) <= {"step", "advance", "read"}:
        parser.error(f"--hows: of step, advance, read; got {args.hows}")
    times: dict[tuple[str, str], list[float]] = {(case, how): [] for case in CASES for how in hows}
    reads = args.steps // 5
    for _ in range(args.rounds):
        for how in hows:
            for case, (world, snapshot) in cases.items():
                mujoco.mj_copyData(world.data, world.model, snapshot)
                inject(world, case)
                sim = world.robots[0]
                hold = MotorCommand(q=sim.robot.default_q.tolist())
                start = time.thread_time()
                if how == "step":
                    for k in range(args.steps):
                        if k % COMMAND_EVERY == 0:
                            sim.accept_command(hold)
                        world.step(1)
                elif how == "advance":
                    for _ in range(args.steps // COMMAND_EVERY):
                        sim.accept_command(hold)
                        world.step(COMMAND_EVERY, held=True)
                else:
                    t0 = world.data.time
                    for k in range(reads):
                        world.data.time = t0 + 5 * k * world.timestep_s
                        world.reader.read(world.data, [k])
                    world.data.time = t0
                elapsed = time.thread_time() - start
                times[case, how].append(elapsed / (reads if how == "read" else args.steps) * 1e6)
                assert not world.fallen(world.take([0]))[0], f"{case}: the robot fell; the case measures nothing"
    print(f"{args.rounds} rounds of {args.steps} steps; CPU us per physics step (read: per state), median "
          "(ratio to none)")
    print(f"{'case':<10}" + "".join(f" {how:>16}" for how in hows))
    for case in CASES:
        cells = []
        for how in hows:
            median = statistics.median(times[case, how])
            base = statistics.median(times["none", how])
            cells.append(f"{median:7.1f} ({median / base:4.2f})")
        print(f"{case:<10}" + "".join(f" {cell:>16}" for cell in cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
