"""The router fan-out cost with real routers: a `zensim router` per host (network namespace), in a mesh.

    .venv/bin/python benchmarks/router_mesh.py --hosts 3 --steps 2x1,2x2,2x4,2x8 --seconds 6

Needs root and iproute2 (the hosts are namespaces: tests/netns.py, loaded by path). Each host runs:

- one `zensim router` listening on its own address, connected to every other host's router (each
  pair once: routers never find each other by themselves), so the routers form a full mesh;
- per step `WxR` of `--steps`, W `zensim sim --world FILE.toml` processes, clients of that router,
  each world holding R floating G1s (ids `h{host}w{world}r{k}`, on a 2 m grid so they never touch);
- `--subscribers-per-host` subscribers (this file run with `--subscriber`, plain zenoh clients of
  their own host's router) that watch every robot of the next `--watch-hosts` hosts: every sample
  they count has crossed two routers and one router-to-router link. Each also watches one robot of
  its own host (one router, no mesh) as a baseline. With several subscribers per host the router
  there fans each sample out to all of them; with `--watch-hosts 2` the sims' router sends each
  sample down two router links.

Per step, two windows with the same sims running:

1. status: the subscribers take only `state/sim` (10 Hz per robot) of their remote robots, which
   gives each world's RTF. A zenoh client sends nothing that nobody subscribed to (the "inside
   hosts" bytes show it), so this is the routers' cost with the sims up and almost nothing to carry;
2. joints: the subscribers add `state/joints` (100 Hz of sim time per robot) of every watched robot.

Router CPU is read from /proc (user + system time) over each window; the joints window's extra CPU
over the status window, summed over the routers, per delivered sample, is what delivering one sample
across the mesh costs (two routers on its path). Latency: zenoh routers stamp every sample that
arrives without a timestamp (zenoh's default for routers; the sims send none), so a sample's
timestamp is when the sims' own router took it in; the subscriber subtracts it from its wall clock in
its callback (all namespaces share one machine clock). That is router in -> router -> the
subscriber's Python callback, without the sim -> first router hop on loopback; the benchmark checks
that every remote sample was stamped by its sims' router. Delivered / published compares the samples
counted with each robot's `seq` advance over the window (a slow sim publishes fewer than 100 a
second: that is the sim, not the mesh). Bytes: the hosts' eth0 transmit counters (what crossed
between hosts) and lo (inside hosts: clients and their router, which talk over loopback even on the
host's own address), headers included.

Runs by hand (a few minutes). Prints a markdown table per window; `--json PATH` also writes every figure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from harness import cpu_s, plain_client, test_scaffolding, wait_for
from zensim.schemas import Codec, JointState, Keys, SimStatus

ZENOH_PORT = 7447
GRID_M = 2.0
"""Robots stand on a square grid this far apart: they never touch, so contacts cost what standing costs."""
SETTLE_S = 2.0
"""After every robot is seen, before a window starts: the sims are standing and the routers warm."""
REPLY_TIMEOUT_S = 20.0


# ----- the subscriber: this file run with --subscriber, inside a host's namespace -----

class Watch:
    """What one subscriber process counts for one robot during a window."""

    def __init__(self) -> None:
        self.n = 0
        self.bytes = 0
        self.first_seq = self.last_seq = -1
        self.first_status: tuple[float, float] | None = None
        """(wall time, sim time) of the first SimStatus in the window; `last_status` of the newest."""
        self.last_status: tuple[float, float] | None = None

    def rtf(self) -> float | None:
        """Sim time per wall second over the window (from the robot's SimStatus at arrival)."""
        if self.first_status is None or self.last_status is None or self.last_status[0] <= self.first_status[0]:
            return None
        return (self.last_status[1] - self.first_status[1]) / (self.last_status[0] - self.first_status[0])


class Subscriber:
    """A plain zenoh client that watches remote robots (and local baseline ones) and reports per window."""

    def __init__(self, session: zenoh.Session, remote: list[str], local: list[str]) -> None:
        self.session = session
        self.remote, self.local = remote, local
        self.lock = threading.Lock()
        self.recording = False
        self.watch = {rid: Watch() for rid in remote + local}
        self.latency_ms: dict[str, list[float]] = {"remote": [], "local": []}
        self.stampers: dict[str, set[str]] = {"remote": set(), "local": set()}
        """Ids of the routers that stamped the samples: remote samples must carry the remote host's router's."""
        self.unstamped = 0
        self.started = time.time()
        self.seen_status: set[str] = set()
        self.seen_joints: set[str] = set()
        self.subs: list[Any] = []
        self.joints_codec, self.status_codec = Codec(JointState), Codec(SimStatus)
        for rid in remote:
            self.subs.append(session.declare_subscriber(Keys(rid).sim_status, self._on_status))

    def subscribe_joints(self) -> None:
        for rid in self.remote + self.local:
            self.subs.append(self.session.declare_subscriber(Keys(rid).joints, self._on_joints))

    def _on_status(self, sample: zenoh.Sample) -> None:
        now = time.time()
        rid = str(sample.key_expr).split("/")[1]
        status = self.status_codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        with self.lock:
            self.seen_status.add(rid)
            if self.recording:
                watch = self.watch[rid]
                watch.last_status = (now, status.sim_time_s)
                watch.first_status = watch.first_status or watch.last_status

    def _on_joints(self, sample: zenoh.Sample) -> None:
        now_ns = time.time_ns()
        rid = str(sample.key_expr).split("/")[1]
        data = sample.payload.to_bytes()
        state = self.joints_codec.decode(data, str(sample.encoding))
        stamp = sample.timestamp
        with self.lock:
            self.seen_joints.add(rid)
            if not self.recording:
                return
            watch = self.watch[rid]
            watch.n += 1
            watch.bytes += len(data)
            watch.last_seq = state.seq
            if watch.first_seq < 0:
                watch.first_seq = state.seq
            if stamp is None:
                self.unstamped += 1
                return
            # The stamp is the router's hybrid logical clock: the machine's wall clock, since the Unix epoch.
            sent_ns = stamp.get_time_as_ntp64().as_nanos()
            where = "remote" if rid in self.remote else "local"
            self.latency_ms[where].append(round((now_ns - sent_ns) / 1e6, 3))
            self.stampers[where].add(str(stamp.get_id()))

    def start_window(self) -> None:
        with self.lock:
            self.watch = {rid: Watch() for rid in self.remote + self.local}
            self.latency_ms = {"remote": [], "local": []}
            self.stampers, self.unstamped = {"remote": set(), "local": set()}, 0
            self.started = time.time()
            self.recording = True

    def report(self) -> dict[str, Any]:
        with self.lock:
            self.recording = False
            window_s = time.time() - self.started
            robots = {}
            for rid, w in self.watch.items():
                published = w.last_seq - w.first_seq + 1 if w.first_seq >= 0 else 0
                robots[rid] = {"remote": rid in self.remote, "delivered": w.n, "published": published,
                               "bytes": w.bytes, "rtf": w.rtf()}
            return {"window_s": window_s, "robots": robots, "latency_ms": self.latency_ms,
                    "stampers": {k: sorted(v) for k, v in self.stampers.items()}, "unstamped": self.unstamped}


def seen_in_time(condition: Any, timeout_s: float) -> bool:
    try:
        return bool(wait_for(condition, timeout_s, "robots", interval_s=0.05))
    except TimeoutError:
        return False


def subscriber_main(endpoint: str, remote: list[str], local: list[str]) -> int:
    """Answer one JSON line per request on stdin: up, wait_status, joints, start, report, quit."""
    def reply(**fields: Any) -> None:
        sys.stdout.write(json.dumps(fields) + "\n")
        sys.stdout.flush()

    with plain_client(endpoint) as session:
        sub = Subscriber(session, remote, local)
        reply(ev="up")
        for line in sys.stdin:
            op = json.loads(line).get("op")
            if op == "wait_status":
                ok = seen_in_time(lambda: sub.seen_status >= set(remote), 120)
                reply(ev=op, ok=ok, missing=sorted(set(remote) - sub.seen_status))
            elif op == "joints":
                sub.subscribe_joints()
                ok = seen_in_time(lambda: sub.seen_joints >= set(remote + local), 30)
                reply(ev=op, ok=ok, missing=sorted(set(remote + local) - sub.seen_joints))
            elif op == "start":
                sub.start_window()
                reply(ev=op)
            elif op == "report":
                reply(ev=op, **sub.report())
            elif op == "quit":
                break
        for s in sub.subs:
            s.undeclare()
    return 0


# ----- the benchmark: namespaces, routers, worlds, subscribers -----

class SubscriberProcess:
    """A subscriber process in a host's namespace, driven by JSON lines (see `subscriber_main`)."""

    def __init__(self, mesh: Mesh, host: int, name: str, remote: list[str], local: list[str]) -> None:
        self.host = host
        argv = [sys.executable, "-u", str(Path(__file__).resolve()), "--subscriber", mesh.endpoint(host),
                "--remote", ",".join(remote), "--local", ",".join(local)]
        self.process = mesh.netns.NsProcess(mesh.net, mesh.hosts[host], argv, mesh.env, mesh.log_dir, name=name,
                                            stdin=subprocess.PIPE, capture_stdout=True)
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.proc.stdout is not None
        for line in self.process.proc.stdout:
            try:
                self.lines.put(json.loads(line))
            except ValueError:
                continue

    def send(self, op: str) -> None:
        stdin = self.process.proc.stdin
        assert stdin is not None
        stdin.write((json.dumps({"op": op}) + "\n").encode())
        stdin.flush()

    def expect(self, ev: str, timeout_s: float = REPLY_TIMEOUT_S) -> dict[str, Any]:
        """The next line whose `ev` is `ev`; fails when the process exits or nothing comes in time."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                msg = self.lines.get(timeout=0.2)
            except queue.Empty:
                if not self.process.alive():
                    raise RuntimeError(f"{self.process.name} exited:\n{self.process.log()[-2000:]}") from None
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no {ev!r} from {self.process.name}") from None
                continue
            if msg.get("ev") == ev:
                return msg

    def stop(self) -> None:
        try:
            if self.process.alive():
                self.send("quit")
                self.process.proc.wait(5)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.process.stop()
        if self.process.proc.stdout is not None:
            self.process.proc.stdout.close()


def stop_all(processes: list[Any], timeout_s: float = 5.0) -> None:
    """SIGTERM every process first, then wait for all of them together for up to `timeout_s`; SIGKILL
    the process group of any that lingers."""
    for p in processes:
        if p.alive():
            p.proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    for p in processes:
        p.stop(max(0.1, deadline - time.monotonic()))
    processes.clear()


def world_file(path: Path, world_id: str, ids: list[str]) -> Path:
    side = math.ceil(math.sqrt(len(ids)))
    rows = "".join(f'[[robots]]\nid = "{rid}"\nxy = [{GRID_M * (k % side)}, {GRID_M * (k // side)}]\n\n'
                   for k, rid in enumerate(ids))
    path.write_text(f'id = "{world_id}"\n\n{rows}')
    return path


def link_tx_bytes(net: Any, host: str, link: str) -> int:
    """Bytes a link of the host has sent. eth0: traffic to other hosts; lo: traffic inside the host
    (a client connected to its own host's address talks over lo too)."""
    out = subprocess.run(["ip", "-n", net.hosts[host].netns, "-s", "-j", "link", "show", link],
                         capture_output=True, text=True, check=True, timeout=10).stdout
    return int(json.loads(out)[0]["stats64"]["tx"]["bytes"])


def percentile(values: list[float], p: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(p / 100 * len(ordered)))]


class Mesh:
    """The namespaces and one `zensim router` per host, meshed; worlds and subscribers come and go per step.

    Args:
        watch_hosts: each subscriber watches the robots of this many next hosts (1 .. hosts - 1); with
            more than 1, a sim's router sends each sample down that many router links.
        subscribers_per_host: subscriber processes per host, all watching the same robots: the router
            on their host fans each sample out to all of them.
    """

    def __init__(self, netns: Any, net: Any, env: dict[str, str], log_dir: Path, watch_hosts: int,
                 subscribers_per_host: int) -> None:
        self.netns, self.net, self.env, self.log_dir = netns, net, env, log_dir
        self.hosts = list(net.hosts)
        self.watch_hosts, self.subscribers_per_host = watch_hosts, subscribers_per_host
        self.routers: list[Any] = []
        self.sims: list[Any] = []
        self.subscribers: list[SubscriberProcess] = []

    def endpoint(self, host: int) -> str:
        return f"tcp/{self.net.address(self.hosts[host])}:{ZENOH_PORT}"

    def start_routers(self) -> None:
        for i, host in enumerate(self.hosts):
            # Each pair of routers once: host i connects to every host before it. A zenoh link carries
            # both directions, and a router whose peer is not listening yet retries by itself.
            argv = [sys.executable, "-m", "zensim", "router", "--zenoh-listen", self.endpoint(i)]
            if i:
                argv += ["--zenoh-connect", ",".join(self.endpoint(j) for j in range(i))]
            self.routers.append(self.netns.NsProcess(self.net, host, argv, self.env, self.log_dir,
                                                     name=f"router-h{i}"))

    def watched(self, host: int) -> list[int]:
        """The hosts whose robots the subscribers on `host` watch: the next `watch_hosts`, round the ring."""
        return [(host + k) % len(self.hosts) for k in range(1, self.watch_hosts + 1)]

    def start_step(self, worlds: int, per_world: int) -> None:
        """Start every world (clients of their host's router) and every subscriber."""
        ids: list[list[str]] = []
        for i, host in enumerate(self.hosts):
            ids.append([])
            for w in range(worlds):
                world = [f"h{i}w{w}r{k}" for k in range(per_world)]
                path = world_file(self.log_dir / f"h{i}w{w}-{per_world}.toml", f"h{i}w{w}", world)
                env = dict(self.env, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=self.endpoint(i))
                argv = [sys.executable, "-m", "zensim", "sim", "--world", str(path)]
                self.sims.append(self.netns.NsProcess(self.net, host, argv, env, self.log_dir, name=f"sim-h{i}w{w}"))
                ids[i] += world
        for i in range(len(self.hosts)):
            remote = [rid for h in self.watched(i) for rid in ids[h]]
            for k in range(self.subscribers_per_host):
                self.subscribers.append(SubscriberProcess(self, i, f"sub-h{i}s{k}", remote, ids[i][:1]))
        for sub in self.subscribers:
            sub.expect("up")

    def check_alive(self) -> None:
        for p in [*self.routers, *self.sims]:
            if not p.alive():
                raise RuntimeError(f"{p.name} exited ({p.proc.returncode}):\n{p.log()[-2000:]}")

    def all_subscribers(self, op: str, timeout_s: float = REPLY_TIMEOUT_S) -> list[dict[str, Any]]:
        for sub in self.subscribers:
            sub.send(op)
        return [sub.expect(op, timeout_s) for sub in self.subscribers]

    def window(self, seconds: float) -> dict[str, Any]:
        """One measured window: router and sim CPU, bytes on the links, and every subscriber's report."""
        time.sleep(SETTLE_S)
        self.check_alive()
        cpu0 = [cpu_s(r.pid) for r in self.routers]
        sims0 = sum(cpu_s(s.pid) for s in self.sims)
        eth0 = sum(link_tx_bytes(self.net, h, "eth0") for h in self.hosts)
        lo0 = sum(link_tx_bytes(self.net, h, "lo") for h in self.hosts)
        start = time.monotonic()
        self.all_subscribers("start")
        time.sleep(seconds)
        reports = self.all_subscribers("report")
        wall = time.monotonic() - start
        self.check_alive()
        for sub, report in zip(self.subscribers, reports):
            report["host"] = sub.host
        return {"wall_s": wall,
                "router_cores": [(cpu_s(r.pid) - c0) / wall for r, c0 in zip(self.routers, cpu0)],
                "sim_cores": (sum(cpu_s(s.pid) for s in self.sims) - sims0) / wall,
                "across_bytes_per_s": (sum(link_tx_bytes(self.net, h, "eth0") for h in self.hosts) - eth0) / wall,
                "inside_bytes_per_s": (sum(link_tx_bytes(self.net, h, "lo") for h in self.hosts) - lo0) / wall,
                "reports": reports, "load": os.getloadavg()[0]}

    def stop_step(self) -> None:
        for sub in self.subscribers:
            sub.stop()
        self.subscribers.clear()
        stop_all(self.sims)

    def close(self) -> None:
        self.stop_step()
        stop_all(self.routers)


def stamped_by_sims_router(mesh: Mesh, reports: list[dict[str, Any]]) -> bool | None:
    """Whether every remote sample was stamped by the router of its sims' host (so the latency starts
    there): a subscriber's remote samples carry exactly the router ids that stamp the baseline robots
    of the hosts it watches (the subscribers there see them as local). None when nothing was stamped."""
    own: dict[int, set[str]] = {}
    for rep in reports:
        own.setdefault(rep["host"], set()).update(rep["stampers"]["local"])
    if not all(own.get(h) for h in range(len(mesh.hosts))) or not all(rep["stampers"]["remote"] for rep in reports):
        return None
    if any(len(ids) != 1 for ids in own.values()):
        return False
    return all(set(rep["stampers"]["remote"]) == set().union(*(own[h] for h in mesh.watched(rep["host"])))
               for rep in reports)


def summary(mesh: Mesh, phase: str, robots: int, worlds: int, w: dict[str, Any]) -> dict[str, Any]:
    """The figures of one window, from the subscribers' reports."""
    pairs = [(r, rep["window_s"]) for rep in w["reports"] for r in rep["robots"].values() if r["remote"]]
    rates = [r["delivered"] / t for r, t in pairs]  # per (robot, subscriber) pair
    fractions = [r["delivered"] / r["published"] for r, _ in pairs if r["published"]]
    rtfs = [r["rtf"] for r, _ in pairs if r["rtf"] is not None]
    lat = [x for rep in w["reports"] for x in rep["latency_ms"]["remote"]]
    local = [x for rep in w["reports"] for x in rep["latency_ms"]["local"]]
    return {"phase": phase, "robots": robots, "worlds": worlds, "subscribers": len(mesh.subscribers),
            "watch_hosts": mesh.watch_hosts, "window_s": w["wall_s"],
            "rate_mean": sum(rates) / len(rates) if rates else 0.0, "rate_min": min(rates, default=0.0),
            "delivered_fraction_min": min(fractions, default=math.nan), "delivered_per_s": sum(rates),
            "p50_ms": percentile(lat, 50), "p99_ms": percentile(lat, 99), "latency_samples": len(lat),
            "local_p50_ms": percentile(local, 50), "local_p99_ms": percentile(local, 99),
            "router_cores": w["router_cores"], "sim_cores": w["sim_cores"],
            "worst_rtf": min(rtfs, default=math.nan), "missing_rtf": len(pairs) - len(rtfs),
            "across_mb_per_s": w["across_bytes_per_s"] / 1e6, "inside_mb_per_s": w["inside_bytes_per_s"] / 1e6,
            "load": w["load"], "stamped_by_sims_router": stamped_by_sims_router(mesh, w["reports"]),
            "unstamped": sum(rep["unstamped"] for rep in w["reports"])}


def cost_per_sample_us(status: dict[str, Any], joints: dict[str, Any]) -> float:
    """Router CPU the joints window added over the status window, all routers, per delivered sample, us."""
    added = sum(joints["router_cores"]) - sum(status["router_cores"])
    return added / joints["delivered_per_s"] * 1e6 if joints["delivered_per_s"] else math.nan


HEADER = ("| G1s | worlds | subs | window | joints/robot/s mean (min) | delivered / published, min "
          "| latency p50 / p99, ms | same-host p50 / p99, ms | router CPU per router, cores "
          "| router CPU per delivered sample, us | sims CPU, cores | slowest RTF | across hosts, MB/s "
          "| inside hosts, MB/s | load |")


def row(s: dict[str, Any]) -> str:
    cores = " / ".join(f"{c:.3f}" for c in s["router_cores"])
    if s["phase"] == "status":
        joints = fraction = latency = local = per_sample = "-"
    else:
        joints = f"{s['rate_mean']:.1f} ({s['rate_min']:.1f})"
        fraction = f"{s['delivered_fraction_min']:.3f}"
        latency = f"{s['p50_ms']:.2f} / {s['p99_ms']:.2f}"
        local = f"{s['local_p50_ms']:.2f} / {s['local_p99_ms']:.2f}"
        per_sample = f"{s['us_per_sample']:.1f}"
    return (f"| {s['robots']} | {s['worlds']} | {s['subscribers']} | {s['phase']} | {joints} | {fraction} "
            f"| {latency} | {local} | {cores} | {per_sample} | {s['sim_cores']:.2f} | {s['worst_rtf']:.3f} "
            f"| {s['across_mb_per_s']:.2f} | {s['inside_mb_per_s']:.2f} | {s['load']:.1f} |")


def run_step(mesh: Mesh, worlds: int, per_world: int, seconds: float) -> list[dict[str, Any]]:
    """One robot count: the status window, then the joints window, with the same sims running."""
    robots = len(mesh.hosts) * worlds * per_world
    all_worlds = len(mesh.hosts) * worlds
    mesh.start_step(worlds, per_world)
    try:
        for reply in mesh.all_subscribers("wait_status", 130):
            if not reply["ok"]:
                mesh.check_alive()
                raise TimeoutError(f"robots never reported state/sim: {reply['missing']}")
        status = summary(mesh, "status", robots, all_worlds, mesh.window(seconds))
        print(row(status), flush=True)
        for reply in mesh.all_subscribers("joints", 40):
            if not reply["ok"]:
                raise TimeoutError(f"no state/joints across the mesh from {reply['missing']}")
        joints = summary(mesh, "joints", robots, all_worlds, mesh.window(seconds))
        joints["us_per_sample"] = cost_per_sample_us(status, joints)
        print(row(joints), flush=True)
        if not joints["stamped_by_sims_router"] or joints["unstamped"]:
            print(f"  warning: not every sample was stamped by its sims' router ({joints['unstamped']} unstamped): "
                  "the latency columns do not measure what they say", flush=True)
        return [status, joints]
    finally:
        mesh.stop_step()


def interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--hosts", type=int, default=3, help="host namespaces, one router each (at least 3)")
    parser.add_argument("--steps", default="2x1,2x2,2x4,2x8",
                        help="one step per WxR: W worlds (sim processes) per host, R G1s per world")
    parser.add_argument("--watch-hosts", type=int, default=1,
                        help="each host's subscribers watch the robots of this many other hosts")
    parser.add_argument("--subscribers-per-host", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=6.0, help="length of each measured window")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    parser.add_argument("--subscriber", metavar="ENDPOINT", help=argparse.SUPPRESS)
    parser.add_argument("--remote", default="", help=argparse.SUPPRESS)
    parser.add_argument("--local", default="", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        return subscriber_main(args.subscriber, [r for r in args.remote.split(",") if r],
                               [r for r in args.local.split(",") if r])
    if args.hosts < 3:
        parser.error("--hosts must be at least 3 (a mesh)")
    if not 1 <= args.watch_hosts < args.hosts:
        parser.error("--watch-hosts must be 1 .. hosts - 1")
    try:
        steps = [tuple(int(n) for n in step.split("x")) for step in args.steps.split(",")]
    except ValueError:
        parser.error("--steps is a list of WxR (worlds per host x robots per world): 2x1,2x4")
    if not all(len(step) == 2 and min(step) >= 1 for step in steps):
        parser.error("--steps is a list of WxR (worlds per host x robots per world), each at least 1")
    # SIGINT and SIGTERM unwind through the `finally`s that stop every process and delete the namespaces
    # (set for SIGINT too: a shell starts background jobs with SIGINT ignored, and Python keeps it so).
    signal.signal(signal.SIGINT, interrupted)
    signal.signal(signal.SIGTERM, interrupted)
    netns = test_scaffolding("netns")
    env = dict(os.environ, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING", PYTHONUNBUFFERED="1")
    log_dir = Path(tempfile.mkdtemp(prefix="zensim-mesh-"))
    results: list[dict[str, Any]] = []
    print(f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.2f} at the start; {args.hosts} hosts; "
          f"{args.subscribers_per_host} subscriber(s) per host, each watching {args.watch_hosts} other "
          f"host(s); {args.seconds:g} s windows; logs in {log_dir}")
    print(HEADER)
    print("|" + "---|" * (HEADER.count("|") - 1))
    try:
        with netns.Network([f"h{i}" for i in range(args.hosts)]) as net:
            mesh = Mesh(netns, net, env, log_dir, args.watch_hosts, args.subscribers_per_host)
            try:
                mesh.start_routers()
                for worlds, per_world in steps:
                    results += run_step(mesh, worlds, per_world, args.seconds)
            finally:
                mesh.close()
    except KeyboardInterrupt:
        print("interrupted: every process stopped, the namespaces deleted", file=sys.stderr)
        return 130
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
