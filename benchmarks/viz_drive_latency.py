"""How fast a key on the viewer page reaches the walking controller: key press -> first `cmd/velocity`
put -> first `state/loco` carrying the new command -> (a press from standing) the first `state/loco` that
says the feet step.

Runs a router, the sim (real-time clock, floating), `zensim loco` and the viz as real processes on
loopback, opens the page in headless chromium, presses Stand, then presses and releases W `--presses`
times (held `--hold-s` each) through chromium's own input pipeline (DevTools Input.dispatchKeyEvent).
A plain zenoh subscriber in this process stamps the first cmd/velocity sample with the new vx and the
first state/loco whose `commanded` vx is the new one; press and release both count. Each press starts
from a robot standing with its feet planted (after a release the controller settles 1 s, then plants the
feet over 0.3 s: walking.toml), and its `stepping` figure is the first state/loco with `stepping` true.

    .venv/bin/python benchmarks/viz_drive_latency.py [--presses 20] [--hold-s 1.0]

state/loco goes out at 10 Hz (status_rate_hz) and at each ctl/loco request, not at each velocity
command: the second figure includes waiting for the next status (0-100 ms).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import zenoh

from harness import behind_private_router, cpu_s, free_port, plain_client, test_scaffolding, wait_for
from zensim.schemas import Codec, Keys, LocoStatus, VelocityCommand

Browser = test_scaffolding("browser").Browser


def summary(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    return {"n": len(ordered), "p50_ms": round(statistics.median(ordered), 1),
            "p99_ms": round(ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))], 1),
            "max_ms": round(ordered[-1], 1)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presses", type=int, default=20, help="W presses (each also a release)")
    parser.add_argument("--hold-s", type=float, default=1.0, help="how long W is held each time, s")
    args = parser.parse_args()

    robot_id = f"bench{os.getpid()}"
    keys = Keys(robot_id)
    port = free_port()
    procs, endpoint = behind_private_router(robot_id)
    results: dict[str, object] = {}
    try:
        sim = procs.zensim("sim")
        loco = procs.zensim("loco")
        viz = procs.zensim("viz", "--port", str(port))
        wait_for(lambda: "zensim loco up" in loco.log(), 60, "zensim loco")
        wait_for(lambda: "viz up" in viz.log() and "description of" in viz.log(), 60, "viz with a description")
        with plain_client(endpoint) as session, Browser() as browser:
            events: dict[str, float] = {}
            expected = {"vx": 0.0}
            newest: dict[str, LocoStatus] = {}
            velocity_codec, loco_codec = Codec(VelocityCommand), Codec(LocoStatus)

            def on_velocity(sample: zenoh.Sample) -> None:
                now = time.perf_counter()
                message = velocity_codec.decode(sample.payload.to_bytes(), str(sample.encoding))
                if "cmd" not in events and message.vx == expected["vx"]:
                    events["cmd"] = now

            def on_loco(sample: zenoh.Sample) -> None:
                now = time.perf_counter()
                message = loco_codec.decode(sample.payload.to_bytes(), str(sample.encoding))
                newest["status"] = message
                if "cmd" in events and "loco" not in events and message.commanded[0] == expected["vx"]:
                    events["loco"] = now
                if "cmd" in events and "step" not in events and expected["vx"] and message.stepping:
                    events["step"] = now

            subs = [session.declare_subscriber(keys.velocity, on_velocity),
                    session.declare_subscriber(keys.loco_status, on_loco)]
            browser.goto(f"http://127.0.0.1:{port}/")
            browser.wait("window.zensim && zensim.sceneReady && zensim.status && zensim.status.loco", 90, "the page")
            browser.click("btn-stand")
            wait_for(lambda: "status" in newest and newest["status"].walking, 60, "the robot standing")
            to_cmd: list[float] = []
            to_loco: list[float] = []
            cmd_to_loco: list[float] = []
            to_stepping: list[float] = []
            c0, l0, v0, t0 = cpu_s(sim.pid), cpu_s(loco.pid), cpu_s(viz.pid), time.monotonic()
            for i in range(2 * args.presses):
                down = i % 2 == 0
                expected["vx"] = 0.5 if down else 0.0
                time.sleep(args.hold_s if not down else 0.5)  # let the previous status settle
                if down:  # from standing still: the feet planted again after the last release
                    wait_for(lambda: not newest["status"].stepping, 20, "the feet planted", interval_s=0.01)
                events.clear()
                pressed = time.perf_counter()
                browser.key("w", down=down)
                wait_for(lambda: "loco" in events, 10, "the command in state/loco", interval_s=0.001)
                to_cmd.append(1000 * (events["cmd"] - pressed))
                to_loco.append(1000 * (events["loco"] - pressed))
                cmd_to_loco.append(1000 * (events["loco"] - events["cmd"]))
                if down:
                    wait_for(lambda: "step" in events, 10, "the feet stepping", interval_s=0.001)
                    to_stepping.append(1000 * (events["step"] - pressed))
            elapsed = time.monotonic() - t0
            for sub in subs:
                sub.undeclare()
            results["key_to_cmd_velocity"] = summary(to_cmd)
            results["key_to_state_loco"] = summary(to_loco)
            results["cmd_velocity_to_state_loco"] = summary(cmd_to_loco)
            results["key_to_stepping"] = summary(to_stepping)
            results["cpu_pct"] = {name: round(100 * (cpu_s(p.pid) - c) / elapsed, 1)
                                  for name, p, c in (("sim", sim, c0), ("loco", loco, l0), ("viz", viz, v0))}
    finally:
        procs.stop_all()
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
