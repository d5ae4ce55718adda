"""The Unitree adapter's DDS edge under floods (issue 18, finding 5), in one run:

    .venv/bin/python benchmarks/unitree_flood.py [--seconds 5] [--rate-hz 10000] [--sport-rate-hz 10000] [--garbage 20000]

Starts a router, a sim (fixed-base G1, rtf 1, states at 500 Hz) and `zensim unitree --interface lo`
as real processes on loopback, DDS in a domain of its own, then, one after another:

- quiet:   an SDK-style controller holds the robot with LowCmd_ at 500 Hz for --seconds;
- flood:   the same controller writes LowCmd_ as fast as --rate-hz allows for --seconds;
- after:   500 Hz again for --seconds (does the adapter recover at once?);
- sport:   the LowCmd_ controller stops; LocoClient's SetFsmId(500) starts the locomotion controller
           (Unitree's walking policy on the sim's states), then the same request floods the sport
           service (rt/api/sport/request) at --sport-rate-hz for --seconds (issue 27: each answered
           SetFsmId restarts the policy's schedule, so the adapter works per request, not per state);
- garbage: --garbage malformed RTPS packets (valid RTPS header, random submessages) at the adapter's
           UDP ports, as fast as one Python sender goes; then the adapter's log is measured.

Per phase: the LowCmd_ rate written, the sim's real-time factor (its sim time over wall time), the
LowState_ rate the adapter wrote, LowCmd_ forwarded and shed per second (UnitreeStatus), sport
requests sent and answered per second, and the CPU the adapter and the sim used (% of one core).
Writes are pre-serialized (ddspy_write), so the sender's own cost is small.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import time

from cyclonedds._clayer import ddspy_write
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from harness import Latest, Processes, cpu_s, free_port, plain_client, test_scaffolding, wait_for
from zensim.schemas import Keys, SimStatus, UnitreeStatus
from zensim.unitree.idl import Request_, RequestHeader_, RequestIdentity_, RequestPolicy_

sdk = test_scaffolding("unitree_sdk")
KD, KP, SdkClient, low_cmd_crc, new_low_cmd, unused_domain_id = (
    sdk.KD, sdk.KP, sdk.SdkClient, sdk.low_cmd_crc, sdk.new_low_cmd, sdk.unused_domain_id)

ELBOW = 18


def hold_command() -> bytes:
    cmd = new_low_cmd()
    m = cmd.motor_cmd[ELBOW]
    m.mode, m.q, m.kp, m.kd = 1, 0.5, KP[ELBOW], KD[ELBOW]
    cmd.crc = low_cmd_crc(cmd)
    return cmd.serialize()


def sport_request(request_id: int) -> bytes:
    """One serialized SetFsmId(500) request (start: balance and walk), as LocoClient writes it."""
    return Request_(header=RequestHeader_(identity=RequestIdentity_(id=request_id, api_id=7101),
                                          policy=RequestPolicy_(priority=0, noreply=False)),
                    parameter='{"data": 500}', binary=[]).serialize()


def udp_ports(pid: int) -> list[int]:
    out = subprocess.run(["ss", "-Huanp"], capture_output=True, text=True, check=True).stdout
    return [int(line.split()[3].rsplit(":", 1)[1]) for line in out.splitlines() if f"pid={pid}," in line]


def main() -> None:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each LowCmd_ phase, s")
    parser.add_argument("--rate-hz", type=float, default=10_000.0, help="the flood's LowCmd_ rate")
    parser.add_argument("--sport-rate-hz", type=float, default=10_000.0, help="the sport-request flood's rate")
    parser.add_argument("--garbage", type=int, default=20_000, help="malformed RTPS packets sent")
    args = parser.parse_args()

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = "bench" + str(random.randint(0, 10**6))
    domain = unused_domain_id()
    base = dict(os.environ, ZENSIM_ROBOT_ID=robot, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    procs = Processes(dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint), prefix="unitree-flood-")
    procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
    sim = procs.zensim("sim", "--mode", "fixed", "--rtf", "1", "--state-rate-hz", "500")
    adapter = procs.zensim("unitree", "--domain-id", str(domain), "--interface", "lo", "--status-rate-hz", "10")
    try:
        wait_for(lambda: "unitree adapter up" in adapter.log() or not adapter.alive(), 60, "the adapter")
        client = SdkClient(domain)
        client.wait_state()
        keys = Keys(robot)
        command = hold_command()
        sport_writer = DataWriter(client.participant, Topic(client.participant, "rt/api/sport/request", Request_))
        requests = [sport_request(i) for i in range(1000)]
        with plain_client(endpoint) as session:
            sim_status = Latest(session, keys.sim_status, SimStatus)
            status = Latest(session, keys.unitree_status, UnitreeStatus)
            sim_status.wait(what="the sim's status")
            status.wait(what="the adapter's status")
            print(f"adapter UDP sockets: {udp_ports(adapter.pid)} "
                  f"({subprocess.run(['ss', '-Huanp'], capture_output=True, text=True).stdout.count(f'pid={adapter.pid},')} "
                  "sockets; see `ss -uanp`)")
            print(f"{'phase':8} {'LowCmd_/s sent':>14} {'sim RTF':>8} {'LowState_ Hz':>12} {'fwd/s':>7} {'shed/s':>8} "
                  f"{'sport req/s':>11} {'answered/s':>10} {'adapter CPU':>11} {'sim CPU':>8}")
            for phase, rate_hz, sport_hz in (("quiet", 500.0, 0.0), ("flood", args.rate_hz, 0.0), ("after", 500.0, 0.0),
                                             ("sport", 0.0, args.sport_rate_hz)):
                if sport_hz:  # the controller on: resend until the adapter counts a request (discovery)
                    first = status.value.sport_requests

                    def answered() -> bool:
                        ddspy_write(sport_writer._ref, requests[0])
                        return status.value.sport_requests > first

                    wait_for(answered, 20, "the sport service to answer", 0.2)
                    time.sleep(2.0)
                s0, u0 = sim_status.value, status.value
                c0 = (cpu_s(adapter.pid), cpu_s(sim.pid))
                t0 = time.monotonic()
                sent, next_send = 0, t0 if rate_hz else float("inf")
                sport_sent, next_sport = 0, t0 if sport_hz else float("inf")
                while (now := time.monotonic()) - t0 < args.seconds:
                    if now >= next_sport:
                        ddspy_write(sport_writer._ref, requests[sport_sent % len(requests)])
                        sport_sent += 1
                        next_sport += 1.0 / sport_hz
                    elif now >= next_send:
                        ddspy_write(client.lowcmd._ref, command)
                        sent += 1
                        next_send += 1.0 / rate_hz
                    elif rate_hz <= 1000 and not sport_hz:
                        time.sleep(max(0.0, next_send - now))
                wall = time.monotonic() - t0
                seq = status.value.seq
                status.wait(lambda m: m.seq > seq, what="a status")  # counts up to date
                s1, u1 = sim_status.value, status.value
                wall_s = time.monotonic() - t0
                c1 = (cpu_s(adapter.pid), cpu_s(sim.pid))
                shed = getattr(u1, "lowcmd_shed", 0) - getattr(u0, "lowcmd_shed", 0)
                answered = u1.sport_requests - u0.sport_requests
                print(f"{phase:8} {sent / wall:14.0f} {(s1.sim_time_s - s0.sim_time_s) / wall_s:8.2f} "
                      f"{(u1.lowstate_published - u0.lowstate_published) / wall_s:12.0f} "
                      f"{(u1.lowcmd_forwarded - u0.lowcmd_forwarded) / wall_s:7.0f} {shed / wall_s:8.0f} "
                      f"{sport_sent / wall:11.0f} {answered / wall_s:10.0f} "
                      f"{100 * (c1[0] - c0[0]) / wall_s:10.0f}% {100 * (c1[1] - c0[1]) / wall_s:7.0f}%")

            ports = udp_ports(adapter.pid)
            log_before = len(adapter.log())
            rnd = random.Random(18)
            header = b"RTPS\x02\x01\x01\x10" + bytes(12)
            packets = [header + rnd.randbytes(rnd.randint(4, 120)) for _ in range(200)]
            t0 = time.monotonic()
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
                for i in range(args.garbage):
                    try:
                        sender.sendto(packets[i % len(packets)], ("127.0.0.1", ports[i % len(ports)]))
                    except OSError:
                        pass
            garbage_s = time.monotonic() - t0
            time.sleep(2.0)
            log = adapter.log()[log_before:]
            lines = [line for line in log.splitlines() if "malformed" in line]
            print(f"garbage: {args.garbage} packets in {garbage_s:.1f} s -> {len(lines)} log lines about them, "
                  f"{len(log.encode())} bytes of log; adapter alive: {adapter.alive()}")
    finally:
        procs.stop_all()


if __name__ == "__main__":
    main()
