"""Helpers for the test that runs the real compose stack: the Docker engine, the compose command,
the offline base image, and one compose project of its own."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

from support import REPO
from zensim.schemas import keys

BASE_IMAGE = "zensim-base:bookworm"
CA_DIR = Path("/usr/local/share/ca-certificates")
SERVICES = tuple(s for s in keys.SERVICES if s not in keys.OPTIONAL_SERVICES)  # compose.yaml's default ones


class DockerUnavailable(RuntimeError):
    """The Docker CLI, the engine or a compose command is missing; the message says which."""


def run(cmd: list[str], *, env: dict[str, str] | None = None, timeout_s: float = 120,
        check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run a command, capture stdout and stderr as text; on failure raise with both in the message."""
    try:
        done = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"").decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        raise AssertionError(f"timed out after {timeout_s} s: {' '.join(cmd)}\n{out[-4000:]}\n{err[-4000:]}") from None
    if check and done.returncode != 0:
        raise AssertionError(
            f"exit {done.returncode}: {' '.join(cmd)}\n--- stdout\n{done.stdout[-6000:]}\n--- stderr\n{done.stderr[-6000:]}"
        )
    return done


def require_engine() -> None:
    """Raise DockerUnavailable unless the docker CLI exists and `docker info` reaches the engine."""
    if shutil.which("docker") is None:
        raise DockerUnavailable("the `docker` command is not installed")
    done = subprocess.run(["docker", "info", "--format", "{{.ServerVersion}}"],
                          capture_output=True, text=True, timeout=60)
    if done.returncode != 0 or not done.stdout.strip():
        raise DockerUnavailable(f"`docker info` cannot reach the Docker engine: {(done.stderr or done.stdout).strip()}")


def compose_command() -> list[str]:
    """`docker compose` (v2) when it works, else `docker-compose` (v1)."""
    v2 = subprocess.run(["docker", "compose", "version"], capture_output=True, text=True, timeout=60)
    if v2.returncode == 0:
        return ["docker", "compose"]
    if shutil.which("docker-compose"):
        return ["docker-compose"]
    raise DockerUnavailable("neither `docker compose` (v2) nor `docker-compose` (v1) is installed")


def extra_ca_certs() -> str:
    """PEM text of the machine's extra CAs (a TLS-intercepting proxy's), for pip in `docker build`.

    Byte for byte what docs/deployment.md passes, `"$(cat /usr/local/share/ca-certificates/*.crt)"`,
    since a build arg's value is part of the layer cache key: the test and a developer share the cache.
    """
    if not CA_DIR.is_dir():
        return ""
    return "".join(p.read_text() for p in sorted(CA_DIR.glob("*.crt"))).rstrip("\n")


def build_base_image(timeout_s: float = 600) -> None:
    """scripts/build-base-image (skips when the image exists); via `sudo -n` when not root."""
    cmd = [str(REPO / "scripts" / "build-base-image")]
    if os.geteuid() != 0:
        cmd = ["sudo", "-n", *cmd]
    run(cmd, timeout_s=timeout_s)


def free_ports(n: int) -> list[int]:
    """`n` different TCP ports that nothing listens on right now (bound together, so distinct)."""
    import socket

    socks = [socket.socket() for _ in range(n)]
    try:
        for sock in socks:
            sock.bind(("127.0.0.1", 0))
        return [sock.getsockname()[1] for sock in socks]
    finally:
        for sock in socks:
            sock.close()


class ComposeStack:
    """One compose project (`-p name`) of compose.yaml (plus override `files`), with its own env (ports, image, base)."""

    def __init__(self, compose: list[str], project: str, env: dict[str, str],
                 files: tuple[str, ...] = ("compose.yaml",)) -> None:
        self.compose = compose
        self.project = project
        self.env = {**os.environ, **env}
        self.files = [arg for name in files for arg in ("-f", str(REPO / name))]

    def run(self, *args: str, timeout_s: float = 120, check: bool = True) -> subprocess.CompletedProcess[str]:
        return run([*self.compose, *self.files, "-p", self.project, *args],
                   env=self.env, timeout_s=timeout_s, check=check)

    def containers(self, all_states: bool = True) -> list[str]:
        """Ids of the project's containers, found by compose's label (works for v1 and v2)."""
        cmd = ["docker", "ps", "-q", "--no-trunc", "--filter", f"label=com.docker.compose.project={self.project}"]
        if all_states:
            cmd.insert(2, "-a")
        return run(cmd).stdout.split()

    def networks(self) -> list[str]:
        return run(["docker", "network", "ls", "-q", "--filter",
                    f"label=com.docker.compose.project={self.project}"]).stdout.split()

    def states(self) -> dict[str, dict]:
        """service -> {"status": running/exited/..., "health": starting/healthy/unhealthy/none, "restarts": n}."""
        ids = self.containers()
        if not ids:
            return {}
        out = {}
        for info in json.loads(run(["docker", "inspect", *ids]).stdout):
            service = info["Config"]["Labels"].get("com.docker.compose.service", info["Name"])
            state = info["State"]
            out[service] = {
                "status": state["Status"],
                "health": (state.get("Health") or {}).get("Status", "none"),
                "restarts": info.get("RestartCount", 0),
                "exit_code": state.get("ExitCode"),
            }
        return out

    def wait_healthy(self, services: tuple[str, ...] = SERVICES, timeout_s: float = 180) -> dict[str, float]:
        """Wait until every service's container reports `healthy`; returns seconds until each did.

        Fails at once when a container reports `unhealthy` or has restarted (it crashed).
        """
        start = time.monotonic()
        healthy_at: dict[str, float] = {}
        states: dict[str, dict] = {}
        while time.monotonic() - start < timeout_s:
            states = self.states()
            for service in services:
                st = states.get(service)
                if st is None:
                    continue
                if st["health"] == "unhealthy" or st["restarts"] > 0 or st["status"] in ("exited", "dead"):
                    raise AssertionError(f"service {service} failed: {st}")
                if st["health"] == "healthy" and service not in healthy_at:
                    healthy_at[service] = time.monotonic() - start
            if len(healthy_at) == len(services):
                return healthy_at
            time.sleep(1.0)
        raise AssertionError(f"not all services healthy after {timeout_s} s: {states}")

    def logs(self) -> str:
        done = self.run("logs", "--no-color", "--timestamps", timeout_s=60, check=False)
        return done.stdout + done.stderr

    def down(self, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
        return self.run("down", "-v", "--remove-orphans", "--timeout", "10", timeout_s=timeout_s, check=False)
