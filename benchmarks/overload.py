"""Overload: does the physics keep time while hostile clients flood it? (issues 9 and 17)

    .venv/bin/python benchmarks/overload.py [--seconds 60] [--rate-hz 10000] [--trials 150] [--kinds valid]

Starts a router and a sim (floating G1, rtf 1, states at 500 Hz) as real processes on loopback, and a
well-behaved client in this process: a 100 Hz controller that holds the default pose on cmd/motors
and steps the left elbow now and then, timing command -> first state/joints reflecting it (the torque
probe of bridge_latency.py). Its samples say their source (zenoh source info), as zensim's own
publishers' do. First idle, then beside flooding clients (`--kinds`, default `valid`), each its own
process, each aiming at `--rate-hz` samples per second on cmd/motors:

    valid       a valid full-body MotorCommand: every joint but the probed left elbow, by name, holding
                the default pose (what decoding and checking a whole-robot command costs, without
                fighting the good client for the joint it times)
    malformed   random bytes (msgpack and JSON-looking garbage)
    oversize    a 64 KiB payload (over the G1's cap of about 20 KiB)
    nested      deep nesting and invalid UTF-8, under the cap (the costly decode failures)
    forged-copy malformed's garbage, each sample claiming the good client's own source (zenoh source info:
                the flooder reads the good client's source id off one of its samples, as any
                subscriber can, and puts its own samples with it)
    forged-many malformed's garbage, spread over 64 source ids of the flooder's making (64 publishers'
                ids, one per sample in turn, each claimed in zenoh source info)

(issue 27: a flood must not shed a good client's commands, whatever source info either claims; the
garbage floods leave the good client the only one whose commands apply, so the robot's command age
is that client's.)

Reported for each phase: worst 1 s window RTF (from state/sim), state/joints rate and its worst
1 s window, the good client's command -> state p50/p99, the command age p50/p99 (state/sim's
`command_age_s`: time since the last command the sim applied, whoever sent it), the states'
delivery lag p50/p99 (arrival wall time minus sim time, less the phase's smallest such offset: how
late a state leaves and arrives against the sim clock; at rtf 1 that clock runs with the wall), the
watchdog flag (never engaged?), commands rejected and shed, and the RSS of the sim and the router before the flood, 10 s
into it and at its end. Each flooder prints the rate it reached. The flooders run niced (19) so that
what is measured is the sim's isolation, not the scheduler's share for busy processes: say so with
the figures, and how loaded the machine was.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from bridge_latency import elbow_trials, run_trials
from harness import Processes, client_config, free_port, rss_mb
from zensim.common.wire import payload_of
from zensim.schemas import Codec, JointState, Keys, MotorCommand, RobotInfo, SimStatus

FLOODER = r"""
import json, os, random, sys, time, zenoh
kind, endpoint, key, rate, seconds = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
pose = json.loads(sys.argv[6])  # joint name -> default q: the valid flood's full body
rng = random.Random(kind)
if kind == "malformed":
    payloads = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))) for _ in range(500)]
    payloads += [b'{"q": [' + b"1," * rng.randrange(1, 50) + b"}" for _ in range(100)]
elif kind == "oversize":
    payloads = [b'{"q": [0.1], "names": ["' + b"x" * 65536 + b'"]}']
elif kind == "nested":
    payloads = [b'{"q": [0.1], "x": ' + b"[" * 3000 + b"]" * 3000 + b"}", b'{"names": ["a\xff\xfe"], "q": [0.1]}']
elif kind in ("forged-copy", "forged-many"):  # malformed's garbage, under forged source info
    payloads = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))) for _ in range(500)]
else:
    payloads = [json.dumps({"names": list(pose), "q": list(pose.values())}).encode()]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    pub = session.declare_publisher(key)
    claims = [None]  # the source ids claimed in turn (None: the publisher's own, as zenoh sets none)
    if kind == "forged-copy":  # the good client's id, read off one of its samples
        seen = []
        sub = session.declare_subscriber(
            key, lambda s: s.source_info is not None and seen.append(s.source_info.source_id))
        deadline = time.monotonic() + 10.0
        while not seen and time.monotonic() < deadline:
            time.sleep(0.01)
        sub.undeclare()
        if not seen:
            sys.exit("forged-copy: no sample with source info from the good client in 10 s")
        claims = [seen[0]]
    elif kind == "forged-many":
        extra = [session.declare_publisher(key) for _ in range(64)]
        claims = [p.id for p in extra]
    sent, start, period = 0, time.perf_counter(), 1.0 / rate
    while True:
        now = time.perf_counter()
        if now - start >= seconds:
            break
        due = start + sent * period
        if due > now:
            time.sleep(min(due - now, 0.001))
            continue
        claim = claims[sent % len(claims)]
        if claim is None:
            pub.put(payloads[sent % len(payloads)])
        else:
            pub.put(payloads[sent % len(payloads)], source_info=zenoh.SourceInfo(claim, sent + 1))
        sent += 1
    print(json.dumps({"kind": kind, "sent": sent, "rate_hz": sent / (time.perf_counter() - start)}), flush=True)
"""


def joint_names(session: zenoh.Session, keys: Keys) -> tuple[str, ...]:
    """The robot's joints, in order (the valid flood names each)."""
    for reply in session.get(keys.robot_info, timeout=5.0):
        if reply.ok is not None:
            return Codec(RobotInfo).decode(*payload_of(reply.ok)).joint_names
    raise RuntimeError("no info/robot")


def pin(pid: int, cpus: set[int]) -> None:
    """Move every thread of a process onto `cpus` (threads made later inherit it)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            os.sched_setaffinity(int(task.name), cpus)
        except (ProcessLookupError, PermissionError):
            pass


class Watch:
    """Statuses and state arrival times (with the sim time each state describes), as received."""

    def __init__(self) -> None:
        self.statuses: list[tuple[float, SimStatus]] = []
        self.state_times: list[float] = []
        self.state_sim_times: list[float] = []
        self._codec = Codec(SimStatus)
        self._joints_codec = Codec(JointState)

    def on_status(self, sample: zenoh.Sample) -> None:
        self.statuses.append((time.monotonic(), self._codec.decode(*payload_of(sample))))

    def on_state(self, sample: zenoh.Sample) -> None:
        self.state_times.append(time.monotonic())
        self.state_sim_times.append(self._joints_codec.decode(*payload_of(sample)).sim_time_s)

    def delivery_lag_s(self, start: float, end: float) -> np.ndarray:
        """Each state's arrival minus its sim time, less the smallest such offset in the window, s.

        Resets (sim time jumping back) would break the offset: none happen in this benchmark."""
        arrival, sim_time = np.array(self.state_times), np.array(self.state_sim_times)
        keep = (arrival >= start) & (arrival <= end)
        offset = arrival[keep] - sim_time[keep]
        return offset - offset.min() if len(offset) else np.array([float("nan")])

    def window(self, start: float, end: float) -> dict:
        statuses = [(t, s) for t, s in self.statuses if start <= t <= end]
        worst_rtf, t0 = float("inf"), start
        for t, s in statuses:  # worst RTF over consecutive ~1 s windows of wall time
            if t - t0 >= 1.0:
                before = min(statuses, key=lambda ts: abs(ts[0] - t0))
                worst_rtf = min(worst_rtf, (s.sim_time_s - before[1].sim_time_s) / (t - before[0]))
                t0 = t
        states = np.array([t for t in self.state_times if start <= t <= end])
        per_second = np.histogram(states, bins=np.arange(start, end, 1.0))[0] if len(states) else np.array([0])
        return {
            "worst_1s_rtf": worst_rtf,
            "state_rate_hz": len(states) / (end - start),
            "worst_1s_state_rate_hz": int(per_second.min()) if len(per_second) else 0,
            "watchdog_engaged": any(s.watchdog for _, s in statuses),
            "rejected": statuses[-1][1].rejected_commands - statuses[0][1].rejected_commands if statuses else 0,
            "shed": statuses[-1][1].shed_commands - statuses[0][1].shed_commands if statuses else 0,
            "lag_s": self.delivery_lag_s(start, end),
            "physics_resets": statuses[-1][1].physics_resets if statuses else 0,
            "command_age_s": np.array([s.command_age_s for _, s in statuses if s.command_age_s is not None]
                                      or [float("nan")]),
        }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="flood duration")
    parser.add_argument("--rate-hz", type=float, default=10_000.0, help="samples per second per flooder")
    parser.add_argument("--trials", type=int, default=150, help="latency trials per phase")
    parser.add_argument("--kinds", default="valid",
                        help="flooders, comma-separated: valid, malformed, oversize, nested, forged-copy, forged-many "
                             "(default: valid)")
    parser.add_argument("--state-rate-hz", default="500")
    parser.add_argument("--no-nice", action="store_true", help="run the flooders at normal priority")
    parser.add_argument("--pin", action="store_true",
                        help="the sim and the good client on CPU 0, the router and the flooders on CPU 1: the sim's "
                             "isolation measured as if the attack ran on other hosts (it needs more than 2 cores)")
    parser.add_argument("--cmd-rate-limit-hz", default="0",
                        help="the router's per-link rate limit on cmd/** (zensim router --cmd-rate-limit-hz); 0: off")
    args = parser.parse_args()

    keys = Keys("overload")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID=keys.robot, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
               ZENSIM_ZENOH_MULTICAST_SCOUTING="false", ZENSIM_LOG_LEVEL="WARNING")
    procs = Processes(env)
    results: dict[str, dict] = {}
    flood_rates: list[dict] = []
    try:
        router = procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "",
                              "--cmd-rate-limit-hz", args.cmd_rate_limit_hz)
        with zenoh.open(client_config(endpoint)) as session:
            sim = procs.zensim("sim", "--mode", "floating", "--rtf", "1", "--state-rate-hz", args.state_rate_hz)
            i, default, low, high, probe = elbow_trials(session, keys)
            if args.pin:
                pin(sim.pid, {0})
                pin(os.getpid(), {0})
                pin(router.pid, {1})
            watch = Watch()
            subs = [session.declare_subscriber(keys.joints, lambda s: (probe.on_state(s), watch.on_state(s))),
                    session.declare_subscriber(keys.sim_status, watch.on_status)]
            motors = session.declare_publisher(keys.motors, encoding=zenoh.Encoding("application/msgpack"))
            motors_codec = Codec(MotorCommand)
            sn = itertools.count(1)
            elbow = [float(default[i])]
            stop = threading.Event()
            names = joint_names(session, keys)
            pose = {name: float(q) for k, (name, q) in enumerate(zip(names, default)) if k != i}

            def controller() -> None:  # the well-behaved client: 100 Hz, the whole pose
                while not stop.wait(0.01):
                    send(elbow[0])

            def send(target: float) -> None:
                elbow[0] = target
                q = default.copy()
                q[i] = target
                motors.put(motors_codec.encode(MotorCommand(q=tuple(q.tolist()))),
                           source_info=zenoh.SourceInfo(motors.id, next(sn)))  # as zensim's publishers say

            threading.Thread(target=controller, daemon=True).start()
            time.sleep(1.0)

            start = time.monotonic()
            idle = run_trials(probe, send, args.trials, low, high)
            time.sleep(max(0.0, 10.0 - (time.monotonic() - start)))
            results["idle"] = watch.window(start + 1.0, time.monotonic())
            results["idle"]["latencies"] = idle
            rss_before = {"sim": rss_mb(sim.pid), "router": rss_mb(router.pid)}

            nice = [] if args.no_nice else ["nice", "-n", "19"]
            flooders = [procs.start(f"flood-{kind}", [*nice, sys.executable, "-c", FLOODER, kind, endpoint, keys.motors,
                                                       str(args.rate_hz), str(args.seconds), json.dumps(pose)])
                        for kind in args.kinds.split(",")]
            if args.pin:
                time.sleep(1.0)  # their zenoh threads exist once the sessions are open
                for proc in flooders:
                    pin(proc.pid, {1})
            start = time.monotonic()
            rss_at_10 = None
            latencies: list[float] = []
            while time.monotonic() - start < args.seconds:
                if rss_at_10 is None and time.monotonic() - start >= 10.0:
                    rss_at_10 = {"sim": rss_mb(sim.pid), "router": rss_mb(router.pid)}
                if len(latencies) < args.trials:
                    latencies += run_trials(probe, send, 10, low, high)
                else:
                    time.sleep(0.2)
            end = time.monotonic()
            rss_end = {"sim": rss_mb(sim.pid), "router": rss_mb(router.pid)}
            for proc in flooders:
                proc.wait(30)
            for proc in flooders:
                log = proc.log().strip().splitlines()
                flood_rates.append(json.loads(log[-1]) if log and log[-1].startswith("{") else {"error": log[-3:]})
            results["flood"] = watch.window(start + 1.0, end)
            results["flood"]["latencies"] = latencies
            results["flood"]["rss_mb_before"] = rss_before
            results["flood"]["rss_mb_at_10s"] = rss_at_10
            results["flood"]["rss_mb_end"] = rss_end
            stop.set()
            for sub in subs:
                sub.undeclare()
            print(f"sim alive: {sim.poll() is None}, router alive: {router.poll() is None}")
    finally:
        procs.stop_all()

    print(f"\nrouter rate limit on cmd/**: {args.cmd_rate_limit_hz} Hz per link; pinned: {args.pin}; "
          f"flooders (niced: {not args.no_nice}):")
    for rate in flood_rates:
        print("  ", rate)
    print(f"\n{'phase':<7} {'worst 1 s RTF':>14} {'states/s':>9} {'worst 1 s':>9} {'cmd p50 ms':>10} {'cmd p99 ms':>10} "
          f"{'lag p50 ms':>10} {'lag p99 ms':>10} {'age p50 ms':>10} {'age p99 ms':>10} {'watchdog':>8} {'rejected':>9} "
          f"{'shed':>9} {'phys resets':>11}")
    for phase, r in results.items():
        ms, lag, age = np.array(r["latencies"]) * 1e3, r["lag_s"] * 1e3, r["command_age_s"] * 1e3
        print(f"{phase:<7} {r['worst_1s_rtf']:>14.4f} {r['state_rate_hz']:>9.1f} {r['worst_1s_state_rate_hz']:>9d} "
              f"{np.percentile(ms, 50):>10.2f} {np.percentile(ms, 99):>10.2f} {np.percentile(lag, 50):>10.2f} "
              f"{np.percentile(lag, 99):>10.2f} {np.percentile(age, 50):>10.2f} {np.percentile(age, 99):>10.2f} "
              f"{str(r['watchdog_engaged']):>8} {r['rejected']:>9d} {r['shed']:>9d} "
              f"{r['physics_resets']:>11d}")
    flood = results.get("flood", {})
    if flood.get("rss_mb_at_10s"):
        for name in ("sim", "router"):
            a, b, c = flood["rss_mb_before"][name], flood["rss_mb_at_10s"][name], flood["rss_mb_end"][name]
            print(f"RSS {name}: {a:.1f} MB before the flood, {b:.1f} MB at 10 s, {c:.1f} MB at the end "
                  f"({c - a:+.1f} MB over the flood, {c - b:+.1f} MB after its first 10 s)")
    if "idle" in results and "flood" in results:
        idle, flood = results["idle"], results["flood"]
        for what, a, b in (("command -> state", np.array(idle["latencies"]), np.array(flood["latencies"])),
                           ("state delivery lag", idle["lag_s"], flood["lag_s"]),
                           ("command age", idle["command_age_s"], flood["command_age_s"])):
            print(f"{what}, flood / idle: p50 {np.percentile(b, 50) / np.percentile(a, 50):.2f}x, "
                  f"p99 {np.percentile(b, 99) / np.percentile(a, 99):.2f}x")
    print(f"load average while it ran: {os.getloadavg()}")
    print(f"logs: {procs.dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
