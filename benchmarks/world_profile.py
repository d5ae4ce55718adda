"""Where the world loop spends its time: N G1s in one world, `rtf 0`, under cProfile, no network clients.

    .venv/bin/python benchmarks/world_profile.py [--robots 32] [--seconds 4]

Prints the sim seconds reached, the process CPU they took (cores per real-time second = CPU / sim
seconds: what N robots cost, whatever else the machine runs) and the loop's top functions by own time.
"""

from __future__ import annotations

import argparse
import cProfile
import logging
import math
import pstats
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from zensim.sim.settings import SimSettings
from zensim.sim.service import SimService, load_world


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--robots", type=int, default=32)
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args()
    logging.disable(logging.INFO)
    side = math.ceil(math.sqrt(args.robots))
    path = Path(tempfile.mkdtemp()) / "world.toml"
    path.write_text('id = "profile"\n' + "".join(
        f'[[robots]]\nid = "p{k}"\nxy = [{2.0 * (k % side)}, {2.0 * (k // side)}]\n' for k in range(args.robots)))
    settings = SimSettings(world=str(path), rtf=0.0)
    world, world_file = load_world(settings)
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as session:
        stop = threading.Event()
        service = SimService(session, settings, stop, world, world_file)
        threading.Timer(args.seconds, stop.set).start()
        cpu0, wall0 = time.process_time(), time.perf_counter()
        profile = cProfile.Profile()
        profile.enable()
        service.run()
        profile.disable()
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        service.close()
    sim_s = float(world.data.time)
    print(f"{args.robots} G1: {sim_s:.2f} sim s in {wall:.2f} s wall, {cpu:.2f} s CPU: "
          f"{cpu / sim_s:.2f} cores per real-time second")
    pstats.Stats(profile).sort_stats("tottime").print_stats(14)


if __name__ == "__main__":
    main()
