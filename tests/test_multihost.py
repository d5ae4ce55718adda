"""Multi-host: router, sim, bridge and viz each on its own "host" (a network namespace with its own address).

The hosts are namespaces joined by veth pairs to a bridge in a hub namespace
(tests/netns.py); nothing touches the machine's own network. Each service is
started as users start it, `python -m zensim <service>` with `ZENSIM_*`
environment, only inside `ip netns exec <host>`. The router listens on its
host's address; the others are clients that connect to it by that address.

The test's own side is a plain zenoh client session on a fifth host. A zenoh
session belongs to a process, so it runs as a small subprocess (this file,
run as a script: `--probe`) that takes JSON requests on stdin and writes JSON
events on stdout (every joint state it sees, replies, the viz's status).

Then the sim's link is cut at the hub for a few seconds: states stop, every
process stays up; after the link is restored, states flow again and a new
command moves the joint, with no process restarted. The recovery time is
printed (pytest -s) and written to the test log. Needs root and iproute2: a
machine that cannot make namespaces fails the test, it does not skip.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from netns import CutKind, Network, NetnsError, NsProcess
from support import REPO, wait_for

HOSTS = ("router", "sim", "bridge", "viz", "client")
ZENOH_PORT = 7447
VIZ_PORT = 7000
VIZ_TOKEN = "multihost-test-token"
"""The viz serves beyond loopback here, so it requires a token (docs/security.md); the test sets it."""
JOINT = "left_elbow_joint"
CUT_S = 3.0
"""How long the sim's link is down: well under zenoh's 10 s lease, so the sessions stall, not close."""
TOL_RAD = 0.05
START_TIMEOUT_S = 40.0
RECOVERY_TIMEOUT_S = 15.0
"""Upper bound on recovery; TCP's retransmission backoff alone can add up to about CUT_S."""


class Probe:
    """The test's zenoh client, a subprocess in the client namespace (see `probe_main`)."""

    def __init__(self, net: Network, env: dict[str, str], log_dir: Path, connect: str, robot_id: str) -> None:
        argv = [sys.executable, "-u", str(Path(__file__).resolve()), "--probe", connect, robot_id]
        self.process = NsProcess(net, "client", argv, env, log_dir, name="probe",
                                 stdin=subprocess.PIPE, capture_stdout=True)
        self._lock = threading.Lock()
        self._replies: dict[int, dict] = {}
        self.states: list[tuple[float, dict]] = []
        """(arrival time, {"seq", "sim_time_s", "q"}) for every state/joints sample seen."""
        self.viz: list[tuple[float, dict]] = []
        """(arrival time, status) for every status message the viz's websocket sent."""
        self.ws_errors: list[str] = []
        """Errors of the probe's websocket to the viz: any one fails the test at the next look."""
        self._next_id = 0
        self._reader = threading.Thread(target=self._read, name="probe-reader", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.proc.stdout is not None
        for line in self.process.proc.stdout:
            try:
                event = json.loads(line)
            except ValueError:
                continue
            now = time.monotonic()
            with self._lock:
                if event.get("ev") == "state":
                    self.states.append((now, event))
                elif event.get("ev") == "viz":
                    self.viz.append((now, event))
                elif event.get("ev") == "ws_error":
                    self.ws_errors.append(event.get("error", "?"))
                elif "id" in event:
                    self._replies[event["id"]] = event

    def request(self, op: str, timeout_s: float = 15.0, **fields: Any) -> dict:
        """Send one request; wait for and return its reply."""
        with self._lock:
            self._next_id += 1
            rid = self._next_id
        stdin = self.process.proc.stdin
        assert stdin is not None
        stdin.write((json.dumps({"op": op, "id": rid, **fields}) + "\n").encode())
        stdin.flush()

        def reply() -> dict | None:
            with self._lock:
                found = self._replies.pop(rid, None)
            if found is None and not self.process.alive():
                raise AssertionError(f"the probe exited:\n{self.process.log()}")
            return found

        return wait_for(reply, timeout_s, f"the probe's reply to {op}")

    def states_after(self, t: float) -> list[tuple[float, dict]]:
        with self._lock:
            return [(at, s) for at, s in self.states if at > t]

    def latest_state(self) -> dict | None:
        with self._lock:
            return self.states[-1][1] if self.states else None

    def viz_after(self, t: float) -> list[tuple[float, dict]]:
        with self._lock:
            if self.ws_errors:
                raise AssertionError(f"the probe's websocket to the viz failed: {self.ws_errors}")
            return [(at, s) for at, s in self.viz if at > t]

    def stop(self) -> None:
        stdin = self.process.proc.stdin
        try:
            if stdin is not None and self.process.alive():
                stdin.write(b'{"op": "quit", "id": 0}\n')
                stdin.flush()
                self.process.proc.wait(5)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.process.stop()
        self._reader.join(5)
        if self.process.proc.stdout is not None:
            self.process.proc.stdout.close()


class Deployment:
    """Four services on four hosts and the probe on a fifth."""

    def __init__(self, net: Network, log_dir: Path) -> None:
        self.net = net
        self.robot_id = "t" + uuid.uuid4().hex[:10]
        self.router_endpoint = f"tcp/{net.address('router')}:{ZENOH_PORT}"
        self.viz_url = f"http://{net.address('viz')}:{VIZ_PORT}/"
        base = dict(os.environ, ZENSIM_ROBOT_ID=self.robot_id, ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
                    PYTHONUNBUFFERED="1")
        client = dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=self.router_endpoint)
        self.services: dict[str, NsProcess] = {}
        self.probe: Probe | None = None

        def start(host: str, args: list[str], env: dict[str, str]) -> None:
            self.services[host] = NsProcess(net, host, [sys.executable, "-m", "zensim", host, *args], env, log_dir)

        start("router", [], dict(base, ZENSIM_ZENOH_MODE="router", ZENSIM_ZENOH_LISTEN=self.router_endpoint))
        # Clients wait for their router (connect timeout -1), so they need not wait for it here.
        start("sim", ["--mode", "fixed", "--rtf", "1"], client)
        start("bridge", [], client)
        start("viz", [], dict(client, ZENSIM_VIZ_HOST="0.0.0.0", ZENSIM_VIZ_PORT=str(VIZ_PORT), ZENSIM_VIZ_TOKEN=VIZ_TOKEN))
        self.probe = Probe(net, client, log_dir, self.router_endpoint, self.robot_id)

    @property
    def expected_alive(self) -> set[str]:
        return set(self.services)

    def pids(self) -> dict[str, int]:
        return {name: p.pid for name, p in self.services.items()}

    def all_running(self) -> dict[str, int]:
        """The pids of the services; fails naming any that exited."""
        dead = {name: p.proc.returncode for name, p in self.services.items() if not p.alive()}
        assert not dead, f"services exited: {dead}\n" + "\n".join(
            f"----- {n} -----\n{self.services[n].log()}" for n in dead)
        return self.pids()

    def logs(self) -> str:
        parts = [f"----- {name} log -----\n{p.log()}" for name, p in self.services.items()]
        if self.probe is not None:
            parts.append(f"----- probe log -----\n{self.probe.process.log()}")
        return "\n".join(parts)

    def stop(self) -> None:
        if self.probe is not None:
            self.probe.stop()
        # Clients first, the router last, as an operator would.
        for name in ("viz", "bridge", "sim", "router"):
            if name in self.services:
                self.services[name].stop()


@pytest.fixture(scope="module")
def net() -> Iterator[Network]:
    try:
        network = Network(HOSTS)
    except NetnsError as exc:
        pytest.fail(f"cannot make network namespaces (this test needs root and iproute2; CI runs as root): {exc}",
                    pytrace=False)
    try:
        yield network
    finally:
        network.close()


@pytest.fixture(scope="module")
def deployment(net: Network, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Iterator[Deployment]:
    failed_before = request.session.testsfailed
    dep = Deployment(net, tmp_path_factory.mktemp("multihost"))
    try:
        assert dep.probe is not None
        wait_for(lambda: set(dep.probe.request("alive")["names"]) >= dep.expected_alive or not dep.all_running(),
                 START_TIMEOUT_S, f"{sorted(dep.expected_alive)} alive, seen from the client host", interval_s=0.2)
        yield dep
    finally:
        dep.stop()
        if request.session.testsfailed > failed_before:
            print("\n" + dep.logs())


def joint_q(probe: Probe, index: int) -> float | None:
    state = probe.latest_state()
    return None if state is None else state["q"][index]


def put_target(probe: Probe, robot_id: str, q: float) -> None:
    probe.request("put", key=f"zensim/{robot_id}/cmd/joints", value={"names": [JOINT], "q": [q]})


def tracks(probe: Probe, index: int, target: float) -> bool:
    q = joint_q(probe, index)
    return q is not None and abs(q - target) < TOL_RAD


def joint_index(probe: Probe) -> tuple[int, float]:
    """JOINT's index in the state vectors and its default position in the fixed mode."""
    info = wait_for(lambda: probe.request("info").get("info"), 30, "info/robot from the client host")
    index = info["joint_names"].index(JOINT)
    return index, info["default_q"]["fixed"][index]


def test_commands_and_states_flow_between_hosts(deployment: Deployment) -> None:
    dep, probe = deployment, deployment.probe
    assert probe is not None
    index, _ = joint_index(probe)
    wait_for(lambda: len(probe.states_after(0)) > 10, 10, "state/joints at the client host")
    for target in (0.6, -0.2):
        put_target(probe, dep.robot_id, target)
        wait_for(lambda: tracks(probe, index, target), 10, f"{JOINT} at {target} (client -> bridge -> sim)")
    assert probe.request("http", url=dep.viz_url).get("status") == 403  # served beyond loopback: token needed
    page = probe.request("http", url=f"{dep.viz_url}?token={VIZ_TOKEN}")  # then the cookie, after a redirect
    assert page.get("status") == 200 and page.get("bytes", 0) > 0, page
    # The viz host gets states too: its page's websocket reports the newest state seq it holds.
    probe.request("ws", url=dep.viz_url.replace("http://", "ws://") + f"ws?token={VIZ_TOKEN}")
    wait_for(lambda: any(s.get("state_seq") for _, s in probe.viz_after(0)), 20, "states at the viz host")
    # And commands flow from the viz's sliders (its websocket) through the bridge to the sim.
    probe.request("ws_send", message={"type": "targets", "names": [JOINT], "q": [0.3]})
    wait_for(lambda: tracks(probe, index, 0.3), 10, f"{JOINT} at 0.3 (viz slider -> bridge -> sim)")


@pytest.mark.parametrize("how", ["carrier", "remote"])
def test_cut_sim_link_recovers_without_restart(
    deployment: Deployment, net: Network, how: CutKind, record_property: Callable[[str, object], None]
) -> None:
    dep, probe = deployment, deployment.probe
    assert probe is not None
    index, default_q = joint_index(probe)
    pids = dep.all_running()
    held = 0.5 if how == "carrier" else 0.7
    assert abs(held - default_q) > 0.2, "the held target must differ from the watchdog's pose"
    put_target(probe, dep.robot_id, held)
    wait_for(lambda: tracks(probe, index, held), 10, f"{JOINT} at {held} before the cut")
    seq_before = probe.latest_state()["seq"]

    cut_at = time.monotonic()
    net.cut("sim", how)
    try:
        # Nothing reaches the client while the link is down (allow what was already on the wire).
        time.sleep(CUT_S)
        during = [s for at, s in probe.states_after(cut_at + 0.3)]
        assert not during, f"{len(during)} states arrived while the sim's link was down"
        dep.all_running()
    finally:
        restored_at = time.monotonic()
        net.restore("sim")

    # States flow again on the same sessions: seq goes on from where it was (the sim did not restart).
    first_at, first = wait_for(lambda: next(iter(probe.states_after(restored_at)), None),
                               RECOVERY_TIMEOUT_S, "state/joints at the client after the link came back")
    assert first["seq"] > seq_before
    recovery_s = first_at - restored_at
    # With no motor commands for more than its watchdog_timeout_s (0.5 s), the sim held the default
    # pose; the bridge kept its target through the cut, so once commands reach the sim again the
    # joint goes back to the held target with no new command.
    def back_at_held() -> float | None:
        states = probe.states_after(restored_at)
        off = [i for i, (_, s) in enumerate(states) if abs(s["q"][index] - held) >= TOL_RAD]
        if not off or off[-1] + 1 == len(states):
            return None
        return states[off[-1] + 1][0]

    commands_s = wait_for(back_at_held, RECOVERY_TIMEOUT_S, f"{JOINT} away from {held} (watchdog), then back") \
        - restored_at
    # A new command goes all the way through again.
    new = -0.4
    sent_at = time.monotonic()
    put_target(probe, dep.robot_id, new)
    wait_for(lambda: tracks(probe, index, new), 10, f"{JOINT} at {new} after the cut")
    command_s = time.monotonic() - sent_at
    # The viz's status (5 Hz) names the newest state it holds: it moves on past the cut too.
    before_cut = max((s.get("state_seq") or 0 for at, s in probe.viz_after(0) if at < cut_at), default=0)
    wait_for(lambda: any((s.get("state_seq") or 0) > before_cut for _, s in probe.viz_after(restored_at)),
             RECOVERY_TIMEOUT_S, "new states at the viz host after the cut")
    assert set(probe.request("alive")["names"]) >= dep.expected_alive
    assert dep.all_running() == pids, "a service restarted"
    for name, value in (("cut_s", restored_at - cut_at), ("states_back_s", recovery_s),
                        ("held_target_back_s", commands_s), ("new_command_tracked_s", command_s)):
        record_property(name, round(value, 3))
    print(f"\n{how} cut {restored_at - cut_at:.1f} s: first state {recovery_s:.2f} s after restore, "
          f"held target back {commands_s:.2f} s after restore, new command tracked in {command_s:.2f} s")


@pytest.mark.parametrize("compose_file, env", [
    ("sim-host.yaml", {}),
    ("ui-host.yaml", {"ZENSIM_ROUTER_HOST": "192.0.2.10"}),
])
def test_multihost_compose_files_are_valid(compose_file: str, env: dict[str, str]) -> None:
    """`compose config` accepts the split deployment's files (nothing is built or started)."""
    from docker_stack import DockerUnavailable, compose_command

    try:
        command = compose_command()
    except DockerUnavailable as exc:
        pytest.fail(str(exc))
    path = REPO / "deploy" / "multihost" / compose_file
    done = subprocess.run([*command, "-f", str(path), "config"], capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, **env))
    assert done.returncode == 0, done.stderr
    assert "7447" in done.stdout


def test_ui_host_compose_file_needs_the_router_address() -> None:
    from docker_stack import compose_command

    env = {k: v for k, v in os.environ.items() if k != "ZENSIM_ROUTER_HOST"}
    path = REPO / "deploy" / "multihost" / "ui-host.yaml"
    done = subprocess.run([*compose_command(), "-f", str(path), "config"], capture_output=True, text=True,
                          timeout=60, env=env)
    assert done.returncode != 0 and "ZENSIM_ROUTER_HOST" in done.stderr


# --------------------------------------------------------------------------------------------------
# The probe: run in the client namespace as `python tests/test_multihost.py --probe ENDPOINT ROBOT_ID`.

def probe_main(connect: str, robot_id: str) -> int:
    """A plain zenoh client: JSON requests on stdin, JSON events on stdout (see `Probe`)."""
    import asyncio
    import urllib.request

    import zenoh

    from zensim.common.wire import payload_of
    from zensim.schemas import Codec, JointState

    out_lock = threading.Lock()

    def emit(event: dict) -> None:
        line = json.dumps(event) + "\n"
        with out_lock:
            sys.stdout.write(line)
            sys.stdout.flush()

    codec = Codec(JointState)
    root = f"zensim/{robot_id}"

    def on_state(sample: zenoh.Sample) -> None:
        state = codec.decode(*payload_of(sample))
        emit({"ev": "state", "seq": state.seq, "sim_time_s": state.sim_time_s, "q": list(state.q)})

    ws: dict[str, Any] = {}

    def websocket(url: str, opened: threading.Event) -> None:
        import tornado.websocket

        async def main() -> None:
            conn = await tornado.websocket.websocket_connect(url)
            ws["conn"], ws["loop"] = conn, asyncio.get_running_loop()
            opened.set()
            while (message := await conn.read_message()) is not None:
                if isinstance(message, bytes):
                    if message[:4] == (2).to_bytes(4, "little"):  # a pose frame: ack it like the page does
                        await conn.write_message(json.dumps({"type": "ack"}))
                    continue
                data = json.loads(message)
                if data.get("type") == "status":
                    emit({"ev": "viz", "state_seq": data.get("state_seq"), "alive": data.get("alive")})

        try:
            asyncio.run(main())
        except Exception as exc:  # reported to the test, which fails on it
            emit({"ev": "ws_error", "error": repr(exc)})
            opened.set()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        session.declare_subscriber(f"{root}/state/joints", on_state)
        for line in sys.stdin:
            request = json.loads(line)
            op, reply = request["op"], {"id": request["id"]}
            if op == "quit":
                break
            try:
                if op == "alive":
                    reply["names"] = sorted(str(r.ok.key_expr).rsplit("/", 1)[-1]
                                            for r in session.liveliness().get(f"{root}/alive/*", timeout=1.0) if r.ok)
                elif op == "info":
                    for r in session.get(f"{root}/info/robot?format=json", timeout=2.0):
                        if r.ok is not None:
                            reply["info"] = json.loads(r.ok.payload.to_bytes())
                elif op == "put":
                    session.put(request["key"], json.dumps(request["value"]).encode(),
                                encoding=zenoh.Encoding("application/json"))
                elif op == "http":
                    opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())  # a browser's cookies
                    try:
                        with opener.open(request["url"], timeout=10) as response:
                            reply.update(status=response.status, bytes=len(response.read()))
                    except urllib.error.HTTPError as exc:
                        exc.close()  # an HTTPError holds the response's socket until closed
                        reply.update(status=exc.code)
                elif op == "ws":
                    opened = threading.Event()
                    threading.Thread(target=websocket, args=(request["url"], opened), daemon=True).start()
                    opened.wait(10)
                    reply["connected"] = "conn" in ws
                elif op == "ws_send":
                    ws["loop"].call_soon_threadsafe(ws["conn"].write_message, json.dumps(request["message"]))
                else:
                    reply["error"] = f"unknown op {op}"
            except Exception as exc:  # reported to the test, which fails on it
                reply["error"] = repr(exc)
            emit(reply)
    return 0


if __name__ == "__main__" and len(sys.argv) == 4 and sys.argv[1] == "--probe":
    sys.exit(probe_main(sys.argv[2], sys.argv[3]))
