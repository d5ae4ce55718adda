"""Helpers for tests that run zensim the way users do: real processes, real Zenoh on loopback."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

REPO = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_for(condition: Callable[[], T], timeout_s: float, what: str, interval_s: float = 0.02) -> T:
    """Poll `condition` until it returns something truthy; fail the test after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)


class Service:
    """A zensim service started as users start it: `python -m zensim <command> ...`.

    Output goes to a log file that is printed when the test fails.
    """

    def __init__(self, command: str, args: list[str], env: dict[str, str], log_dir: Path) -> None:
        self.command = command
        self.log_path = log_dir / f"{command}-{time.monotonic_ns()}.log"
        self._log = self.log_path.open("wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "zensim", command, *args],
            env=env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def signal(self, signum: int = signal.SIGTERM) -> None:
        if self.alive():
            self.proc.send_signal(signum)

    def kill(self) -> None:
        if self.alive():
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(5)

    def stop(self, timeout_s: float = 5.0) -> int:
        """SIGTERM, wait, then SIGKILL; returns the exit code. Processes it started in sessions of their own
        (`zensim up`'s services, roscore) are killed too when they outlive it: a leader killed before it
        stopped them left them running for an hour, loading every later test."""
        offspring = descendants(self.proc.pid) if self.alive() else []
        self.signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.kill()
            return self.proc.returncode
        finally:
            self._log.close()
            for pid, started in offspring:
                if _start_time(pid) == started:  # still that process, not a new one with its number
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)


def _start_time(pid: int) -> int | None:
    """When a process started (clock ticks since boot), None when there is none with that number."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def descendants(pid: int) -> list[tuple[int, int | None]]:
    """Every process below `pid` now (children, their children, ...) and its start time, from /proc."""
    found: list[int] = []
    todo = [pid]
    while todo:
        parent = todo.pop()
        try:
            tasks = list(Path(f"/proc/{parent}/task").iterdir())
        except OSError:
            continue
        for task in tasks:
            with contextlib.suppress(OSError):
                children = [int(c) for c in (task / "children").read_text().split()]
                found += children
                todo += children
    return [(child, _start_time(child)) for child in found]


async def close_quietly(conn: Any) -> None:
    """Close a tornado websocket and wait for the close to finish, so its socket is not left to the garbage
    collector (a ResourceWarning at the end of the run, an error under filterwarnings=error)."""
    import asyncio

    import tornado.websocket

    conn.close()
    try:
        while await asyncio.wait_for(conn.read_message(), 2.0) is not None:
            pass
    except (asyncio.TimeoutError, tornado.websocket.WebSocketClosedError):
        pass


def wait_subscribed(session, key: str, timeout_s: float, what: str) -> None:
    """Wait until some subscriber on the network matches `key` (zenoh's matching status): a put made
    after this reaches it, where one made before the subscription was known may be lost."""
    publisher = session.declare_publisher(key)
    try:
        wait_for(lambda: publisher.matching_status.matching, timeout_s, what)
    finally:
        publisher.undeclare()


class Latest:
    """Subscribes to one key and keeps the newest decoded message (and how many came)."""

    def __init__(self, session, key: str, message_type: type) -> None:
        import threading

        from zensim.schemas import Codec

        self._codec: Codec[Any] = Codec(message_type)
        self._lock = threading.Lock()
        self.value: Any = None  # the newest message, of `message_type`
        self.count = 0
        self.history: list = []
        self.keep_history = False
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        message = self._codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        with self._lock:
            self.value = message
            self.count += 1
            if self.keep_history:
                self.history.append(message)

    def wait(self, predicate: Callable = lambda m: True, timeout_s: float = 10.0, what: str = "a message"):
        """Wait until the newest message satisfies `predicate`; return it."""
        return wait_for(lambda: self.value if self.value is not None and predicate(self.value) else None, timeout_s, what)


def ctl(session, key: str, payload: dict | None = None, timeout_s: float = 10.0) -> dict:
    """Send a control request as JSON with a plain zenoh get; return the decoded JSON reply."""
    import json

    replies = list(session.get(key, payload=json.dumps(payload or {}), timeout=timeout_s))
    assert replies, f"no reply from {key}"
    assert replies[0].ok is not None, f"error reply from {key}: {replies[0].err.payload.to_string()}"
    return json.loads(replies[0].ok.payload.to_bytes())


def plain_client(endpoint: str, wait_for_router: bool = False):
    """A plain zenoh client session (no zensim code) connected to `endpoint`, multicast off.

    With `wait_for_router` it waits up to a minute for a router that is still starting instead of failing
    at once (not for ever: a router that never comes must fail the test, not hang the run).
    """
    import json

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if wait_for_router:
        conf.insert_json5("connect/timeout_ms", "60000")
    return zenoh.open(conf)


# A robot other than the G1, for tests that restart the sim with another robot.
TWO_JOINT_ARM = """<robot name="two_joint_arm">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="upper"><visual><geometry><box size="0.04 0.04 0.3"/></geometry></visual>
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="lower"><visual><geometry><box size="0.04 0.04 0.3"/></geometry></visual>
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
</robot>
"""
