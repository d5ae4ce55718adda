"""Many G1s: one world (`zensim sim --world`) vs one `zensim sim` process per robot, side by side.

For each robot count, first one world holding every robot, then one process per robot, each behind
the same `zensim router`, while a plain client commands every robot at 100 Hz (pre-encoded motor
commands, as a controller would send them). Reported per setup:

- worst 1 s RTF: the smallest sim-time advance over any 1 s of wall time, per robot, worst robot
  (from each robot's SimStatus, 10 Hz; arrival time at the client);
- states: state/joints delivered to the client per robot per second (min and mean over robots);
- mean RTF: sim time over the whole run per wall second (slowest robot);
- sim CPU: cores the sim process(es) used (user + system time / wall time), and per real-time
  second (CPU / mean RTF: what N robots cost, less dependent on how busy the shared machine is);
- the 1-minute load average at the end of the run (the machine is shared).

    .venv/bin/python benchmarks/many_robots.py --counts 1,4,8,16,32 --seconds 6

Runs by hand (minutes); the machine is shared, so compare the two columns of one run only.
"""

from __future__ import annotations

import argparse
import bisect
import math
import os
import threading
import time
from pathlib import Path

import msgspec
import zenoh

from harness import Processes, cpu_s, free_port, plain_client, thread_cpu_s, wait_for
from zensim.robots import robot_files
from zensim.robots.builder import build
from zensim.schemas import Keys, MotorCommand, SimStatus

GRID_M = 2.0
"""Robots stand on a square grid this far apart: they never touch, so contacts cost what standing costs."""
COMMAND_HZ = 100.0
WINDOW_S = 1.0


class Watcher:
    """Counts every robot's state/joints and keeps every SimStatus (arrival time, sim time): no decode but status."""

    def __init__(self, session: zenoh.Session, ids: list[str]) -> None:
        self.ids = set(ids)
        self.counts: dict[str, int] = dict.fromkeys(ids, 0)
        self.status: dict[str, list[tuple[float, float]]] = {i: [] for i in ids}
        self.recording = False
        decoder = msgspec.msgpack.Decoder(SimStatus)
        json_decoder = msgspec.json.Decoder(SimStatus)

        def on_joints(sample: zenoh.Sample) -> None:
            if self.recording:
                robot = str(sample.key_expr).split("/")[1]
                if robot in self.counts:
                    self.counts[robot] += 1

        def on_status(sample: zenoh.Sample) -> None:
            robot = str(sample.key_expr).split("/")[1]
            if robot not in self.status:
                return
            data = sample.payload.to_bytes()
            status = json_decoder.decode(data) if data[:1] == b"{" else decoder.decode(data)
            self.status[robot].append((time.monotonic(), status.sim_time_s))

        self._subs = [session.declare_subscriber("zensim/*/state/joints", on_joints),
                      session.declare_subscriber("zensim/*/state/sim", on_status)]

    def all_seen(self) -> bool:
        return all(self.status[i] for i in self.ids)

    def worst_rtf(self, start: float, end: float) -> float:
        """Smallest sim-time advance per wall second over any WINDOW_S window in [start, end], any robot."""
        worst = math.inf
        for samples in self.status.values():
            samples = [s for s in samples if start <= s[0] <= end]
            times = [s[0] for s in samples]
            for i, (t0, sim0) in enumerate(samples):
                j = bisect.bisect_left(times, t0 + WINDOW_S, i + 1)
                if j >= len(samples):
                    break
                t1, sim1 = samples[j]
                worst = min(worst, (sim1 - sim0) / (t1 - t0))
        return worst

    def mean_rtf(self, start: float, end: float) -> float:
        """Sim-time advance over the whole of [start, end] per wall second, slowest robot."""
        rates = []
        for samples in self.status.values():
            inside = [s for s in samples if start <= s[0] <= end]
            if len(inside) >= 2:
                rates.append((inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0]))
        return min(rates) if rates else math.nan

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


class Commander:
    """Publishes each robot's default-pose command at COMMAND_HZ from one thread (bytes encoded once)."""

    def __init__(self, session: zenoh.Session, ids: list[str], payload: bytes) -> None:
        self._stop = threading.Event()
        publishers = [session.declare_publisher(Keys(i).motors, encoding=zenoh.Encoding("application/msgpack"))
                      for i in ids]

        def run() -> None:
            period, next_t = 1.0 / COMMAND_HZ, time.monotonic()
            while not self._stop.is_set():
                for pub in publishers:
                    pub.put(payload)
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))
            for pub in publishers:
                pub.undeclare()

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def world_file(path: Path, ids: list[str]) -> Path:
    side = math.ceil(math.sqrt(len(ids)))
    rows = "".join(f'[[robots]]\nid = "{rid}"\nxy = [{GRID_M * (k % side)}, {GRID_M * (k // side)}]\n\n'
                   for k, rid in enumerate(ids))
    path.write_text(f'id = "{ids[0]}-world"\n\n{rows}')
    return path


def measure(setup: str, n: int, seconds: float, endpoint: str, session: zenoh.Session, payload: bytes,
            commands: bool) -> dict[str, float] | None:
    tag = f"{setup[0]}{n}x{os.getpid() % 1000}"
    ids = [f"{tag}r{k}" for k in range(n)]
    env = dict(os.environ, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    procs = Processes(env)
    watcher = Watcher(session, ids)
    commander = None
    try:
        if setup == "world":
            sims = [procs.zensim("sim", "--world", str(world_file(procs.dir / "world.toml", ids)))]
        else:
            sims = [procs.zensim("sim", "--robot-id", rid) for rid in ids]
        wait_for(lambda: watcher.all_seen() or not all(s.alive() for s in sims), 60 + 3 * n, f"{n} robots up")
        if not all(s.alive() for s in sims):
            print(f"  {setup} {n}: a sim exited: {next(s for s in sims if not s.alive()).log()[-800:]}")
            return None
        if commands:
            commander = Commander(session, ids, payload)
        time.sleep(2.0)  # settle: every robot standing, commands flowing
        cpu0 = sum(cpu_s(s.pid) for s in sims)
        threads0 = thread_cpu_s(sims[0].pid)
        start = time.monotonic()
        watcher.recording = True
        time.sleep(seconds)
        watcher.recording = False
        end = time.monotonic()
        cpu = (sum(cpu_s(s.pid) for s in sims) - cpu0) / (end - start)
        threads = {name: (used - threads0.get(name, 0.0)) / (end - start) for name, used in thread_cpu_s(sims[0].pid).items()}
        rates = [watcher.counts[i] / (end - start) for i in ids]
        return {"rtf": watcher.worst_rtf(start, end), "mean_rtf": watcher.mean_rtf(start, end), "rate_min": min(rates),
                "rate_mean": sum(rates) / n, "cpu": cpu, "load": os.getloadavg()[0], "threads": threads}
    finally:
        if commander is not None:
            commander.stop()
        watcher.close()
        procs.stop_all()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--counts", default="1,4,8,16,32,64")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--max-procs", type=int, default=64, help="largest count run as one process per robot")
    parser.add_argument("--no-commands", action="store_true", help="no client commanding the robots")
    parser.add_argument("--only", choices=("world", "procs"), help="run one setup only")
    parser.add_argument("--threads", action="store_true", help="also print where the sim's CPU went, by thread")
    args = parser.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    robot = build(robot_files("unitree_g1"), "floating")
    payload = msgspec.msgpack.encode(MotorCommand(q=robot.default_q.tolist()))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    routers = Processes(dict(os.environ, ZENSIM_ZENOH_LISTEN=endpoint, ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
                             ZENSIM_LOG_LEVEL="WARNING"))
    routers.zensim("router")
    try:
        with plain_client(endpoint) as session:
            print(f"{os.cpu_count()} cores; {args.seconds:g} s per run; commands at {COMMAND_HZ:g} Hz per robot: "
                  f"{not args.no_commands}")
            print("| G1s | setup | worst 1 s RTF | mean RTF | states/robot/s min (mean) | sim CPU, cores "
                  "| cores per real-time s | load avg |")
            print("|---|---|---|---|---|---|---|---|")
            for n in counts:
                for setup in ("world", "procs"):
                    if args.only and setup != args.only:
                        continue
                    if setup == "procs" and n > args.max_procs:
                        print(f"| {n} | procs | not run (--max-procs {args.max_procs}) | | |", flush=True)
                        continue
                    r = measure(setup, n, args.seconds, endpoint, session, payload, not args.no_commands)
                    if r is None:
                        print(f"| {n} | {setup} | failed | | |", flush=True)
                        continue
                    print(f"| {n} | {setup} | {r['rtf']:.3f} | {r['mean_rtf']:.3f} | {r['rate_min']:.1f} "
                          f"({r['rate_mean']:.1f}) | {r['cpu']:.2f} | {r['cpu'] / r['mean_rtf']:.2f} | {r['load']:.1f} |",
                          flush=True)
                    if args.threads:
                        busiest = sorted(r["threads"].items(), key=lambda kv: -kv[1])[:6]
                        print(f"  ({setup} {n}: cores by thread of {'the world' if setup == 'world' else 'one sim'}: "
                              + ", ".join(f"{name} {used:.2f}" for name, used in busiest) + ")", flush=True)
    finally:
        routers.stop_all()


if __name__ == "__main__":
    main()
