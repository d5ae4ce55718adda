"""The viewer page refuses DNS-rebinding Host names and, when reachable beyond loopback, asks for its
token: raw HTTP/websocket requests with forged headers, and headless chromium resolving a foreign name
to 127.0.0.1 (what a rebinding attack does)."""

from __future__ import annotations

import base64
import os
import re
import socket
import time
from collections.abc import Callable

import pytest

from browser import Browser, chromium_binary
from support import Service, free_port, wait_for
from zensim.viz.access import Guard


def request(port: int, path: str = "/", host: str | None = None, websocket: bool = False,
            headers: dict[str, str] | None = None) -> tuple[int, str]:
    """One raw HTTP/1.1 request with exactly the headers given; returns (status, response head)."""
    lines = [f"GET {path} HTTP/1.1", f"Host: {host or f'127.0.0.1:{port}'}"]
    if websocket:
        lines += ["Upgrade: websocket", "Connection: Upgrade", "Sec-WebSocket-Version: 13",
                  f"Sec-WebSocket-Key: {base64.b64encode(os.urandom(16)).decode()}"]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = sock.recv(4096)
            if not chunk:
                break
            head += chunk
    text = head.split(b"\r\n\r\n", 1)[0].decode(errors="replace")
    return int(text.split()[1]), text


def start_viz(start_service: Callable[..., Service], *args: str) -> tuple[Service, int]:
    port = free_port()
    viz = start_service("viz", "--port", str(port), *args)
    wait_for(lambda: "viz up" in viz.log() or not viz.alive(), 60, "the viz to serve")
    assert viz.alive(), viz.log()
    return viz, port


@pytest.mark.parametrize("bind, published_on, needs_token", [
    ("127.0.0.1", None, False), ("::1", None, False), ("0.0.0.0", None, True), ("192.168.1.20", None, True),
    ("0.0.0.0", "127.0.0.1", False),  # compose's default: the container binds all, Docker publishes on loopback
    ("0.0.0.0", "0.0.0.0", True), ("127.0.0.1", "0.0.0.0", True),
])
def test_a_token_is_needed_exactly_when_reachable_beyond_loopback(bind: str, published_on: str | None,
                                                                 needs_token: bool) -> None:
    guard = Guard(bind, published_on, (), None)
    assert (guard.token is not None) == needs_token
    assert guard.token_ok("anything") != needs_token and guard.token_ok(guard.token or "x")


def test_loopback_viz_refuses_foreign_host_names(start_service: Callable[..., Service]) -> None:
    viz, port = start_viz(start_service, "--allowed-hosts", "robot.lab")
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}", "robot.lab", "10.1.2.3:7000"):
        assert request(port, host=host)[0] == 200, host
    for host in ("attacker.example", f"attacker.example:{port}", "localhost.attacker.example", "127.0.0.1.nip.io"):
        assert request(port, host=host)[0] == 403, host
        assert request(port, "/meshcat/main.min.js", host=host)[0] == 403
        # A rebinding page is same-origin with itself: matching Origin and Host must not be enough.
        status, _ = request(port, "/ws", host=host, websocket=True, headers={"Origin": f"http://{host}"})
        assert status == 403, host
    assert request(port, "/ws", websocket=True, headers={"Origin": f"http://127.0.0.1:{port}"})[0] == 101
    # Another site's page on a good Host is still refused by the Origin check.
    assert request(port, "/ws", websocket=True, headers={"Origin": "http://attacker.example"})[0] == 403
    assert "refused GET" in viz.log()


def test_token_once_then_cookie(start_service: Callable[..., Service]) -> None:
    # Published beyond loopback (as compose does with ZENSIM_BIND=0.0.0.0): the token is required.
    viz, port = start_viz(start_service, "--published-on", "0.0.0.0", "--token", "s3cret-token")
    assert viz.log().count("s3cret-token") == 1  # once, as the URL; the settings line hides it
    assert request(port)[0] == 403
    assert request(port, "/?token=wrong")[0] == 403
    assert request(port, "/ws", websocket=True, headers={"Origin": f"http://127.0.0.1:{port}"})[0] == 403
    status, head = request(port, "/?token=s3cret-token")
    assert status == 302 and re.search(r"Location: /\r?$", head, re.M), head
    cookie = re.search(r"Set-Cookie: ([^;]+);", head).group(1)
    assert "HttpOnly" in head and "SameSite=Strict" in head
    assert request(port, headers={"Cookie": cookie})[0] == 200
    assert request(port, "/ws", websocket=True, headers={"Origin": f"http://127.0.0.1:{port}", "Cookie": cookie})[0] == 101
    assert request(port, headers={"Cookie": cookie.split("=")[0] + "=wrong"})[0] == 403
    # The token never overrides the Host rule.
    assert request(port, "/?token=s3cret-token", host="attacker.example")[0] == 403


def test_browser_uses_the_printed_url_and_a_rebinding_name_gets_nothing(start_service: Callable[..., Service]) -> None:
    if chromium_binary() is None:
        pytest.fail("chromium is needed: apt-get install -y --no-install-recommends chromium")
    start_service("sim", "--mode", "fixed")
    viz, port = start_viz(start_service, "--published-on", "0.0.0.0")
    url = wait_for(lambda: re.search(r"http://\S+/\?token=\S+", viz.log()), 10, "the token URL").group(0)
    rules = "--host-resolver-rules=MAP attacker.test 127.0.0.1"  # the printed URL is used as printed
    with Browser(width=800, height=600, extra_flags=(rules,)) as browser:
        browser.goto(url)
        browser.wait("window.zensim && zensim.status && zensim.status.alive.includes('sim')", 60,
                     "the page's websocket to bring status")
        assert browser.eval("location.search") == ""  # the token left the address bar
        browser.goto(f"http://127.0.0.1:{port}/")  # later visits: the cookie
        browser.wait("window.zensim && zensim.status && zensim.status.alive.includes('sim')", 60, "status again")
        # The attacker's name resolves to us, with the token given: still refused by Host.
        browser.goto(f"http://attacker.test:{port}/?token=x")
        browser.wait("document.readyState === 'complete'", 20)
        assert browser.eval("!window.zensim")
        assert "Forbidden" in browser.eval("document.body ? document.body.innerText : ''")


def test_the_printed_url_names_a_host_the_allow_list_accepts() -> None:
    """With --host 0.0.0.0 the URL names this machine (there is no address to print): that name is accepted."""
    for bind, published_on in (("0.0.0.0", None), ("::", None), ("0.0.0.0", "0.0.0.0"), ("192.168.1.20", None),
                               ("0.0.0.0", "10.0.0.5")):
        guard = Guard(bind, published_on, (), None)
        assert guard.token is not None
        assert guard.host_ok(f"{guard.url_host}:7000"), (bind, published_on, guard.url_host)
    assert Guard("0.0.0.0", None, (), None).url_host == socket.gethostname().lower().rstrip(".")
    assert Guard("0.0.0.0", "10.0.0.5", (), None).url_host == "10.0.0.5"


def test_the_token_reaches_no_log_and_refusals_are_logged_at_a_bounded_rate(
        start_service: Callable[..., Service]) -> None:
    viz, port = start_viz(start_service, "--published-on", "0.0.0.0", "--token", "s3cret-token")
    wait_for(lambda: "s3cret-token" in viz.log(), 10, "the token URL")
    before = len(viz.log().splitlines())
    for _ in range(20):
        assert request(port, "/?token=s3cret-token")[0] == 302
    for _ in range(150):  # a curl loop with a guessed token
        assert request(port, "/?token=guess-token")[0] == 403
    assert request(port, "/static/viz.css?token=s3cret-token")[0] == 200
    time.sleep(1.5)
    assert request(port, "/?token=guess-token")[0] == 403  # after the quiet period: logged, with a count
    log = viz.log()
    assert log.count("s3cret-token") == 1, log  # only the start line's URL
    assert "guess-token" not in log
    new_lines = log.splitlines()[before:]
    assert len(new_lines) < 40, f"{len(new_lines)} log lines for 171 requests:\n" + "\n".join(new_lines[:50])
    assert any("more like it held back" in line for line in new_lines), new_lines


def test_secured_viz_asks_its_token_on_loopback_too(tmp_path) -> None:
    """With --secure-dir, a loopback page is no way around the network's credentials: it needs its token."""
    import subprocess
    import sys

    folder = tmp_path / "secrets"
    subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder)], check=True,
                   capture_output=True, timeout=60)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    port = free_port()
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(folder), PYTHONUNBUFFERED="1")
    router = Service("router", ["--zenoh-listen", endpoint], env, tmp_path)
    viz = None
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 20, "the secured router")
        viz = Service("viz", ["--zenoh-connect", endpoint, "--port", str(port)], env, tmp_path)
        url = wait_for(lambda: re.search(r"http://127\.0\.0\.1:\d+/\?token=(\S+)", viz.log()) or not viz.alive(),
                       60, "the token URL")
        assert viz.alive(), viz.log()
        assert "the network is secured" in viz.log()
        assert request(port)[0] == 403
        assert request(port, "/ws", websocket=True, headers={"Origin": f"http://127.0.0.1:{port}"})[0] == 403
        assert isinstance(url, re.Match), viz.log()
        assert request(port, f"/?token={url.group(1)}")[0] == 302
    finally:
        if viz is not None:
            viz.stop()
        router.stop()
