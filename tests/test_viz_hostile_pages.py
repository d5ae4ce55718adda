"""The viewer against hostile pages and hostile sessions (issue 18, findings 2 and 3).

A page that floods the websocket and never reads what it is sent is dropped, and a second page goes
on drawing at its rate; a page's control requests cannot pile up; invented liveliness tokens do not
grow what every page is sent; a NUL in a static path is a 404, not a traceback.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import socket
import struct
import subprocess
import threading
import time
import urllib.error
import urllib.request

import tornado.websocket

from support import Service, close_quietly, free_port, wait_for
from zensim.schemas import Keys, SimStatus
from support import Latest

FRAME_KIND = 2


def start_stack(start_service) -> tuple[Service, int]:
    start_service("sim", "--mode", "fixed")
    port = free_port()
    viz = start_service("viz", "--port", str(port))
    wait_for(lambda: "viz up" in viz.log() or not viz.alive(), 60, "the viz to serve")
    assert viz.alive(), viz.log()
    return viz, port


class GoodPage:
    """A page that reads everything and acks every frame, as the real page does; counts frames by arrival time."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.frames: list[float] = []
        self.statuses: list[str] = []
        self.closed = threading.Event()
        self._stop = False
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        conn = await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{self.port}/ws", max_message_size=64 << 20)
        while not self._stop:
            try:
                message = await asyncio.wait_for(conn.read_message(), 1.0)
            except asyncio.TimeoutError:
                continue
            if message is None:
                break
            if isinstance(message, bytes) and struct.unpack_from("<I", message)[0] == FRAME_KIND:
                self.frames.append(time.monotonic())
                await conn.write_message(json.dumps({"type": "ack"}))
            elif isinstance(message, str) and '"status"' in message[:40]:
                self.statuses.append(message)
        await close_quietly(conn)
        self.closed.set()

    def rate(self, since: float, until: float) -> float:
        return sum(1 for t in self.frames if since <= t < until) / (until - since)

    def stop(self) -> None:
        self._stop = True
        self.closed.wait(5)


def deaf_page(port: int, messages: int, seconds: float) -> tuple[int, str]:
    """A websocket that sends `messages` invalid messages as fast as it can and never reads a byte.

    Returns how many it got out before the viz closed it, and why it stopped.
    """
    sock = silent_page(port)  # the handshake: from here it sends, never reads
    payload = b'{"type": "nonsense"}'
    mask = os.urandom(4)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    frame = bytes([0x81, 0x80 | len(payload)]) + mask + masked
    batch = frame * 500
    sent, deadline = 0, time.monotonic() + seconds
    sock.settimeout(2.0)
    try:
        while sent < messages and time.monotonic() < deadline:
            sock.sendall(batch)
            sent += 500
        why = "sent everything"
    except (BrokenPipeError, ConnectionResetError):
        why = "closed by the viz"
    except socket.timeout:
        why = "the viz stopped reading"  # its socket buffers are full: it no longer reads this page
    finally:
        sock.close()
    return sent, why


def test_a_page_that_floods_and_never_reads_is_dropped_and_others_keep_their_frames(start_service) -> None:
    viz, port = start_stack(start_service)
    good = GoodPage(port)
    try:
        wait_for(lambda: len(good.frames) > 20, 60, "the good page's first frames")
        time.sleep(2.0)
        baseline_end = time.monotonic()
        baseline = good.rate(baseline_end - 2.0, baseline_end)
        log_lines_before = viz.log().count("\n")
        attack_start = time.monotonic()
        sent, why = deaf_page(port, 500_000, 20.0)
        attack_end = time.monotonic()
        time.sleep(1.0)
        during = good.rate(attack_start, max(attack_end, attack_start + 1.0))
        after = good.rate(attack_end, time.monotonic())
        log_lines = viz.log().count("\n") - log_lines_before
    finally:
        good.stop()
    assert viz.alive(), viz.log()[-2000:]
    assert "dropped a page that does not read or floods" in viz.log(), (sent, why, viz.log()[-2000:])
    # 60 frames/s on a quiet machine, during and after the attack alike (docs/benchmarks.md); a loaded
    # machine lowers the baseline itself, so the attack is judged against it.
    wanted = min(50.0, 0.8 * baseline)
    assert during >= wanted and after >= wanted, (baseline, during, after, sent, why, attack_end - attack_start)
    assert log_lines < 60, viz.log()[-3000:]
    assert "Traceback" not in viz.log() and "never retrieved" not in viz.log(), viz.log()[-3000:]


def test_control_requests_of_one_page_do_not_pile_up(start_service, zsession, robot_id) -> None:
    viz, port = start_stack(start_service)
    status = Latest(zsession, Keys(robot_id).sim_status, SimStatus)
    status.wait(what="the sim's status")

    async def spam_resets() -> int:
        conn = await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{port}/ws", max_message_size=64 << 20)
        sent = 0
        try:
            for _ in range(3000):
                await conn.write_message(json.dumps({"type": "ctl", "verb": "reset"}))
                sent += 1
            await asyncio.sleep(0.5)
        except tornado.websocket.WebSocketClosedError:
            pass  # the viz dropped this page as a flood: as good an answer as any
        await close_quietly(conn)
        return sent

    asyncio.run(spam_resets())
    stopped = time.monotonic()
    resets_at_stop = status.wait(lambda m: True).resets
    time.sleep(3.0)
    resets_later = status.wait(lambda m: True).resets
    # At most the one request in flight when the page left may still land: no backlog of thousands.
    assert resets_later - resets_at_stop <= 1, (resets_at_stop, resets_later, time.monotonic() - stopped)
    assert resets_later < 100, resets_later
    assert viz.alive() and "Traceback" not in viz.log()


def test_invented_liveliness_tokens_do_not_grow_every_page_s_status(start_service, zsession, robot_id) -> None:
    viz, port = start_stack(start_service)
    good = GoodPage(port)
    keys = Keys(robot_id)
    tokens = []
    try:
        wait_for(lambda: good.statuses, 60, "a status message")
        for i in range(3000):
            tokens.append(zsession.liveliness().declare_token(keys.alive(("x" * 200 if i % 2 else "s") + str(i))))
        time.sleep(3.0)
        newest = good.statuses[-1]
    finally:
        for token in tokens:
            token.undeclare()
        good.stop()
    status = json.loads(newest)
    assert len(status["alive"]) <= 32 + 6, len(status["alive"])  # 32 names; zensim's six services always show
    assert "sim" in status["alive"] and "viz" in status["alive"]
    assert len(newest) < 8000, len(newest)
    assert viz.log().count("\n") < 200, "one log line per token"


def test_a_nul_in_a_static_path_is_a_404_without_a_traceback(start_service) -> None:
    port = free_port()
    viz = start_service("viz", "--port", str(port))
    wait_for(lambda: "viz up" in viz.log() or not viz.alive(), 60, "the viz to serve")
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/static/x%00.js", timeout=5)
        raise AssertionError("a NUL path was served")
    except urllib.error.HTTPError as exc:
        exc.close()  # an HTTPError holds the response's socket until closed
        assert exc.code == 404, exc.code
    assert "Traceback" not in viz.log(), viz.log()[-2000:]


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        lines = status.read().splitlines()
    for line in lines:
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS for {pid}")


def steady_rss_mb(pid: int, window_s: float = 1.0) -> bool:
    """Whether a process's RSS changed by less than 1 MB over `window_s`."""
    first = rss_mb(pid)
    time.sleep(window_s)
    return abs(rss_mb(pid) - first) < 1.0


def connections_to(port: int) -> int:
    """Established TCP connections whose local port is `port` (the viz's side of its pages)."""
    out = subprocess.run(["ss", "-Htn", "state", "established", f"( sport = :{port} )"], capture_output=True,
                         text=True, check=True).stdout
    return len(out.splitlines())


def silent_page(port: int) -> socket.socket:
    """A websocket that completes the handshake and then never reads (nor sends) a byte."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # the upgrade answer only; nothing after it is ever read
    assert b" 101 " in response.split(b"\r\n")[0], response
    return sock


def test_pages_that_never_read_cost_the_viz_no_copy_of_the_scene(start_service) -> None:
    """Issue 27 item 5: each page that never reads held its own copy of the ~5.7 MB scene in the viz (1000
    such pages: 197 -> 3 517 MB, kept after they closed). Now every page is handed the same framed bytes,
    a few messages at a time: 50 such pages cost the viz a few MB, and a reading page still draws."""
    viz, port = start_stack(start_service)
    good = GoodPage(port)  # the scene is built and a page gets it
    try:
        wait_for(lambda: len(good.frames) > 5, 60, "the good page's first frames")
    finally:
        good.stop()
    time.sleep(1.0)
    before = rss_mb(viz.proc.pid)
    pages = [silent_page(port) for _ in range(50)]
    try:
        # Each is handed scene messages until its socket's buffers are full: wait until the viz's memory
        # stops changing (it grew ~1.8 MB a page before).
        wait_for(lambda: steady_rss_mb(viz.proc.pid), 60, "the viz's memory steady with the pages open")
        with_pages = rss_mb(viz.proc.pid)
        log_lines = viz.log().count("\n")
    finally:
        for page in pages:
            page.close()
    wait_for(lambda: connections_to(port) == 0, 30, "the pages gone")
    after = rss_mb(viz.proc.pid)
    good = GoodPage(port)
    try:
        wait_for(lambda: len(good.frames) > 5, 60, "a new page's frames after them")
    finally:
        good.stop()
    print(f"\nviz RSS {before:.0f} MB, {with_pages:.0f} MB with 50 pages that never read, {after:.0f} MB after")
    assert with_pages - before < 25, (before, with_pages)  # under 0.5 MB a page (a scene copy each: ~1.8 MB)
    assert after - before < 25, (before, after)
    assert viz.log().count("\n") - log_lines < 15, viz.log()[-2000:]  # connections: a line a second at most
    assert viz.alive(), viz.log()[-2000:]
