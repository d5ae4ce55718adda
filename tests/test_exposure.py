"""Nothing exposed by default: the sockets of services started with no network flags, of `zensim up`, and
compose's defaults.

Each run gets its own network namespace (tests/netns.py) with a LAN interface `eth0` beside `lo`, so
the default meeting point tcp/127.0.0.1:7447 and the viz's port 7000 are free, and what the kernel
lists for the namespace (/proc/<pid>/net/...) is exactly what our processes opened.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from netns import Network, NetnsError, NsProcess
from support import REPO, wait_for

SCOUTING_PORT = 7446
SCOUTING_GROUP_HEX = "E00000E0"  # 224.0.0.224 as /proc/net/igmp writes it
LOOPBACK = {"127.0.0.1", "::1"}


@pytest.fixture
def net() -> Iterator[Network]:
    try:
        with Network(["solo"]) as network:
            yield network
    except NetnsError as exc:
        pytest.skip(f"no network namespaces here: {exc}")


def _addr(hex_addr: str) -> tuple[str, int]:
    host, port = hex_addr.split(":")
    raw = bytes.fromhex(host)
    if len(raw) == 4:
        ip = ".".join(str(b) for b in reversed(raw))
    else:  # four little-endian 32-bit words
        words = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
        import ipaddress

        ip = str(ipaddress.IPv6Address(words))
        mapped = ipaddress.IPv6Address(words).ipv4_mapped
        ip = str(mapped) if mapped else ip
    return ip, int(port, 16)


def sockets(pid: int) -> dict[str, list[tuple[str, int]]]:
    """TCP listeners and UDP sockets of the namespace `pid` lives in: {"tcp_listen": [...], "udp": [...]}."""
    out: dict[str, list[tuple[str, int]]] = {"tcp_listen": [], "udp": []}
    for table in ("tcp", "tcp6", "udp", "udp6"):
        lines = Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]
        for line in lines:
            fields = line.split()
            local, state = fields[1], fields[3]
            if table.startswith("tcp") and state == "0A":
                out["tcp_listen"].append(_addr(local))
            elif table.startswith("udp"):
                out["udp"].append(_addr(local))
    return out


def assert_nothing_exposed(pid: int) -> None:
    found = sockets(pid)
    assert found["tcp_listen"], "expected some loopback listeners"
    exposed = [s for s in found["tcp_listen"] if s[0] not in LOOPBACK]
    assert not exposed, f"TCP listeners beyond loopback: {exposed}"
    assert not [s for s in found["udp"] if s[1] == SCOUTING_PORT or s[0] not in LOOPBACK], found["udp"]
    assert SCOUTING_GROUP_HEX not in Path(f"/proc/{pid}/net/igmp").read_text().upper()


def env_without_network_settings() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ZENSIM_")}
    return dict(env, PYTHONUNBUFFERED="1", ZENSIM_SIM_MODE="fixed")


def check(net: Network, service: str) -> bool:
    done = subprocess.run(net.exec_argv("solo", [sys.executable, "-m", "zensim", "check", "--service", service]),
                          env=env_without_network_settings(), capture_output=True, timeout=60)
    return done.returncode == 0


def test_services_started_by_hand_with_no_flags_meet_on_loopback_only(net: Network, tmp_path: Path) -> None:
    env = env_without_network_settings()
    procs = [NsProcess(net, "solo", [sys.executable, "-m", "zensim", name], env, tmp_path, name=name)
             for name in ("sim", "bridge", "viz")]
    sim, bridge, viz = procs
    try:
        wait_for(lambda: "robot from the sim" in bridge.log() or not bridge.alive(), 90, "the bridge to find the sim")
        wait_for(lambda: "sim is alive" in viz.log() or not viz.alive(), 30, "the viz to see the sim")
        assert all(p.alive() for p in procs), "\n".join(p.log() for p in procs)
        assert check(net, "bridge") and check(net, "viz")
        assert_nothing_exposed(sim.pid)
    finally:
        for proc in procs:
            proc.stop()


def test_zensim_up_with_defaults_listens_on_loopback_only(net: Network, tmp_path: Path) -> None:
    up = NsProcess(net, "solo", [sys.executable, "-m", "zensim", "up"], env_without_network_settings(), tmp_path,
                   name="up")
    try:
        wait_for(lambda: check(net, "viz") or not up.alive(), 120, "zensim up's viz", interval_s=1.0)
        assert check(net, "sim") and check(net, "bridge"), up.log()
        assert_nothing_exposed(up.pid)
    finally:
        up.stop(15)


def children(pid: int) -> dict[int, str]:
    """The direct children of `pid`: {pid: command line}."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    found[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except (OSError, IndexError, ValueError):
                continue
    return found


@pytest.mark.skipif(not Path("/usr/bin/rosmaster").exists(), reason="needs Debian's ROS 1")
def test_zensim_up_ros1_keeps_the_ros_side_on_loopback_and_zensim_s_secrets_from_it(net: Network,
                                                                                   tmp_path: Path) -> None:
    """`zensim up --ros1` with no ROS_IP (ROS's own default: every interface): the master, the gateway's XML-RPC
    and TCPROS servers all listen on loopback, no rosout listens anywhere, and the master's environment holds
    nothing of zensim's (the viewer token once reached roslaunch's world-readable logs)."""
    secret = "viewer-token-that-must-not-leak"
    env = {k: v for k, v in env_without_network_settings().items() if not k.startswith("ROS_")}
    env.update(ROS_HOME=str(tmp_path / "ros"), ZENSIM_VIZ_TOKEN=secret)
    up = NsProcess(net, "solo", [sys.executable, "-m", "zensim", "up", "--ros1", "--viz", "false"], env, tmp_path,
                   name="up")
    try:
        wait_for(lambda: check(net, "ros1") or not up.alive(), 120, "zensim up's ros1 gateway", interval_s=1.0)
        assert up.alive(), up.log()
        assert_nothing_exposed(up.pid)
        masters = [pid for pid, command in children(up.pid).items() if "rosmaster" in command]
        assert len(masters) == 1, children(up.pid)
        master_env = Path(f"/proc/{masters[0]}/environ").read_bytes().split(b"\0")
        assert not [v for v in master_env if v.startswith(b"ZENSIM_") or secret.encode() in v], master_env
        assert b"ROS_IP=127.0.0.1" in master_env
        logs = [p for p in (tmp_path / "ros").rglob("*") if p.is_file()]
        assert not [p for p in logs if secret in p.read_text(errors="replace")], logs
    finally:
        up.stop(20)


NOT_ZENOH = {"roscore"}
"""Compose services that are no Zenoh client (the ROS master of the ros1 profile): nothing to secure on Zenoh."""


def test_compose_defaults_publish_on_loopback_and_scout_nowhere() -> None:
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())
    for name, service in compose["services"].items():
        for port in service.get("ports", []):
            assert port.startswith("${ZENSIM_BIND:-127.0.0.1}:"), (name, port)
        if name in NOT_ZENOH:
            continue
        assert service["environment"]["ZENSIM_ZENOH_MULTICAST_SCOUTING"] == "false", name


def test_a_zenoh_config_file_widens_nothing_unless_it_says_listen(net: Network, tmp_path: Path) -> None:
    """ZENSIM_ZENOH_CONFIG_FILE (docs/multihost.md) for other settings keeps the loopback default; a file that
    says `listen` itself is obeyed. Each service logs where it listens."""
    quiet = tmp_path / "lease.json5"
    quiet.write_text('{ transport: { link: { tx: { lease: 5000 } } } }\n')  # says nothing about listen
    env = dict(env_without_network_settings(), ZENSIM_ZENOH_CONFIG_FILE=str(quiet))
    router = NsProcess(net, "solo", [sys.executable, "-m", "zensim", "router"], env, tmp_path, name="router")
    sim = None
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 30, "the router")
        sim = NsProcess(net, "solo", [sys.executable, "-m", "zensim", "sim"], env, tmp_path, name="sim")
        wait_for(lambda: "sim up" in sim.log() or not sim.alive(), 90, "the sim")
        assert router.alive() and sim.alive(), router.log() + sim.log()
        assert "listening on tcp/127.0.0.1:7447" in router.log(), router.log()
        assert "zenoh peer: listening on tcp/127.0.0.1:0" in sim.log(), sim.log()
        assert_nothing_exposed(router.pid)
    finally:
        for proc in (sim, router):
            if proc is not None:
                proc.stop()
    wide = tmp_path / "wide.json5"
    wide.write_text('{ listen: { endpoints: ["tcp/0.0.0.0:7448"] } }\n')
    env = dict(env_without_network_settings(), ZENSIM_ZENOH_CONFIG_FILE=str(wide))
    router = NsProcess(net, "solo", [sys.executable, "-m", "zensim", "router"], env, tmp_path, name="router-wide")
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 30, "the router")
        assert ("0.0.0.0", 7448) in sockets(router.pid)["tcp_listen"], router.log()
        assert "listening on tcp/0.0.0.0:7448" in router.log()
    finally:
        router.stop()


def test_compose_secure_covers_every_service_of_every_profile() -> None:
    """Each service compose.yaml can start (any profile) is, under compose.secure.yaml, a tls/ client of the
    router with only its own role's credentials (and the viewer's, for its healthcheck)."""
    plain = yaml.safe_load((REPO / "compose.yaml").read_text())["services"]
    secure = yaml.safe_load((REPO / "compose.secure.yaml").read_text())["services"]
    assert set(plain) - NOT_ZENOH == set(secure), f"not secured: {sorted(set(plain) - NOT_ZENOH - set(secure))}"
    for name, service in secure.items():
        env = service["environment"]
        assert env["ZENSIM_SECURE_DIR"] == "/run/zensim-secrets", name
        endpoint = env["ZENSIM_ZENOH_LISTEN" if name == "router" else "ZENSIM_ZENOH_CONNECT"]
        assert endpoint.startswith("tls/"), (name, endpoint)
        mounted = {volume.split(":")[1].rsplit("/", 1)[-1] for volume in service["volumes"]}
        own = {"router.json5", "users.txt"} if name == "router" else {f"{name}.json5"}
        assert mounted == own | {"viewer.json5"}, (name, mounted)
        assert all(volume.endswith(":ro") for volume in service["volumes"]), name
