"""Run one of unitree_sdk2_python's example programs, unchanged, on a private DDS domain.

    python tests/run_sdk_example.py DOMAIN path/to/example.py [args...]
The G1 examples hard-code domain 0 (the robot's) in their ChannelFactoryInitialize call; parallel test
runs on one machine must not meet on it, so the SDK's ChannelFactoryInitialize is wrapped to put the
participant in DOMAIN instead. Nothing else changes: the example's own code runs as `__main__`.
"""

import runpy
import sys

import unitree_sdk2py.core.channel as channel

domain = int(sys.argv[1])
initialize = channel.ChannelFactoryInitialize


def on_private_domain(_id: int = 0, networkInterface: str | None = None) -> None:  # noqa: N803 (the SDK's name)
    initialize(domain, networkInterface)


channel.ChannelFactoryInitialize = on_private_domain
example = sys.argv[2]
sys.argv = [example, *sys.argv[3:]]
runpy.run_path(example, run_name="__main__")
