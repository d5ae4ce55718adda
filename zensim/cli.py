"""The `zensim` command: one sub-command per job.

    zensim sim      the physics service (MuJoCo)
    zensim bridge   joint targets -> motor commands
    zensim viz      the web viewer with joint sliders
    zensim router   a Zenoh router for the others to meet at
    zensim up       all of the above as local processes
    zensim check    exit 0 when a service is alive (for healthchecks)
    zensim robot    build or inspect a robot model
    zensim secure   make the credentials of a secured network (secure init DIR)
    zensim unitree  Unitree's DDS LowCmd/LowState for SDK controllers
    zensim ros1     the ROS 1 gateway: RViz, joint_state_publisher_gui, controller topics
    zensim ros2     the ROS 2 face: rmw_zenoh's keys on zensim's router, and DDS
    zensim loco     the walking controller: cmd/velocity, ctl/loco (and the sport service, /cmd_vel)
    zensim record   record a robot's samples into MCAP; replay, resim: play or re-simulate one
    zensim scenario play a scenario file (pushes, velocities, faults on a timeline) and score the run
    zensim course   run the standard course (flat, slope, stairs, rough, pushes) and write a score table

Each sub-command takes `--help`. Settings come from `ZENSIM_*` variables and
flags; each service's README has its table (services/*/README.md, the
router's in docs/deployment.md).
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
from collections.abc import Sequence

from zensim.schemas.keys import SERVICES

COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("zensim.sim.__main__", "run the physics service"),
    "bridge": ("zensim.bridge.__main__", "run the bridge: joint targets -> motor commands"),
    "viz": ("zensim.viz.__main__", "run the web viewer with joint sliders"),
    "router": ("zensim.router", "run a Zenoh router"),
    "up": ("zensim.up", "run router, sim, bridge and viz as local processes"),
    "check": ("zensim.check", "exit 0 when a service's liveliness token is seen"),
    "robot": ("zensim.robots.cli", "build or inspect a robot model"),
    "secure": ("zensim.secure", "make TLS certificates, passwords and role configs (secure init DIR)"),
    "unitree": ("zensim.unitree.__main__", "run the Unitree DDS adapter (unitree_sdk2's rt/lowcmd, rt/lowstate)"),
    "ros1": ("zensim.ros1.__main__", "run the ROS 1 gateway (robot_description, joint states, controller topics)"),
    "ros2": ("zensim.ros2.__main__", "run the ROS 2 face (rmw_zenoh's keys and DDS: joint states, TF, commands)"),
    "loco": ("zensim.loco.__main__", "run the walking controller (cmd/velocity, ctl/loco, state/loco)"),
    "record": ("zensim.record", "record every sample of a robot into an MCAP file"),
    "replay": ("zensim.replay", "publish a recording's states again (the viewer draws the past run)"),
    "resim": ("zensim.resim", "re-simulate a recording's commands and report the divergence"),
    "scenario": ("zensim.scenario", "play a scenario file against the running controller and score it"),
    "course": ("zensim.course", "run the standard course against a controller and write its score table"),
}


LONG_RUNNING = frozenset(SERVICES)


def usage() -> str:
    lines = ["usage: zensim COMMAND [--help] [options]", "", "commands:"]
    lines += [f"  {name:<8} {text}" for name, (_, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    if args[0] in ("-V", "--version"):
        from zensim import __version__

        print(__version__)
        return 0
    command, rest = args[0], args[1:]
    if command not in COMMANDS:
        print(f"zensim: unknown command {command!r}\n\n{usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[command][0])
    code = module.main(rest)
    if command in LONG_RUNNING:
        # The service has closed its zenoh session and said goodbye; tearing down the interpreter
        # with zenoh's runtime loaded takes another 1-2 s, which would break the promise of a clean
        # exit within 2 s of SIGTERM (Docker's stop, compose restarts). Flush and leave now.
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
