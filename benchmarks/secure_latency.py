"""What the secured links cost: round trip through a router, plain TCP against TLS + passwords + access control.

    .venv/bin/python benchmarks/secure_latency.py [--trials 2000] [--size 800]

Starts a real `zensim router` (plain `tcp/`, then `--secure-dir` with `tls/`) and an echo process on
loopback; the client puts on `zensim/bench/cmd/motors` (what an operator may put), the echo, with the
sim's credentials, answers on `zensim/bench/state/joints` (what only the sim may publish), and the
client times put -> echo -> sample. Both setups run side by side in one invocation, alternating
rounds, so machine noise hits both alike. Prints p50/p90/p99 in ms per setup and their ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from harness import free_port

PING = "zensim/bench/cmd/motors"
PONG = "zensim/bench/state/joints"


def client_conf(endpoint: str, secrets: Path | None, role: str) -> zenoh.Config:
    if secrets is None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
    else:
        conf = zenoh.Config.from_file(str(secrets / f"{role}.json5"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "-1")
    return conf


def echo_main(endpoint: str, secrets: str) -> None:
    """The echo process: every ping back as a pong, as the sim's role."""
    with zenoh.open(client_conf(endpoint, Path(secrets) if secrets else None, "sim")) as session:
        pong = session.declare_publisher(PONG)
        session.declare_subscriber(PING, lambda s: pong.put(s.payload.to_bytes()))
        print("ready", flush=True)
        sys.stdin.read()


class Setup:
    def __init__(self, name: str, secrets: Path | None, log_dir: Path) -> None:
        self.name = name
        scheme = "tls" if secrets else "tcp"
        self.endpoint = f"{scheme}/127.0.0.1:{free_port()}"
        env = dict(os.environ, ZENSIM_LOG_LEVEL="WARNING", ZENSIM_ROBOT_ID="bench")
        if secrets:
            env["ZENSIM_SECURE_DIR"] = str(secrets)
        self.router = subprocess.Popen([sys.executable, "-m", "zensim", "router", "--zenoh-listen", self.endpoint],
                                       env=env, stdout=(log_dir / f"{name}-router.log").open("wb"),
                                       stderr=subprocess.STDOUT)
        self.echo = subprocess.Popen([sys.executable, __file__, "--echo", self.endpoint, str(secrets or "")],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.echo.stdout.readline().strip() == "ready"
        self.session = zenoh.open(client_conf(self.endpoint, secrets, "operator"))
        self.got = threading.Event()
        self.sub = self.session.declare_subscriber(PONG, lambda s: self.got.set())
        self.pub = self.session.declare_publisher(PING)
        self.rtts: list[float] = []

    def round(self, trials: int, payload: bytes) -> None:
        for _ in range(trials):
            self.got.clear()
            start = time.perf_counter()
            self.pub.put(payload)
            if self.got.wait(2.0):
                self.rtts.append(time.perf_counter() - start)
            time.sleep(0.0005)

    def close(self) -> None:
        self.session.close()
        self.echo.stdin.close()
        self.echo.wait(10)
        self.router.terminate()
        self.router.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=2000)
    parser.add_argument("--size", type=int, default=800, help="payload bytes (a G1 joint state is ~800 B)")
    parser.add_argument("--echo", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo:
        echo_main(*args.echo)
        return 0
    work = Path(tempfile.mkdtemp(prefix="zensim-secure-bench-"))
    subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(work / "secrets")], check=True,
                   stdout=subprocess.DEVNULL)
    setups = [Setup("plain tcp", None, work), Setup("tls+auth+acl", work / "secrets", work)]
    payload = os.urandom(args.size)
    try:
        for setup in setups:
            setup.round(100, payload)  # warm up: links, ACL caches
            setup.rtts.clear()
        rounds = 10
        for _ in range(rounds):
            for setup in setups:
                setup.round(args.trials // rounds, payload)
    finally:
        for setup in setups:
            setup.close()
    p50 = {}
    for setup in setups:
        ms = np.array(setup.rtts) * 1000
        p50[setup.name] = np.percentile(ms, 50)
        print(f"{setup.name:>14}: n={len(ms)} round trip p50 {np.percentile(ms, 50):.3f} ms, "
              f"p90 {np.percentile(ms, 90):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms")
    print(f"p50 ratio secured/plain: {p50['tls+auth+acl'] / p50['plain tcp']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
