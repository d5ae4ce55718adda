"""Network namespaces for tests that need separate hosts on one machine (root and iproute2).

`Network` makes one namespace per host, each with its own `eth0` and address,
all joined by veth pairs to a Linux bridge that lives in a dedicated hub
namespace. Nothing is created in the machine's own namespace: no interface, no
route, no address, so the host's networking is never touched and nothing is
routed outside. Each host's `lo` is up (zenoh and the viz bind it too).

Cutting a host off (`cut`) loses every packet to or from it until `restore`;
the host keeps its address and route and its sockets stay open. Two kinds: the
hub side of its veth goes down, so the host sees its carrier drop (a cable
pulled at the host), or the veth leaves the bridge with both ends still up (a
failure further along the path, which no host notices except by lost packets).

    with Network(["router", "sim"]) as net:
        proc = NsProcess(net, "sim", ["python", "-m", "zensim", "sim"], env, log_dir)
        net.cut("sim"); ...; net.restore("sim")
"""

from __future__ import annotations

import ipaddress
import os
import secrets
import shutil
import signal
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

SUBNET_BASE = "10.231"
"""First two octets of the test addresses; the third is random per network, hosts are .1, .2, ..."""
IP_TIMEOUT_S = 10.0
CutKind = Literal["carrier", "remote"]


class NetnsError(RuntimeError):
    """An `ip` command failed (not root, no iproute2, no netns support); the message says which."""


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run `ip ARGS...`; raise NetnsError with its stderr when it fails and `check` is set."""
    if shutil.which("ip") is None:
        raise NetnsError("the `ip` command is missing: apt-get install -y iproute2")
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    if check and done.returncode != 0:
        raise NetnsError(f"`ip {' '.join(args)}` failed ({done.returncode}): {done.stderr.strip()}")
    return done


@dataclass(frozen=True)
class Host:
    """One namespace: its name, its address on the test network and its veth's name in the hub."""

    name: str
    netns: str
    address: str
    hub_link: str


class Network:
    """Namespaces `<prefix>-<host>` joined by a bridge in `<prefix>-hub`, on 10.231.<random>.0/24.

    Args:
        hosts: short host names ("router", "sim", ...); each gets a namespace and an address.
        prefix: namespace name prefix; default `zs` + 6 random hex digits, unique per run.

    Raises:
        NetnsError: creating a namespace or a link failed (e.g. not root); everything made so far is removed.
    """

    def __init__(self, hosts: Sequence[str], prefix: str | None = None) -> None:
        if len(set(hosts)) != len(hosts) or not 0 < len(hosts) < 250:
            raise ValueError(f"host names must be unique, 1 to 249 of them: {hosts}")
        self.prefix = prefix or "zs" + secrets.token_hex(3)
        self.hub = f"{self.prefix}-hub"
        third = secrets.randbelow(250) + 1
        self.subnet = ipaddress.ip_network(f"{SUBNET_BASE}.{third}.0/24")
        self.hosts: dict[str, Host] = {
            name: Host(name, f"{self.prefix}-{name}", f"{SUBNET_BASE}.{third}.{i + 1}", f"v{i}")
            for i, name in enumerate(hosts)
        }
        self._made: list[str] = []
        try:
            self._create()
        except BaseException:
            self.close()
            raise

    def _add_netns(self, name: str) -> None:
        ip("netns", "add", name)
        self._made.append(name)
        ip("-n", name, "link", "set", "lo", "up")

    def _create(self) -> None:
        self._add_netns(self.hub)
        ip("-n", self.hub, "link", "add", "br0", "type", "bridge", "forward_delay", "0", "stp_state", "0")
        ip("-n", self.hub, "link", "set", "br0", "up")
        for host in self.hosts.values():
            self._add_netns(host.netns)
            ip("-n", self.hub, "link", "add", host.hub_link, "type", "veth", "peer", "name", "eth0", "netns", host.netns)
            ip("-n", self.hub, "link", "set", host.hub_link, "master", "br0")
            ip("-n", self.hub, "link", "set", host.hub_link, "up")
            ip("-n", host.netns, "addr", "add", f"{host.address}/{self.subnet.prefixlen}", "dev", "eth0")
            ip("-n", host.netns, "link", "set", "eth0", "up")

    def address(self, host: str) -> str:
        return self.hosts[host].address

    def exec_argv(self, host: str, argv: Sequence[str]) -> list[str]:
        """`argv` run inside `host`'s namespace. `ip netns exec` execs it: the pid is the program's own."""
        return ["ip", "netns", "exec", self.hosts[host].netns, *argv]

    def cut(self, host: str, how: CutKind = "carrier") -> None:
        """Cut `host` off: every packet to or from it is lost; its sockets stay open.

        Args:
            host: the host to cut off.
            how: "carrier": the hub side of its veth goes down, so the host's `eth0` loses
                carrier (a cable pulled at the host: its kernel knows). "remote": the veth is
                taken off the bridge and both ends stay up (a failure further along the path:
                nobody's link changes, only packets vanish).
        """
        link = self.hosts[host].hub_link
        if how == "carrier":
            ip("-n", self.hub, "link", "set", link, "down")
        elif how == "remote":
            ip("-n", self.hub, "link", "set", link, "nomaster")
        else:
            raise ValueError(f"unknown cut {how!r}")

    def restore(self, host: str) -> None:
        """Undo `cut`, whichever kind it was: the veth back on the bridge, and up."""
        link = self.hosts[host].hub_link
        ip("-n", self.hub, "link", "set", link, "master", "br0")
        ip("-n", self.hub, "link", "set", link, "up")

    def close(self) -> None:
        """Delete every namespace this network made (their veths and the bridge go with them). Idempotent.

        Stop the processes running inside first: a namespace with a process in it lives on
        (unnamed) until that process exits.
        """
        for name in reversed(self._made):
            ip("netns", "delete", name, check=False)
        self._made.clear()

    def __enter__(self) -> Network:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class NsProcess:
    """A program run in a host's namespace (`ip netns exec NS argv...`), output to a log file.

    Started in its own session, so stopping it reaches only it and its children. With
    `capture_stdout`, whoever reads `proc.stdout` closes it after `stop()`.
    """

    def __init__(
        self,
        net: Network,
        host: str,
        argv: Sequence[str],
        env: dict[str, str],
        log_dir: Path,
        name: str | None = None,
        stdin: int | None = None,
        capture_stdout: bool = False,
    ) -> None:
        self.host = host
        self.name = name or host
        self.log_path = log_dir / f"{self.name}-{time.monotonic_ns()}.log"
        self._log = self.log_path.open("wb")
        self.proc = subprocess.Popen(
            net.exec_argv(host, argv),
            env=env,
            stdin=stdin,
            stdout=subprocess.PIPE if capture_stdout else self._log,
            stderr=self._log if capture_stdout else subprocess.STDOUT,
            start_new_session=True,
        )
        self.pid = self.proc.pid

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """SIGTERM, wait up to `timeout_s`, then SIGKILL its process group; returns the exit code."""
        try:
            if self.alive():
                self.proc.send_signal(signal.SIGTERM)
            try:
                return self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                try:
                    return self.proc.wait(5)
                except subprocess.TimeoutExpired:
                    return None
        finally:
            self._log.close()
            if self.proc.stdin is not None:
                try:
                    self.proc.stdin.close()
                except OSError:  # a broken pipe: the program is gone anyway
                    pass
