"""The ROS gateway's mesh http server (services/ros1/meshserver.py) as RViz and an attacker meet it: a real
server on loopback, real sockets. It answers only the Host names robot_description uses (DNS rebinding),
holds a bounded number of connections and closes idle ones (200 silent connections once held 200 threads)."""

from __future__ import annotations

import http.client
import socket
import threading
import time

import pytest

from support import wait_for
from zensim.ros1.meshserver import MeshServer

MESH = "meshes/pelvis.STL"


@pytest.fixture
def server():
    server = MeshServer("127.0.0.1", 0, lambda path: b"solid pelvis", hosts=("rviz-host.lan",),
                        idle_timeout_s=1.0, max_connections=8)
    server.serve_robot([MESH])
    server.start()
    try:
        yield server
    finally:
        server.close()


def get(port: int, host: str | None) -> int:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        connection.putrequest("GET", f"/{MESH}", skip_host=True)
        if host is not None:
            connection.putheader("Host", host)
        connection.endheaders()
        return connection.getresponse().status
    finally:
        connection.close()


@pytest.mark.parametrize("host, status", [
    ("127.0.0.1:{port}", 200), ("localhost:{port}", 200), ("[::1]:{port}", 200), ("rviz-host.lan:{port}", 200),
    ("attacker.example:{port}", 421), ("127.0.0.1.attacker.example", 421), (None, 421), ("", 421),
])
def test_only_the_expected_host_names_are_answered(server, host, status) -> None:
    assert get(server.port, None if host is None else host.format(port=server.port)) == status


def test_silent_connections_are_bounded_and_closed_when_idle(server) -> None:
    before = threading.active_count()
    silent = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(200)]
    try:
        time.sleep(0.3)
        assert threading.active_count() - before <= 8, "a thread per silent connection"
        # Idle ones are closed after idle_timeout_s; then a real request is served again.
        wait_for(lambda: threading.active_count() - before <= 0, 10, "the idle connections to be closed", 0.1)
        assert get(server.port, f"127.0.0.1:{server.port}") == 200
    finally:
        for sock in silent:
            sock.close()
