"""How fast `zensim viz` gets poses to browsers, and what it costs.

Runs a router, sim (fixed mode), bridge and viz as real processes on
loopback, then measures:

  1. pose frames per second drawn by a headless chromium (software WebGL:
     this is the browser's drawing rate, capped by the viz at rate_hz);
  2. pose frames per second reaching a fast client (a websocket client that
     acks at once), i.e. the viz's own rate, and the viz's CPU meanwhile;
  3. slider -> cmd/joints and slider -> first sim state movement latency,
     driving the slider through the page over the DevTools protocol;
  4. the viz's resident memory before and after the streaming;
  5. with --soak-minutes N: N minutes more of streaming to chromium, a fast
     client and a slow one (acks after 0.5 s), sampling the viz's resident
     memory every 30 s, and the slow client's frame age at the end (a
     growing lag would show there).

    .venv/bin/python benchmarks/viz_rates.py [--seconds 10] [--rate-hz 60] [--soak-minutes 0]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import sys
import threading
import time

import zenoh
from tornado.websocket import websocket_connect

from harness import behind_private_router, cpu_s, free_port, plain_client, rss_mb, test_scaffolding, wait_for
from zensim.schemas import Codec, JointState, JointTargets, Keys

Browser = test_scaffolding("browser").Browser

class AckingClient:
    """A websocket client that acks every frame after `ack_delay_s`: 0 is the most a browser could take."""

    def __init__(self, url: str, ack_delay_s: float = 0.0) -> None:
        self.ack_delay_s = ack_delay_s
        self.frames = 0
        self.last_frame_at = 0.0
        self.loop = asyncio.new_event_loop()
        self.stop = False
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(self._run(url),), daemon=True)
        self.thread.start()

    async def _run(self, url: str) -> None:
        ws = await websocket_connect(url, max_message_size=64 * 1024 * 1024)
        while not self.stop:
            message = await ws.read_message()
            if message is None:
                return
            if isinstance(message, bytes) and message[0] == 2:
                self.frames += 1
                self.last_frame_at = time.monotonic()
                if self.ack_delay_s:
                    await asyncio.sleep(self.ack_delay_s)
                await ws.write_message(json.dumps({"type": "ack"}))
        ws.close()


def soak(port: int, pid: int, minutes: float) -> dict[str, object]:
    """Stream to a fast and a slow client (beside the open chromium page) and watch the viz's memory."""
    url = f"ws://127.0.0.1:{port}/ws"
    fast, slow = AckingClient(url), AckingClient(url, ack_delay_s=0.5)
    wait_for(lambda: fast.frames > 0 and slow.frames > 0, 10, "frames at both clients")
    start, c0 = time.monotonic(), cpu_s(pid)
    samples = [(0.0, rss_mb(pid))]
    while time.monotonic() - start < minutes * 60:
        time.sleep(min(30.0, max(0.0, minutes * 60 - (time.monotonic() - start))))
        samples.append((time.monotonic() - start, rss_mb(pid)))
        print(f"soak {samples[-1][0]:7.0f} s: viz RSS {samples[-1][1]:.1f} MB", file=sys.stderr, flush=True)
    elapsed = time.monotonic() - start
    fast_rate, slow_rate = fast.frames / elapsed, slow.frames / elapsed
    slow_age = time.monotonic() - slow.last_frame_at
    fast.stop = slow.stop = True
    later_half = [mb for t, mb in samples if t >= elapsed / 2]
    return {
        "minutes": round(elapsed / 60, 1),
        "viz_rss_mb_first_last_max": [round(samples[0][1], 1), round(samples[-1][1], 1), round(max(mb for _, mb in samples), 1)],
        "viz_rss_mb_spread_second_half": round(max(later_half) - min(later_half), 1),
        "viz_cpu_pct": round(100 * (cpu_s(pid) - c0) / elapsed, 1),
        "fast_client_frames_per_s": round(fast_rate, 1),
        "slow_client_frames_per_s": round(slow_rate, 2),
        "slow_client_s_since_last_frame": round(slow_age, 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each rate measurement")
    parser.add_argument("--rate-hz", type=float, default=60.0, help="the viz's rate_hz")
    parser.add_argument("--moves", type=int, default=20, help="slider moves for the latency figure")
    parser.add_argument("--soak-minutes", type=float, default=0.0, help="minutes of streaming for the memory soak")
    args = parser.parse_args()

    robot_id = f"bench{os.getpid()}"
    keys = Keys(robot_id)
    port = free_port()
    procs, endpoint = behind_private_router(robot_id)
    results: dict[str, object] = {}
    try:
        procs.zensim("sim", "--mode", "fixed")
        procs.zensim("bridge")
        viz = procs.zensim("viz", "--port", str(port), "--rate-hz", str(args.rate_hz))
        wait_for(lambda: "viz up" in viz.log() and "description of" in viz.log(), 30, "viz with a description")
        with plain_client(endpoint) as session, Browser() as browser:
            browser.goto(f"http://127.0.0.1:{port}/")
            browser.wait("window.zensim && zensim.sceneReady", 60, "the robot drawn")
            rss0 = rss_mb(viz.pid)

            # 1. chromium alone
            f0, c0, t0 = browser.eval("zensim.framesApplied"), cpu_s(viz.pid), time.monotonic()
            time.sleep(args.seconds)
            f1, c1, t1 = browser.eval("zensim.framesApplied"), cpu_s(viz.pid), time.monotonic()
            results["chromium_frames_per_s"] = round((f1 - f0) / (t1 - t0), 1)
            results["viz_cpu_pct_chromium_only"] = round(100 * (c1 - c0) / (t1 - t0), 1)

            # 2. a fast client beside chromium
            fast = AckingClient(f"ws://127.0.0.1:{port}/ws")
            wait_for(lambda: fast.frames > 0, 10, "frames at the fast client")
            n0, f0, c0, t0 = fast.frames, browser.eval("zensim.framesApplied"), cpu_s(viz.pid), time.monotonic()
            time.sleep(args.seconds)
            n1, f1, c1, t1 = fast.frames, browser.eval("zensim.framesApplied"), cpu_s(viz.pid), time.monotonic()
            results["fast_client_frames_per_s"] = round((n1 - n0) / (t1 - t0), 1)
            results["chromium_frames_per_s_meanwhile"] = round((f1 - f0) / (t1 - t0), 1)
            results["viz_cpu_pct_at_rate"] = round(100 * (c1 - c0) / (t1 - t0), 1)
            fast.stop = True

            # 3. slider latency
            names = browser.eval("zensim.robot.joints.map(j => j.name)")
            joint = "left_elbow_joint"
            index = names.index(joint)
            events: dict[str, float] = {}
            state: dict[str, JointState] = {}
            js_codec, jt_codec = Codec(JointState), Codec(JointTargets)

            def on_cmd(sample: zenoh.Sample) -> None:
                msg = jt_codec.decode(sample.payload.to_bytes())
                if joint in msg.names and "cmd" not in events:
                    events["cmd"] = time.perf_counter()

            def on_state(sample: zenoh.Sample) -> None:
                msg = js_codec.decode(sample.payload.to_bytes())
                state["js"] = msg
                ref = events.get("q_before")
                if ref is not None and "moved" not in events and abs(msg.q[index] - ref) > 0.005:
                    events["moved"] = time.perf_counter()

            subs = [session.declare_subscriber(keys.joint_targets, on_cmd),
                    session.declare_subscriber(keys.joints, on_state)]
            to_cmd, to_move = [], []
            wait_for(lambda: "js" in state, 10, "joint states")
            for i in range(args.moves):
                target = 0.3 if i % 2 == 0 else 0.8
                wait_for(lambda: abs(state["js"].q[index] - (0.8 if i % 2 == 0 else 0.3)) < 0.02 or i == 0, 10,
                         "the joint to settle")
                time.sleep(0.2)
                events.clear()
                events["q_before"] = state["js"].q[index]
                t_start = time.perf_counter()
                browser.set_slider(f"slider-{joint}", target)
                wait_for(lambda: "cmd" in events and "moved" in events, 10, "the move", interval_s=0.001)
                to_cmd.append(1000 * (events["cmd"] - t_start))
                to_move.append(1000 * (events["moved"] - t_start))
            for sub in subs:
                sub.undeclare()

            def summary(values: list[float]) -> dict[str, float]:
                ordered = sorted(values)
                return {"p50_ms": round(statistics.median(ordered), 1),
                        "p95_ms": round(ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))], 1),
                        "max_ms": round(ordered[-1], 1)}

            results["slider_to_cmd_joints"] = summary(to_cmd)
            results["slider_to_sim_motion"] = summary(to_move)
            results["viz_rss_mb_before_after"] = [round(rss0, 1), round(rss_mb(viz.pid), 1)]
            if args.soak_minutes > 0:
                results["soak"] = soak(port, viz.pid, args.soak_minutes)
    finally:
        procs.stop_all()
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
