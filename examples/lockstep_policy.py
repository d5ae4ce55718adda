"""Run a policy in lockstep with the sim (ctl/advance): each command advances the physics a fixed number
of steps and the reply brings the new joint state, odometry and IMU, all of one instant.

Start the sim with `zensim sim --clock lockstep` (or `ZENSIM_SIM_CLOCK=lockstep zensim up`): between
two requests no sim time passes, so the policy may think as long as it likes. Runs from the same
commands are bit-identical. The policy here is a PD the client computes itself: it drives one joint to
a goal with torques only (kp = kd = 0 in the sim).

    python examples/lockstep_policy.py left_elbow_joint 0.8 --ticks 100
"""

from __future__ import annotations

import json

import zenoh


def advance(session: zenoh.Session, robot: str, command: dict) -> dict:
    """One lockstep tick: the command in, the AdvanceReply (as a dict) out."""
    reply = next(iter(session.get(f"zensim/{robot}/ctl/advance", payload=json.dumps(command), timeout=10)))
    if reply.ok is None:
        raise RuntimeError(reply.err.payload.to_string())
    state = json.loads(reply.ok.payload.to_bytes())
    if not state["ok"]:
        raise RuntimeError(f"ctl/advance refused: {state['error']}")
    return state


def main(conf: zenoh.Config, robot: str, joint: str, goal: float, ticks: int) -> None:
    with zenoh.open(conf) as session:
        info = json.loads(next(iter(session.get(f"zensim/{robot}/info/robot?format=json", timeout=10))).ok.payload.to_bytes())
        if info["clock"] != "lockstep":
            raise SystemExit(f"the sim runs clock {info['clock']!r}: start it with --clock lockstep")
        i = info["joint_names"].index(joint)
        q, dq = 0.0, 0.0
        for tick in range(ticks):
            tau = 20.0 * (goal - q) - 1.0 * dq  # the policy: any function of the last state
            state = advance(session, robot, {"names": [joint], "q": [0.0], "kp": [0.0], "kd": [0.0], "tau": [tau]})
            q, dq = state["joints"]["q"][i], state["joints"]["dq"][i]
            if tick % 20 == 0 or tick == ticks - 1:
                print(f"t={state['sim_time_s']:.3f} s {joint}={q:+.3f} rad (tau {tau:+.2f} N m)")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="lockstep_policy", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("joint", help="a joint name (info/robot's joint_names)")
    parser.add_argument("goal", type=float, help="where the policy drives it, rad")
    parser.add_argument("--ticks", type=int, default=100, help="how many lockstep ticks to run")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot, args.joint, args.goal, args.ticks)
