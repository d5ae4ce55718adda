"""Drive every robot of a world in one request (world/advance): a world of several robots runs in one
MuJoCo model, and under `--clock lockstep` one request commands them all and brings back all their states.

Start the world with `zensim sim --world lab.toml --clock lockstep` (services/sim/README.md has the
file's format); its id (`id = "lab"`) names the world's keys, zensim/lab/world/*, and each robot keeps
its own keys, zensim/{robot}/*. world/info lists the robots. A controller whose credential covers one
robot only (docs/security.md, "Robots of one world") sends the same request to zensim/{robot}/world/advance,
with that robot's command alone.

    python examples/drive_world.py --world lab --ticks 250
"""

from __future__ import annotations

import json

import zenoh


def query(session: zenoh.Session, key: str, request: dict | None = None) -> dict:
    """A world verb: the JSON request in, the reply as a dict out (an error reply raises)."""
    reply = next(iter(session.get(key, payload=json.dumps(request or {}), timeout=10)))
    if reply.ok is None:
        raise RuntimeError(reply.err.payload.to_string())
    return json.loads(reply.ok.payload.to_bytes())


def main(conf: zenoh.Config, world: str, ticks: int) -> None:
    with zenoh.open(conf) as session:
        info = query(session, f"zensim/{world}/world/info")
        robots = [robot["robot"] for robot in info["robots"]]
        print(f"world {info['world']}: robots {', '.join(robots)}")
        # Each robot's own description, as alone: here only its first joint's name.
        first_joint = {robot: query(session, f"zensim/{robot}/info/robot")["joint_names"][0] for robot in robots}
        for tick in range(ticks):
            # A command per robot (each holds its first joint at 0.3 rad); a robot left out holds its
            # last command. The reply comes once every robot has been stepped.
            commands = {robot: {"names": [first_joint[robot]], "q": [0.3]} for robot in robots}
            reply = query(session, f"zensim/{world}/world/advance", {"commands": commands})
            if not reply["ok"]:
                raise RuntimeError(f"world/advance refused: {reply['error']}")
            if tick % 50 == 0 or tick == ticks - 1:
                firsts = ", ".join(f"{robot} {states['joints']['q'][0]:+.3f}" for robot, states in reply["states"].items())
                print(f"t={reply['sim_time_s']:.3f} s: {firsts}")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="drive_world", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("--world", "-w", default="world", help="the world's id (its file's `id`, default world)")
    parser.add_argument("--ticks", type=int, default=250, help="how many world advances to run")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.world, args.ticks)
