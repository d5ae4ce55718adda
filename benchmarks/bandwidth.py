"""Bytes per second per robot and per topic at the default rates, read from the wire; msgpack vs JSON.

    .venv/bin/python benchmarks/bandwidth.py [--seconds 5]

Starts a `zensim router`, a `zensim sim` (floating G1) and a `zensim bridge` for one robot as real
processes; a plain client subscribes to `zensim/{robot}/**` and counts every sample's payload
bytes per key (what the services put: msgpack). Each sample is also decoded with its topic's message
type and encoded as JSON, for the JSON column. Payload bytes only: zenoh's own framing (a few tens of
bytes per sample, less when batched) comes on top.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections import defaultdict

import zenoh

from harness import Processes, free_port, is_alive, plain_client, wait_for
from zensim.schemas import Codec, Keys, topics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = f"bw{os.getpid()}"
    keys = Keys(robot)
    routers = Processes(dict(os.environ, ZENSIM_ZENOH_LISTEN=endpoint, ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
                             ZENSIM_LOG_LEVEL="WARNING"))
    routers.zensim("router")
    procs = Processes(dict(os.environ, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
                           ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_ROBOT_ID=robot, ZENSIM_LOG_LEVEL="WARNING"))
    publications = {keys.of(t): t for t in topics.TOPICS if t.kind == "publication" and t.message is not None
                    and "{" not in t.key}
    codecs = {key: Codec(t.message_type()) for key, t in publications.items()}
    lock = threading.Lock()
    count: dict[str, int] = defaultdict(int)
    msgpack_bytes: dict[str, int] = defaultdict(int)
    json_bytes: dict[str, int] = defaultdict(int)
    recording = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        if not recording.is_set():
            return
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        codec = codecs.get(key)
        as_json = len(codec.encode(codec.decode(data, str(sample.encoding)), "json")) if codec else 0
        with lock:
            count[key] += 1
            msgpack_bytes[key] += len(data)
            json_bytes[key] += as_json

    try:
        with plain_client(endpoint) as session:
            sub = session.declare_subscriber(keys.everything, on_sample)
            procs.zensim("sim")
            procs.zensim("bridge")
            wait_for(lambda: is_alive(session, keys.alive("bridge")) and is_alive(session, keys.alive("sim")), 60,
                     "sim and bridge")
            time.sleep(2.0)
            recording.set()
            start = time.monotonic()
            time.sleep(args.seconds)
            recording.clear()
            wall = time.monotonic() - start
            sub.undeclare()
    finally:
        procs.stop_all()
        routers.stop_all()
    print(f"one G1, sim + bridge at default rates, {args.seconds:g} s; payload bytes only")
    print("| key | msgs/s | bytes/msg msgpack | kB/s msgpack | kB/s JSON | JSON / msgpack |")
    print("|---|---|---|---|---|---|")
    total_mp = total_js = 0.0
    for key in sorted(count):
        rate, mp, js = count[key] / wall, msgpack_bytes[key] / wall, json_bytes[key] / wall
        total_mp, total_js = total_mp + mp, total_js + js
        short = key.removeprefix(keys.root + "/")
        ratio = f"{js / mp:.2f}" if js else "n/a"
        print(f"| {short} | {rate:.1f} | {msgpack_bytes[key] / count[key]:.0f} | {mp / 1e3:.1f} | "
              f"{js / 1e3:.1f} | {ratio} |")
    print(f"| **all** | | | **{total_mp / 1e3:.1f}** | **{total_js / 1e3:.1f}** | {total_js / total_mp:.2f} |")


if __name__ == "__main__":
    main()
