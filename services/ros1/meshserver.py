"""The robot's meshes over http, for RViz: robot_description points here (mapping.with_mesh_urls).

RViz loads meshes through resource_retriever, which reads `package://`, `file://` and `http://`;
the sim serves them over Zenoh only (info/mesh/{path}). This server answers `GET /{path}` for the
meshes the sim's RobotInfo lists, fetching each from the sim once and keeping it (the G1's 36
meshes are 19 MB). Anything else is 404. It listens on loopback unless told otherwise.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import unquote, urlsplit

from zensim.schemas.keys import mesh_key_path

logger = logging.getLogger("zensim.ros1.meshes")

Fetch = Callable[[str], bytes]
"""Mesh path -> its bytes from the sim; raises LookupError when the sim has none."""


class MeshServer:
    """A threaded http server for one robot's meshes.

    Args:
        bind: address to listen on.
        port: port to listen on; 0 picks a free one.
        fetch: gets one mesh from the sim.
    """

    def __init__(self, bind: str, port: int, fetch: Fetch) -> None:
        self._fetch = fetch
        self._lock = threading.Lock()
        self._allowed: frozenset[str] = frozenset()
        self._cache: dict[str, bytes] = {}
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - the stdlib's name
                server._answer(self)

            def do_HEAD(self) -> None:  # noqa: N802
                server._answer(self, body=False)

            def log_message(self, format: str, *args: object) -> None:  # noqa: A002
                logger.debug("%s " + format, self.address_string(), *args)

        self._httpd = ThreadingHTTPServer((bind, port), Handler)
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
