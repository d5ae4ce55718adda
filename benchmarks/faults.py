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

from step_cases import arguments, print_table, settled, time_rounds
from zensim.schemas import FaultsRequest, JointFault, LinkFaults, MotorCommand, SensorFaults
from zensim.sim.world import World

CASES = ("none", "motors", "sensors", "all", "link", "drift", "dropout", "delay")
HOWS = ("step", "advance", "read")
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
    args = arguments(__doc__, HOWS)
    hows = tuple(args.hows.split(","))
    worlds = {case: settled() for case in CASES}
    hold = MotorCommand(q=worlds["none"][0].robots[0].robot.default_q.tolist())
    reads = args.steps // 5

    def run(world: World, how: str) -> int:
        sim = world.robots[0]
        if how == "step":
            for k in range(args.steps):
                if k % COMMAND_EVERY == 0:
                    sim.accept_command(hold)
                world.step(1)
        elif how == "advance":
            for _ in range(args.steps // COMMAND_EVERY):
                sim.accept_command(hold)
                world.step(COMMAND_EVERY, held=True)
        else:  # reads a state period apart in sim time: the drift turns, the delay's readings move on
            t0 = world.data.time
            for k in range(reads):
                world.data.time = t0 + 5 * k * world.timestep_s
                world.reader.read(world.data, [k])
            world.data.time = t0
            return reads
        return args.steps

    times = time_rounds(worlds, hows, args.rounds, inject, run)
    print(f"{args.rounds} rounds of {args.steps} steps; CPU us per physics step (read: per state), median "
          "(ratio to none)")
    print_table(times, CASES, hows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
