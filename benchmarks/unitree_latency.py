"""Command -> state latency through `zensim unitree`, beside a bare DDS round trip, in one run.

    .venv/bin/python benchmarks/unitree_latency.py [--trials 200] [--state-rate-hz 500]

Starts a router, a sim (fixed-base G1, rtf 1, states at --state-rate-hz) and the adapter as real
processes on loopback, DDS on `lo` in a domain of its own, and measures from the controller's
write on rt/lowcmd to the first rt/lowstate that reflects it:

- bare DDS:   ping -> an echo process -> pong on two DDS topics (Cyclone DDS's own round trip, Python
              at both ends as in the adapter's path), interleaved trial by trial with the two below;
- adapter:    LowCmd_ with a feed-forward torque pulse on the left elbow -> adapter -> cmd/motors ->
              sim -> state/joints + state/imu -> adapter -> LowState_ whose tau_est moved by more
              than half the pulse.

- baseline:   the same pulse as a MotorCommand on cmd/motors straight to the sim, state/joints read
              back over Zenoh (no adapter in the path), measured in the same run.

The controller holds every joint with the SDK example's gains at 500 Hz between trials, like an
SDK control loop, and writes pre-serialized LowCmd_ (its own serialization is not the adapter's
latency). It reads LowState_ raw (numpy on the CDR bytes) for the same reason. A state "reflects"
the pulse when its elbow torque less the hold's PD part (from that state's q and dq) exceeds half
the pulse. Trials are 100-200 ms apart at random. Also reported: the sim's real-time factor (its state/sim) and the CPU the sim
and the adapter use (/proc, % of one core) while a controller holds the robot at 500 Hz through the
adapter, before the trials.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from harness import Latest, Processes, cpu_s, free_port, plain_client, test_scaffolding, wait_for
from zensim.common.wire import payload_of
from zensim.schemas import MSGPACK, Codec, JointState, Keys, MotorCommand, SimStatus, UnitreeStatus
from zensim.unitree.idl import Request_

sdk = test_scaffolding("unitree_sdk")  # an SDK-style client: what a unitree_sdk2 controller sends
KD, KP, SdkClient, low_cmd_crc, new_low_cmd, unused_domain_id = (
    sdk.KD, sdk.KP, sdk.SdkClient, sdk.low_cmd_crc, sdk.new_low_cmd, sdk.unused_domain_id)

ELBOW = 18
PULSE_NM = 8.0
TAU_EST_OFFSET = 4 + 68 + 56 * ELBOW + 16
"""Byte offset of motor_state[ELBOW].tau_est in a serialized LowState_ (see zensim/unitree/codec.py)."""
Q_OFFSET = 4 + 68 + 56 * ELBOW + 4
DQ_OFFSET = 4 + 68 + 56 * ELBOW + 8

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


def percentiles(values: list[float]) -> str:
    a = np.array(values) * 1e3
    return f"p50 {np.percentile(a, 50):.2f} ms, p99 {np.percentile(a, 99):.2f} ms, max {a.max():.2f} ms (n={len(a)})"


def raw_states(client: SdkClient) -> list[bytes]:
    res = ddspy_take(client.lowstate._ref, 64)
    return [] if isinstance(res, int) else [data for data, info in res if info.valid_data]


Path_ = tuple[Callable[[bool], None], Callable[[], "float | None"]]


def run_trials(paths: dict[str, Path_], trials: int) -> dict[str, list[float]]:
    """Hold at 500 Hz; per trial, switch to the pulse and time the first state that shows it.

    Trials alternate between the paths (each trial's commander also holds the robot around it),
    so every path sees the same machine load. The first 5 trials of each path warm up and are
    dropped; a trial that sees nothing within 1 s is counted and reported.
    """
    names = list(paths)
    active = [names[0]]
    pulse = [False]
    stop = threading.Event()

    def control_loop() -> None:
        next_t = time.perf_counter()
        while not stop.is_set():
            paths[active[0]][0](pulse[0])
            next_t += 0.002
            time.sleep(max(0.0, next_t - time.perf_counter()))

    loop = threading.Thread(target=control_loop, daemon=True)
    loop.start()
    latencies: dict[str, list[float]] = {name: [] for name in names}
    missed = dict.fromkeys(names, 0)
    try:
        for trial in range(len(names) * (trials + 5)):
            name = names[trial % len(names)]
            send, feed_forward = paths[name]
            active[0] = name
            time.sleep(random.uniform(0.1, 0.2))  # the new commander holds; old states drain
            feed_forward()
            t0 = time.perf_counter()
            pulse[0] = True
            send(True)
            while True:
                value = feed_forward()
                if value is not None and value > PULSE_NM / 2:
                    if trial >= 5 * len(names):
                        latencies[name].append(time.perf_counter() - t0)
                    break
                if time.perf_counter() - t0 > 1.0:
                    missed[name] += 1
                    break
                time.sleep(0.0001)
            pulse[0] = False
            send(False)
    finally:
        stop.set()
        loop.join()
    for name, count in missed.items():
        if count:
            print(f"{name}: {count} trial(s) saw no state reflecting the pulse within 1 s")
    return latencies


def main() -> None:
    # A SIGTERM (e.g. from `timeout`) must still run the `finally` below, or the services outlive us.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--state-rate-hz", type=float, default=500.0)
    parser.add_argument("--cpu-seconds", type=float, default=10.0, help="length of the CPU/RTF phase, s")
    args = parser.parse_args()

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = "bench" + str(random.randint(0, 10**6))
    domain = unused_domain_id()
    base = dict(os.environ, ZENSIM_ROBOT_ID=robot, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    procs = Processes(dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint), prefix="unitree-bench-")
    procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
    sim = procs.zensim("sim", "--mode", "fixed", "--rtf", "1", "--state-rate-hz", str(args.state_rate_hz))
    adapter = procs.zensim("unitree", "--domain-id", str(domain), "--status-rate-hz", "10")
    import subprocess
    echo = subprocess.Popen([sys.executable, "-c", ECHO, str(domain)], stdout=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: "unitree adapter up" in adapter.log() or not adapter.alive(), 60, "the adapter")
        echo.stdout.readline()
        client = SdkClient(domain)
        keys = Keys(robot)
        with plain_client(endpoint) as session:
            status = Latest(session, keys.sim_status, SimStatus, keep_history=True)
            adapter_status = Latest(session, keys.unitree_status, UnitreeStatus)
            first = client.wait_state()

            # Bare DDS round trip: a ping the size of a LowCmd_ to the echo process and back.
            ping = DataWriter(client.participant, Topic(client.participant, "bench/ping", Request_))
            pong = DataReader(client.participant, Topic(client.participant, "bench/pong", Request_))
            payload = Request_(parameter="x" * 900).serialize()  # about a LowCmd_'s size

            q_hold = np.array([first.motor_state[i].q for i in range(29)])
            kp, kd = np.array(KP, float), np.array(KD, float)

            # The hold command and its pulsed twin, serialized once.
            def serialized(tau: float) -> bytes:
                cmd = new_low_cmd()
                cmd.mode_machine = first.mode_machine
                for i in range(29):
                    m = cmd.motor_cmd[i]
                    m.mode, m.q, m.kp, m.kd = 1, float(q_hold[i]), KP[i], KD[i]
                cmd.motor_cmd[ELBOW].tau = tau
                cmd.crc = low_cmd_crc(cmd)
                return cmd.serialize()

            lowcmd = {False: serialized(0.0), True: serialized(PULSE_NM)}

            def dds_send(pulse: bool) -> None:
                ddspy_write(client.lowcmd._ref, lowcmd[pulse])

            def dds_feed_forward() -> float | None:
                got = raw_states(client)
                if not got:
                    return None
                q, dq, tau = (float(np.frombuffer(got[-1], "<f4", 1, off)[0]) for off in (Q_OFFSET, DQ_OFFSET, TAU_EST_OFFSET))
                return feed_forward(q, dq, tau)

            def feed_forward(q: float, dq: float, tau: float) -> float:
                # The state's torque less the PD part of the hold: what is left is the pulse.
                return tau - kp[ELBOW] * (q_hold[ELBOW] - q) + kd[ELBOW] * dq

            # Baseline, interleaved with the adapter's trials: the same pulse as a MotorCommand on
            # cmd/motors straight to the sim, state/joints read back over Zenoh (no adapter in the path).
            motors = session.declare_publisher(keys.motors, encoding=zenoh.Encoding(MSGPACK))
            codec, joints_codec = Codec(MotorCommand), Codec(JointState)
            zeros = (0.0,) * 29
            commands = {pulse: codec.encode(MotorCommand(
                q=tuple(q_hold.tolist()), dq=zeros, kp=tuple(KP), kd=tuple(KD),
                tau=tuple(PULSE_NM if (pulse and i == ELBOW) else 0.0 for i in range(29)))) for pulse in (False, True)}
            newest: list = [None]

            def on_joints(sample: zenoh.Sample) -> None:
                newest[0] = joints_codec.decode(*payload_of(sample))

            subscriber = session.declare_subscriber(keys.joints, on_joints)

            pinged = [False]

            def bare_send(pulse: bool) -> None:
                dds_send(False)  # the adapter keeps holding the robot: the same load as in its trials
                if pulse and not pinged[0]:
                    pinged[0] = True
                    ddspy_write(ping._ref, payload)
                elif not pulse:
                    pinged[0] = False

            def bare_feed_forward() -> float | None:
                res = ddspy_take(pong._ref, 64)
                return PULSE_NM if not isinstance(res, int) and res else None

            def zenoh_send(pulse: bool) -> None:
                motors.put(commands[pulse])

            def zenoh_feed_forward() -> float | None:
                state, newest[0] = newest[0], None
                return None if state is None else feed_forward(state.q[ELBOW], state.dq[ELBOW], state.tau[ELBOW])

            # CPU and RTF while an SDK-style controller holds the robot at 500 Hz through the adapter.
            stop = threading.Event()

            def hold_loop() -> None:
                next_t = time.perf_counter()
                while not stop.is_set():
                    dds_send(False)
                    next_t += 0.002
                    time.sleep(max(0.0, next_t - time.perf_counter()))

            holder = threading.Thread(target=hold_loop, daemon=True)
            holder.start()
            time.sleep(1.0)
            cpu0 = {name: cpu_s(p.pid) for name, p in (("sim", sim), ("unitree", adapter))}
            lowstates0 = adapter_status.value.lowstate_published if adapter_status.value else 0
            wall0 = time.monotonic()
            status.history.clear()
            time.sleep(args.cpu_seconds)
            wall = time.monotonic() - wall0
            cpu = {name: 100 * (cpu_s(p.pid) - cpu0[name]) / wall for name, p in (("sim", sim), ("unitree", adapter))}
            rtfs = [s.rtf for s in status.history if s.rtf > 0]
            lowstate_hz = (adapter_status.value.lowstate_published - lowstates0) / wall
            stop.set()
            holder.join()

            results = run_trials({"bare": (bare_send, bare_feed_forward), "adapter": (dds_send, dds_feed_forward),
                                  "direct": (zenoh_send, zenoh_feed_forward)}, args.trials)
            bare, through_adapter, direct = results["bare"], results["adapter"], results["direct"]
            subscriber.undeclare()
        print(f"state rate {args.state_rate_hz:.0f} Hz, {args.trials} trials, pulse {PULSE_NM} N m on the left elbow")
        print(f"bare DDS round trip (ping -> echo process -> pong): {percentiles(bare)}")
        print(f"rt/lowcmd torque pulse -> first rt/lowstate reflecting it: {percentiles(through_adapter)}")
        print(f"baseline, cmd/motors torque pulse -> first state/joints reflecting it (Zenoh, no adapter): {percentiles(direct)}")
        p99 = {name: float(np.percentile(v, 99)) for name, v in (("bare", bare), ("adapter", through_adapter))}
        print(f"adapter p99 / bare DDS p99 = {p99['adapter'] / p99['bare']:.2f} (goal: at most 2)")
        print(f"while a controller holds the robot at 500 Hz through the adapter for {wall:.0f} s:")
        print(f"  LowState_ {lowstate_hz:.0f} Hz; sim RTF min {min(rtfs):.3f}, median {np.median(rtfs):.3f} "
              f"({len(rtfs)} status samples)")
        print(f"  CPU, % of one core: sim {cpu['sim']:.0f}, adapter {cpu['unitree']:.0f}, "
              f"together {cpu['sim'] + cpu['unitree']:.0f}")
    finally:
        echo.kill()
        procs.stop_all()


if __name__ == "__main__":
    main()
