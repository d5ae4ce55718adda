"""World lockstep: one `world/advance` round trip carries every robot's command and returns every robot's states.

    .venv/bin/python benchmarks/world_lockstep.py [--counts 1,8] [--advances 400]

For each robot count, starts a router, a world of that many G1s (`zensim sim --world ... --clock
lockstep`, 10 steps per advance) and an echo process as real processes on loopback; this process is
the controller. Measured in one run, per count:

- world/advance: round trip p50 / p99 (msgpack; a new command for every robot at every advance),
  advances/s, sim seconds per wall second and robot-steps per second;
- physics alone: World.step of the same 10 steps for the same robots in this process (no network),
  one after each advance;
- bare zenoh get of the same payload sizes (request and reply bytes of a world/advance) to the echo
  process, one after each advance (side by side: both see the same machine): p50;
- overhead ratio: (advance p50 - physics p50) / bare get p50 (1.0 = no cost beyond zenoh's own); both
  round trips end when the reply's bytes are in hand (the bare get's are never decoded), so decoding the
  reply into messages, the controller's own work, is left out and shown apart: decode, ms.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zenoh

from harness import Processes, free_port, is_alive, plain_client, wait_for
from zensim.schemas import Codec, Keys, MotorCommand, WorldAdvanceReply, WorldAdvanceRequest
from zensim.sim.settings import SimSettings
from zensim.sim.service import load_world

ECHO = """
import threading, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%(endpoint)s"]')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/timeout_ms", "-1")
replies = {}
def on_query(q):
    size = int(str(q.parameters).split("=")[1])
    data = replies.get(size) or replies.setdefault(size, bytes(size))
    q.reply(q.key_expr, data)
with zenoh.open(conf) as s:
    qbl = s.declare_queryable("%(root)s/bench/echo", on_query)
    token = s.liveliness().declare_token("%(root)s/bench/alive")
    threading.Event().wait()
"""
LOCKSTEP_STEPS = 10


def world_file(path: Path, ids: list[str], world_id: str) -> Path:
    side = math.ceil(math.sqrt(len(ids)))
    path.write_text(f'id = "{world_id}"\n' + "".join(
        f'[[robots]]\nid = "{rid}"\nxy = [{2.0 * (k % side)}, {2.0 * (k // side)}]\n' for k, rid in enumerate(ids)))
    return path


def percentiles(samples: list[float]) -> tuple[float, float]:
    return float(np.percentile(samples, 50)), float(np.percentile(samples, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--counts", default="1,8")
    parser.add_argument("--advances", type=int, default=400)
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    routers = Processes(dict(os.environ, ZENSIM_ZENOH_LISTEN=endpoint, ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
                             ZENSIM_LOG_LEVEL="WARNING"))
    routers.zensim("router")
    procs = Processes(env)
    root = f"zensim/wl{os.getpid()}"
    procs.start("echo", [sys.executable, "-c", ECHO % {"endpoint": endpoint, "root": root}])
    request_codec, reply_codec = Codec(WorldAdvanceRequest), Codec(WorldAdvanceReply)
    msgpack = zenoh.Encoding("application/msgpack")
    print(f"{os.cpu_count()} cores; {args.advances} advances of {LOCKSTEP_STEPS} steps per count")
    print("| G1s | advance p50 / p99, ms | advances/s | sim s per wall s | robot-steps/s | physics alone p50, ms "
          "| bare get p50, ms (req/reply bytes) | overhead ratio | decode, ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    try:
        with plain_client(endpoint) as session:
            wait_for(lambda: is_alive(session, f"{root}/bench/alive"), 30, "the echo process")
            for n in (int(c) for c in args.counts.split(",")):
                ids = [f"wl{os.getpid()}n{n}r{k}" for k in range(n)]
                world_id = f"wl{os.getpid()}n{n}"
                path = world_file(Path(tempfile.mkdtemp()) / "world.toml", ids, world_id)
                sim = procs.zensim("sim", "--world", str(path), "--clock", "lockstep",
                                   "--lockstep-steps", str(LOCKSTEP_STEPS))
                wait_for(lambda: is_alive(session, Keys(ids[-1]).alive("sim")), 60 + 3 * n, "the world up")
                key = Keys(world_id).world_advance
                world, _ = load_world(SimSettings(world=str(path)))  # the same robots, for the physics alone
                default_q = next(iter(world.sims.values())).robot.default_q
                trips: list[float] = []
                bare: list[float] = []
                physics: list[float] = []
                advancing = decoding = 0.0
                for i in range(args.advances + 20):
                    q = (default_q + 0.1 * math.sin(0.05 * i)).tolist()
                    request = WorldAdvanceRequest(commands={rid: MotorCommand(q=q) for rid in ids})
                    payload = request_codec.encode(request)
                    t0 = time.perf_counter()
                    got = list(session.get(key, payload=payload, encoding=msgpack, timeout=10))
                    body = got[0].ok.payload.to_bytes()
                    replied = time.perf_counter()  # the reply's bytes are here: decoding them is the client's own work
                    reply = reply_codec.decode(body, "application/msgpack")
                    t1 = time.perf_counter()
                    decoding += t1 - replied
                    assert reply.ok, reply.error
                    # The same sizes to the echo process at once, so both round trips see the same machine.
                    echo = list(session.get(f"{root}/bench/echo?size={len(body)}", payload=bytes(len(payload)), timeout=10))
                    assert len(echo[0].ok.payload.to_bytes()) == len(body)
                    t2 = time.perf_counter()
                    world.step(LOCKSTEP_STEPS)  # and the physics of one advance, here, alone
                    if i >= 20:
                        trips.append(replied - t0)
                        bare.append(t2 - t1)
                        physics.append(time.perf_counter() - t2)
                        advancing += replied - t0
                    sizes = (len(payload), len(body))
                sim.stop()
                p50, p99 = percentiles(trips)
                phys50 = float(np.percentile(physics, 50))
                bare50 = float(np.percentile(bare, 50))
                rate = args.advances / advancing  # advances per second of advancing (the echo gets left out)
                print(f"| {n} | {p50 * 1e3:.2f} / {p99 * 1e3:.2f} | {rate:.0f} | {rate * LOCKSTEP_STEPS * 0.002:.1f} | "
                      f"{rate * LOCKSTEP_STEPS * n:.0f} | {phys50 * 1e3:.2f} | {bare50 * 1e3:.2f} ({sizes[0]}/{sizes[1]}) | "
                      f"{(p50 - phys50) / bare50:.2f} | {decoding / (args.advances + 20) * 1e3:.3f} |", flush=True)
    finally:
        procs.stop_all()
        routers.stop_all()


if __name__ == "__main__":
    main()
