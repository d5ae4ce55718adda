"""Command -> state latency through `zensim unitree`, beside a bare DDS round trip, in one run.

    .venv/bin/python benchmarks/unitree_latency.py [--trials 200] [--state-rate-hz 500]

Starts a router, a sim (fixed-base G1, rtf 1, states at --state-rate-hz) and the adapter as real
processes on loopback, DDS on `lo` in a domain of its own, and measures from the controller's
write on rt/lowcmd to the first rt/lowstate that reflects it:

- bare DDS:   ping -> an echo process -> pong on two DDS topics (Cyclone DDS's own round trip);
- adapter:    LowCmd_ with a feed-forward torque pulse on the left elbow -> adapter -> cmd/motors ->
              sim -> state/joints + state/imu -> adapter -> LowState_ whose tau_est moved by more
              than half the pulse.

The controller holds every joint with the SDK example's gains at 500 Hz between trials, like an
SDK control loop, and writes pre-serialized LowCmd_ (its own serialization is not the adapter's
latency). It reads LowState_ raw (numpy on the CDR bytes) for the same reason. Trials are 100-200
ms apart at random. Also reported: the sim's real-time factor (its state/sim) and the CPU the sim
and the adapter used over the trials (/proc), in % of one core.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))

from cyclonedds._clayer import ddspy_take, ddspy_write  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from support import Latest, Service, free_port, plain_client, wait_for  # noqa: E402
from unitree_sdk import KD, KP, SdkClient, low_cmd_crc, new_low_cmd, unused_domain_id  # noqa: E402
from zensim.schemas import Keys, SimStatus  # noqa: E402
from zensim.unitree.idl import Request_  # noqa: E402

ELBOW = 18
PULSE_NM = 8.0
TAU_EST_OFFSET = 4 + 68 + 56 * ELBOW + 16
"""Byte offset of motor_state[ELBOW].tau_est in a serialized LowState_ (see zensim/unitree/codec.py)."""
Q_OFFSET = 4 + 68 + 56 * ELBOW + 4

ECHO = """
import sys, time
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.core import ReadCondition, SampleState, ViewState, InstanceState, WaitSet
from cyclonedds.util import duration
from cyclonedds._clayer import ddspy_take, ddspy_write
from zensim.unitree.dds import domain_config
from zensim.unitree.idl import Request_
d = int(sys.argv[1]); domain = Domain(d, domain_config("lo")); p = DomainParticipant(d)
r = DataReader(p, Topic(p, "bench/ping", Request_)); w = DataWriter(p, Topic(p, "bench/pong", Request_))
ws = WaitSet(p); ws.attach(ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any))
print("echo up", flush=True)
while True:
    ws.wait(duration(seconds=1))
    res = ddspy_take(r._ref, 16)
    if not isinstance(res, int):
        for data, info in res:
            if info.valid_data:
                ddspy_write(w._ref, data)
"""


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def percentiles(values: list[float]) -> str:
    a = np.array(values) * 1e3
    return f"p50 {np.percentile(a, 50):.2f} ms, p99 {np.percentile(a, 99):.2f} ms, max {a.max():.2f} ms (n={len(a)})"


def raw_states(client: SdkClient) -> list[bytes]:
    res = ddspy_take(client.lowstate._ref, 64)
    return [] if isinstance(res, int) else [data for data, info in res if info.valid_data]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--state-rate-hz", type=float, default=500.0)
    args = parser.parse_args()

    import tempfile
    tmp = Path(tempfile.mkdtemp(prefix="unitree-bench-"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = "bench" + str(random.randint(0, 10**6))
    domain = unused_domain_id()
    base = dict(os.environ, ZENSIM_ROBOT_ID=robot, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    router = Service("router", [], dict(base, ZENSIM_ZENOH_LISTEN=endpoint), tmp)
    client_env = dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint)
    sim = Service("sim", ["--mode", "fixed", "--rtf", "1", "--state-rate-hz", str(args.state_rate_hz)], client_env, tmp)
    adapter = Service("unitree", ["--unitree-domain-id", str(domain)], client_env, tmp)
    import subprocess
    echo = subprocess.Popen([sys.executable, "-c", ECHO, str(domain)], stdout=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: "unitree adapter up" in adapter.log() or not adapter.alive(), 60, "the adapter")
        echo.stdout.readline()
        client = SdkClient(domain)
        keys = Keys(robot)
        with plain_client(endpoint) as session:
            status = Latest(session, keys.sim_status, SimStatus)
            status.keep_history = True
            first = client.wait_state()

            # Bare DDS round trip.
            ping = DataWriter(client.participant, Topic(client.participant, "bench/ping", Request_))
            pong = DataReader(client.participant, Topic(client.participant, "bench/pong", Request_))
            payload = Request_(parameter="x" * 900).serialize()  # about a LowCmd_'s size
            bare = []
            for i in range(args.trials + 20):
                ddspy_take(pong._ref, 64)
                t0 = time.perf_counter()
                ddspy_write(ping._ref, payload)
                while True:
                    res = ddspy_take(pong._ref, 1)
                    if not isinstance(res, int) and res:
                        break
                bare.append(time.perf_counter() - t0)
                time.sleep(random.uniform(0.005, 0.01))
            bare = bare[20:]

            # The hold command and its pulsed twin, serialized once.
            def serialized(tau: float) -> bytes:
                cmd = new_low_cmd()
                cmd.mode_machine = first.mode_machine
                for i in range(29):
                    m = cmd.motor_cmd[i]
                    m.mode, m.q, m.kp, m.kd = 1, first.motor_state[i].q, KP[i], KD[i]
                cmd.motor_cmd[ELBOW].tau = tau
                cmd.crc = low_cmd_crc(cmd)
                return cmd.serialize()

            hold, pulse = serialized(0.0), serialized(PULSE_NM)
            current = [hold]
            stop = threading.Event()

            def control_loop() -> None:
                next_t = time.perf_counter()
                while not stop.is_set():
                    ddspy_write(client.lowcmd._ref, current[0])
                    next_t += 0.002
                    time.sleep(max(0.0, next_t - time.perf_counter()))

            loop = threading.Thread(target=control_loop, daemon=True)
            loop.start()
            time.sleep(1.0)
            cpu0 = {p.command: cpu_s(p.proc.pid) for p in (sim, adapter)}
            wall0 = time.monotonic()
            status.history.clear()
            latencies = []
            for trial in range(args.trials + 5):
                time.sleep(random.uniform(0.1, 0.2))
                raw_states(client)
                base_tau = None
                sample = raw_states(client)
                t0 = time.perf_counter()
                current[0] = pulse
                ddspy_write(client.lowcmd._ref, pulse)
                while True:
                    got = raw_states(client)
                    if got:
                        tau = float(np.frombuffer(got[-1], "<f4", 1, TAU_EST_OFFSET)[0])
                        if base_tau is None and sample:
                            base_tau = float(np.frombuffer(sample[-1], "<f4", 1, TAU_EST_OFFSET)[0])
                        if tau - (base_tau or 0.0) > PULSE_NM / 2:
                            latencies.append(time.perf_counter() - t0)
                            break
                    if time.perf_counter() - t0 > 1.0:
                        print("trial", trial, "timed out")
                        break
                current[0] = hold
                ddspy_write(client.lowcmd._ref, hold)
            latencies = latencies[5:]
            wall = time.monotonic() - wall0
            cpu = {name: 100 * (cpu_s(p.proc.pid) - cpu0[name]) / wall for name, p in (("sim", sim), ("unitree", adapter))}
            stop.set()
            rtfs = [s.rtf for s in status.history if s.rtf > 0]
        print(f"state rate {args.state_rate_hz:.0f} Hz, {args.trials} trials, pulse {PULSE_NM} N m on the left elbow")
        print(f"bare DDS round trip (ping -> echo process -> pong): {percentiles(bare)}")
        print(f"rt/lowcmd torque pulse -> first rt/lowstate reflecting it: {percentiles(latencies)}")
        print(f"sim RTF over the trials: min {min(rtfs):.3f}, median {np.median(rtfs):.3f} ({len(rtfs)} status samples)")
        print(f"CPU over {wall:.0f} s, % of one core: sim {cpu['sim']:.0f}, adapter {cpu['unitree']:.0f}, "
              f"together {cpu['sim'] + cpu['unitree']:.0f}")
    finally:
        echo.kill()
        for service in (adapter, sim, router):
            service.stop()


if __name__ == "__main__":
    main()
