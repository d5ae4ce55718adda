"""The viewer's memory against pages that never read (issue 27, item 5), in one run:

    .venv/bin/python benchmarks/viz_deaf_pages.py [--pages 1000] [--settle-s 10]

Starts a router, a sim (fixed-base G1) and `zensim viz` as real processes on loopback, then opens
--pages websockets to the viewer that complete the handshake and never read a byte (each is sent the
robot's scene, ~5.7 MB with the G1's shells), waits --settle-s, closes them all and waits again.
Prints the viz's RSS before, with the pages open, and 5 s and --settle-s after they left, and whether
a page that reads still gets its scene and frames afterwards.
"""

from __future__ import annotations

import argparse
import base64
import os
import random
import resource
import signal
import socket
import struct
import sys
import time

from harness import behind_private_router, free_port, rss_mb, wait_for


def deaf_page(port: int) -> socket.socket:
    """A websocket that completes the handshake and then never reads."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # the upgrade answer only; nothing after it is ever read
    if b" 101 " not in response.split(b"\r\n")[0]:
        raise RuntimeError(f"no websocket: {response[:200]!r}")
    return sock


def reading_page(port: int, timeout_s: float = 60.0) -> tuple[int, int]:
    """A page that reads: (scene bytes received, frames received) within `timeout_s` of opening."""
    sock = deaf_page(port)
    sock.settimeout(1.0)
    buffer, scene, frames = b"", 0, 0
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline and frames < 3:
            try:
                chunk = sock.recv(1 << 20)
            except TimeoutError:
                continue
            if not chunk:
                break
            buffer += chunk
            while len(buffer) >= 2:  # unmasked server frames: FIN/opcode, length, payload
                length, offset = buffer[1] & 0x7F, 2
                if length == 126:
                    length, offset = struct.unpack_from(">H", buffer, 2)[0], 4
                elif length == 127:
                    length, offset = struct.unpack_from(">Q", buffer, 2)[0], 10
                if len(buffer) < offset + length:
                    break
                payload, buffer = buffer[offset:offset + length], buffer[offset + length:]
                if len(payload) >= 4 and struct.unpack_from("<I", payload)[0] == 2:
                    frames += 1
                    ack = b'{"type": "ack"}'
                    mask = os.urandom(4)
                    sock.sendall(bytes([0x81, 0x80 | len(ack)]) + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(ack)))
                else:
                    scene += len(payload)
    finally:
        sock.close()
    return scene, frames


def main() -> None:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pages", type=int, default=1000, help="pages that never read")
    parser.add_argument("--settle-s", type=float, default=10.0, help="wait with the pages open, and after")
    args = parser.parse_args()
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, max(soft, args.pages + 256)), hard))  # the viz inherits it

    port = free_port()
    procs, _ = behind_private_router("bench" + str(random.randint(0, 10**6)), prefix="viz-deaf-")
    procs.zensim("sim", "--mode", "fixed")
    viz = procs.zensim("viz", "--port", str(port))
    try:
        wait_for(lambda: "viz up" in viz.log() or not viz.alive(), 60, "the viz")
        scene, frames = reading_page(port)
        print(f"a reading page: {scene / 1e6:.2f} MB of scene, {frames} frames")
        time.sleep(2.0)
        before = rss_mb(viz.pid)
        pages = []
        started = time.monotonic()
        for _ in range(args.pages):
            pages.append(deaf_page(port))
        opened_s = time.monotonic() - started
        time.sleep(args.settle_s)
        with_pages = rss_mb(viz.pid)
        for page in pages:
            page.close()
        time.sleep(5.0)
        after_5 = rss_mb(viz.pid)
        time.sleep(max(0.0, args.settle_s - 5.0))
        after = rss_mb(viz.pid)
        scene, frames = reading_page(port)
        dropped = viz.log().count("dropped a page")
        print(f"{args.pages} pages that never read (opened in {opened_s:.1f} s): viz RSS {before:.0f} MB before, "
              f"{with_pages:.0f} MB with them open ({(with_pages - before) / max(1, args.pages) * 1000:.0f} kB a page), "
              f"{after_5:.0f} MB 5 s after they left, {after:.0f} MB {args.settle_s:g} s after; "
              f"a reading page then: {scene / 1e6:.2f} MB of scene, {frames} frames; viz alive: {viz.alive()}; "
              f"'dropped a page' lines: {dropped}")
    finally:
        procs.stop_all()


if __name__ == "__main__":
    main()
