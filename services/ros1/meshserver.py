"""The robot's meshes over http, for RViz: robot_description points here (mapping.with_mesh_urls).

RViz loads meshes through resource_retriever, which reads `package://`, `file://` and `http://`;
the sim serves them over Zenoh only (info/mesh/{path}). This server answers `GET /{path}` for the
meshes the sim's RobotInfo lists, fetching each from the sim once and keeping it (the G1's 36
meshes are 19 MB). Anything else is 404. It listens on loopback unless told otherwise.

A web page the user opens could reach it through DNS rebinding (its own name re-resolved to
127.0.0.1), so a request must name an expected Host (421 otherwise). It holds at most
MAX_CONNECTIONS connections (each is a thread; one more is closed at once) and closes one that
sends nothing for `idle_timeout_s`: 200 silent connections once held 200 threads for ever.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import unquote, urlsplit

from zensim.common.logs import RateLimitedLog

from zensim.schemas.keys import mesh_key_path

logger = logging.getLogger("zensim.ros1.meshes")

Fetch = Callable[[str], bytes]
"""Mesh path -> its bytes from the sim; raises LookupError when the sim has none."""
MAX_CONNECTIONS = 32
"""Connections served at once (RViz opens a few); more are closed unanswered."""
IDLE_TIMEOUT_S = 10.0
"""A connection that sends nothing for this long is closed (RViz fetches each mesh at once)."""
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


def host_name(header: str | None) -> str:
    """The host of a Host header, without its port or IPv6 brackets (`[::1]:7011` -> `::1`)."""
    host = (header or "").strip().lower()
    if host.startswith("["):
        return host[1:].split("]", 1)[0]
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class MeshServer:
    """A threaded http server for one robot's meshes.

    Args:
        bind: address to listen on.
        port: port to listen on; 0 picks a free one.
        fetch: gets one mesh from the sim.
        hosts: the Host names a request may name (the one in robot_description's URLs); loopback
            names are always accepted.
        idle_timeout_s: how long a connection may send nothing.
        max_connections: connections served at once.
    """

    def __init__(self, bind: str, port: int, fetch: Fetch, hosts: Iterable[str] = (),
                 idle_timeout_s: float = IDLE_TIMEOUT_S, max_connections: int = MAX_CONNECTIONS) -> None:
        self._fetch = fetch
        self._lock = threading.Lock()
        self._allowed: frozenset[str] = frozenset()
        self._cache: dict[str, bytes] = {}
        self.hosts = LOOPBACK_NAMES | {host_name(h) for h in hosts if h}
        self._refusal_log = RateLimitedLog(logger, 10.0)
        server = self

        class Handler(BaseHTTPRequestHandler):
            timeout = idle_timeout_s  # socket timeout: an idle or slow connection ends

            def do_GET(self) -> None:  # noqa: N802 - the stdlib's name
                server._answer(self)

            def do_HEAD(self) -> None:  # noqa: N802
                server._answer(self, body=False)

            def log_message(self, format: str, *args: object) -> None:  # noqa: A002
                logger.debug("%s " + format, self.address_string(), *args)

        self._httpd = _BoundedServer((bind, port), Handler, max_connections, self._refusal_log)
        self._httpd.daemon_threads = True
        self.port = self._httpd.server_address[1]
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="mesh-http", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def serve_robot(self, mesh_paths: Iterable[str]) -> None:
        """Serve these meshes (the robot's RobotInfo.mesh_paths) and forget those of a previous robot."""
        with self._lock:
            self._allowed = frozenset(mesh_key_path(p) for p in mesh_paths)
            self._cache.clear()

    def _mesh(self, path: str) -> bytes | None:
        with self._lock:
            if path not in self._allowed:
                return None
            data = self._cache.get(path)
        if data is None:
            data = self._fetch(path)  # outside the lock: one slow mesh does not hold up the others
            with self._lock:
                if path in self._allowed:
                    self._cache[path] = data
        return data

    def _answer(self, handler: BaseHTTPRequestHandler, body: bool = True) -> None:
        host = handler.headers.get("Host")
        if host_name(host) not in self.hosts:
            self._refusal_log.warning("mesh request refused: Host %r is not one of %s", (host or "")[:100],
                                      ", ".join(sorted(self.hosts)))
            handler.send_error(421, "unexpected Host")
            return
        path = mesh_key_path(unquote(urlsplit(handler.path).path))
        try:
            data = self._mesh(path)
        except LookupError as exc:
            logger.warning("mesh %s: %s", path[:200], exc)
            data = None
        if data is None:
            handler.send_error(404, "no such mesh")
            return
        handler.send_response(200)
        handler.send_header("Content-Type", "application/octet-stream")
        handler.send_header("Content-Length", str(len(data)))
        handler.end_headers()
        if body:
            handler.wfile.write(data)

    def close(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()


class _BoundedServer(ThreadingHTTPServer):
    """A thread per connection, at most `max_connections` of them: one more is closed unanswered."""

    request_queue_size = 128  # the listen backlog: a burst of connections is accepted (and sorted) at once

    def __init__(self, address: tuple[str, int], handler: Any, max_connections: int, log: RateLimitedLog) -> None:
        super().__init__(address, handler)
        self._slots = threading.BoundedSemaphore(max_connections)
        self._max = max_connections
        self._log = log

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._slots.acquire(blocking=False):
            self._log.warning("mesh server: %d connections already open; closing a new one from %s",
                              self._max, client_address[0])
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except Exception:
            self._slots.release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()
