"""What every benchmark needs: child processes with logs, a plain zenoh client, waiting, the newest sample.

Benchmarks run by hand (`python benchmarks/<name>.py`), so this folder is on sys.path and
`from harness import ...` needs nothing else. They do not import the test suite's helpers: a
benchmark must keep working however the tests are arranged. Three pieces of test scaffolding are too
big to keep twice (the headless chromium driver, tests/browser.py, the SDK-style DDS client,
tests/unitree_sdk.py, and the network namespaces, tests/netns.py): `test_scaffolding` loads them by
path, in this one place.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

import zenoh

from zensim.common.wire import payload_of
from zensim.schemas import Codec

T = TypeVar("T")

REPO = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_for(condition: Callable[[], T], timeout_s: float, what: str, interval_s: float = 0.02) -> T:
    """Poll `condition` until it returns something truthy, and return that; TimeoutError after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)
    return value


def cpu_s(pid: int) -> float:
    """CPU time (user + system) a process has used, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU time (user + system) each kind of thread of a process has used, s: `main` (the process's first
    thread), zenoh's runtime threads by their names less the number (rx, tx, net, app, acc), and
    `python` for every other thread Python started (on 3.11 they all carry the process's name)."""
    used: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")].rstrip("0123456789").rstrip("-")
        name = "main" if task.name == str(pid) else ("python" if name.startswith("python") else name)
        fields = stat.rsplit(")", 1)[1].split()
        used[name] = used.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return used


def rss_mb(pid: int) -> float:
    """Resident memory of a process, MB (NaN when /proc does not say)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Child(subprocess.Popen):
    """A child process whose output goes to a log file."""

    def __init__(self, argv: list[str], env: dict[str, str], log_path: Path) -> None:
        self.log_path = log_path
        with log_path.open("wb") as log:
            super().__init__(argv, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.poll() is None

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """SIGINT, wait, then SIGKILL to its process group; returns the exit code."""
        if self.alive():
            self.send_signal(signal.SIGINT)
            try:
                return self.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.pid, signal.SIGKILL)
        return self.wait(timeout_s)


class Processes:
    """The benchmark's children, logs in one temporary folder; `stop_all` in a `finally`."""

    def __init__(self, env: dict[str, str], prefix: str = "zensim-bench-") -> None:
        self.env = env
        self.dir = Path(tempfile.mkdtemp(prefix=prefix))
        self.children: list[Child] = []

    def start(self, name: str, argv: list[str], env: dict[str, str] | None = None) -> Child:
        child = Child(argv, {**self.env, **(env or {})}, self.dir / f"{name}-{len(self.children)}.log")
        self.children.append(child)
        return child

    def zensim(self, command: str, *args: str, env: dict[str, str] | None = None) -> Child:
        """`python -m zensim COMMAND ARGS`, as users start a service."""
        return self.start(command, [sys.executable, "-m", "zensim", command, *args], env)

    def stop_all(self) -> None:
        for child in reversed(self.children):
            child.stop()


def behind_private_router(robot_id: str, prefix: str = "zensim-bench-") -> tuple[Processes, str]:
    """A private `zensim router` on a free loopback port, up, and the Processes whose services are its clients.

    The services run robot `robot_id` with multicast scouting off (no other zenoh on the machine joins in)
    and unbuffered output (their logs are read while they run). Returns the processes (the router among
    them: `stop_all` in a `finally` stops it too) and the router's endpoint, for a `plain_client`.
    """
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs = Processes(dict(os.environ, ZENSIM_ROBOT_ID=robot_id, ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
                           PYTHONUNBUFFERED="1", ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint), prefix)
    try:
        router = procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
        wait_for(lambda: "router up" in router.log(), 15, "router")
    except BaseException:
        procs.stop_all()
        raise
    return procs, endpoint


def client_config(endpoint: str) -> zenoh.Config:
    """A plain zenoh client (no zensim code) of `endpoint`, multicast off, that waits for the router."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def plain_client(endpoint: str) -> zenoh.Session:
    return zenoh.open(client_config(endpoint))


def is_alive(session: zenoh.Session, key: str) -> bool:
    """Whether a liveliness token (alive/sim, ...) is declared on `key`."""
    return any(r.ok is not None for r in session.liveliness().get(key, timeout=0.5))


class Latest:
    """Subscribes to one key and keeps the newest decoded message (and, with `keep_history`, all of them)."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type, keep_history: bool = False) -> None:
        self._codec = Codec(message_type)
        self._lock = threading.Lock()
        self.value: Any = None
        self.count = 0
        self.keep_history = keep_history
        self.history: list[Any] = []
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        message = self._codec.decode(*payload_of(sample))
        with self._lock:
            self.value = message
            self.count += 1
            if self.keep_history:
                self.history.append(message)

    def wait(self, predicate: Callable[[Any], bool] = lambda m: True, timeout_s: float = 10.0,
             what: str = "a message") -> Any:
        """Wait until the newest message satisfies `predicate`; return it."""
        return wait_for(lambda: self.value if self.value is not None and predicate(self.value) else None,
                        timeout_s, what)


def test_scaffolding(name: str) -> ModuleType:
    """tests/<name>.py loaded by its path: `browser` (headless chromium), `unitree_sdk` (SDK-style client)
    or `netns` (network namespaces as hosts)."""
    return _load(f"zensim_test_scaffolding.{name}", REPO / "tests" / f"{name}.py")


def module_at(rev: str, path: str) -> ModuleType:
    """The file `path` of the checkout as it was at git revision `rev`, imported as a module of its own (a
    benchmark's "before", run beside the current code in the same rounds)."""
    text = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, check=True, capture_output=True, text=True).stdout
    name = Path(path).stem + "_before"
    copy = Path(tempfile.mkdtemp()) / f"{name}.py"
    copy.write_text(text)
    return _load(name, copy)


def _load(name: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module
