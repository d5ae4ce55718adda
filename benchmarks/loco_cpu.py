"""The walking service's cost: CPU of `zensim loco` per robot while it walks one G1 on a realtime sim.

    .venv/bin/python benchmarks/loco_cpu.py [--seconds 20] [--state-rate-hz 100]

A router, a realtime sim (`--state-rate-hz`: 100 Hz default, 500 Hz as `zensim up --unitree` runs it),
`zensim loco --start walk` and a plain client putting cmd/velocity (0.3 m/s, 10 Hz, default timeout)
as a teleop does. Reports the service's CPU (user + system) over the walking window, per wall second,
and the sim's for comparison. One robot per service: the figure is the per-robot cost.
"""

from __future__ import annotations

import argparse
import json
import os
import time

from harness import Latest, Processes, cpu_s, free_port, is_alive, plain_client, wait_for

from zensim.schemas import Keys, LocoStatus, Odometry


def main(seconds: float, state_rate_hz: float) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys("bench" + os.urandom(3).hex())
    env = dict(os.environ, ZENSIM_ROBOT_ID=keys.robot, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false")
    procs = Processes(env)
    try:
        procs.zensim("router", env={"ZENSIM_ZENOH_MODE": "router", "ZENSIM_ZENOH_LISTEN": endpoint,
                                    "ZENSIM_ZENOH_CONNECT": ""})
        session = plain_client(endpoint)
        sim = procs.zensim("sim", "--state-rate-hz", str(state_rate_hz))
        odom = Latest(session, keys.odom, Odometry)
        odom.wait(timeout_s=60, what="the sim")
        loco = procs.zensim("loco", "--start", "walk")
        status = Latest(session, keys.loco_status, LocoStatus)
        wait_for(lambda: is_alive(session, keys.alive("loco")), 60, "zensim loco")
        status.wait(lambda s: s.walking, 30, "the stand-up")
        start_pos = odom.value.pos
        loco0, sim0, t0 = cpu_s(loco.pid), cpu_s(sim.pid), time.monotonic()
        while time.monotonic() - t0 < seconds:
            session.put(keys.velocity, json.dumps({"vx": 0.3}))
            time.sleep(0.1)
        wall = time.monotonic() - t0
        loco_cpu, sim_cpu = cpu_s(loco.pid) - loco0, cpu_s(sim.pid) - sim0
        end = status.wait(what="a status")
        print(f"{wall:.1f} s walking at 0.3 m/s ({state_rate_hz:g} Hz states): zensim loco {loco_cpu / wall * 100:.1f} % "
              f"of a core (sim {sim_cpu / wall * 100:.1f} %); {end.policy_steps} policy steps, "
              f"walked {odom.value.pos[0] - start_pos[0]:.2f} m, {os.getloadavg()[0]:.1f} load average")
        session.close()
    finally:
        procs.stop_all()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--state-rate-hz", type=float, default=100.0)
    args = parser.parse_args()
    main(args.seconds, args.state_rate_hz)
