"""Pause the sim, step it by hand, resume it and reset the robot (the ctl/* queryables).

Each request is a zenoh get with a JSON payload; the reply (a CtlReply, JSON for a JSON request) says
whether it was done, the sim time and the episode (a new one after each reset). A request never half
happens: a refused one changes nothing and says why in `error`.

    python examples/reset_pause.py
"""

from __future__ import annotations

import json

import zenoh


def ctl(session: zenoh.Session, robot: str, verb: str, request: dict | None = None) -> dict:
    """One control request; its reply as a dict (an error reply raises)."""
    replies = list(session.get(f"zensim/{robot}/ctl/{verb}", payload=json.dumps(request or {}), timeout=10))
    if not replies or replies[0].ok is None:
        raise RuntimeError(f"ctl/{verb}: no reply" if not replies else replies[0].err.payload.to_string())
    reply = json.loads(replies[0].ok.payload.to_bytes())
    if not reply["ok"]:
        raise RuntimeError(f"ctl/{verb} refused: {reply['error']}")
    return reply


def main(conf: zenoh.Config, robot: str) -> None:
    with zenoh.open(conf) as session:
        paused = ctl(session, robot, "pause")
        print(f"paused at t={paused['sim_time_s']:.3f} s")
        stepped = ctl(session, robot, "step", {"n": 50})  # 50 physics steps, replied once they ran
        print(f"stepped 50 steps to t={stepped['sim_time_s']:.3f} s ({stepped['steps']} steps since the start)")
        ctl(session, robot, "resume")
        print("resumed")
        reset = ctl(session, robot, "reset")  # {"names": [...], "q": [...]} resets to another pose
        print(f"reset: episode {reset['episode']}, t={reset['sim_time_s']:.3f} s")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="reset_pause", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot)
