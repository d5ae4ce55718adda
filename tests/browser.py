"""A small headless-chromium driver over the DevTools protocol, for tests and benchmarks.

No selenium or playwright: chromium is started with `--remote-debugging-port=0`,
the port is read from `DevToolsActivePort` in its fresh profile folder, and
one page target is driven over a websocket (tornado's client, on a private
asyncio loop in a background thread, behind a blocking API).
"""

from __future__ import annotations

import asyncio
import io
import itertools
import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
from tornado.websocket import websocket_connect

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--enable-unsafe-swiftshader", "--remote-debugging-port=0",
    # Headless pages must keep drawing (and acking frames) while nobody looks at them.
    "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
    "--disable-backgrounding-occluded-windows",
)


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(RuntimeError):
    """Chromium failed to start or a DevTools call failed."""


class Browser:
    """One headless chromium with one page.

    Args:
        width: window width, px.
        height: window height, px.
        extra_flags: more chromium flags (e.g. --host-resolver-rules to play a DNS-rebinding name).
    """

    def __init__(self, width: int = 1280, height: int = 800, extra_flags: tuple[str, ...] = ()) -> None:
        binary = chromium_binary()
        if binary is None:
            raise BrowserError("chromium is not installed (apt-get install chromium)")
        self.profile = Path(tempfile.mkdtemp(prefix="zensim-chromium-"))
        self.log_path = self.profile.parent / (self.profile.name + ".log")
        self._log = self.log_path.open("wb")
        self.proc = subprocess.Popen(
            [binary, *CHROMIUM_FLAGS, f"--user-data-dir={self.profile}", f"--window-size={width},{height}",
             *extra_flags, "about:blank"],
            stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True,
        )
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="cdp")
        self._thread.start()
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future] = {}
        self.console: list[str] = []
        self._ws: Any = None
        try:
            port = self._wait_port(30.0)
            self._ws_url = self._page_ws_url(port)
            self._call(self._connect())
            self.send("Page.enable")
            self.send("Runtime.enable")
        except BaseException:
            self.close()
            raise

    # --- start-up --------------------------------------------------------------------
    def _wait_port(self, timeout_s: float) -> int:
        marker = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise BrowserError(f"chromium exited with {self.proc.returncode}: {self.log()}")
            try:
                return int(marker.read_text().split()[0])
            except (OSError, ValueError, IndexError):
                time.sleep(0.05)
        raise BrowserError(f"chromium wrote no DevToolsActivePort in {timeout_s} s: {self.log()}")

    @staticmethod
    def _page_ws_url(port: int) -> str:
        deadline = time.monotonic() + 10
        while True:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as resp:
                targets = json.loads(resp.read())
            pages = [t for t in targets if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
            if time.monotonic() > deadline:
                raise BrowserError("chromium has no page target")
            time.sleep(0.1)

    async def _connect(self) -> None:
        self._ws = await websocket_connect(self._ws_url, max_message_size=256 * 1024 * 1024)
        self._reading = asyncio.ensure_future(self._reader())

    async def _reader(self) -> None:
        while True:
            message = await self._ws.read_message()
            if message is None:
                for future in self._pending.values():
                    if not future.done():
                        future.set_exception(BrowserError("DevTools connection closed"))
                return
            data = json.loads(message)
            if "id" in data:
                future = self._pending.pop(data["id"], None)
                if future is not None and not future.done():
                    if "error" in data:
                        future.set_exception(BrowserError(str(data["error"])))
                    else:
                        future.set_result(data.get("result", {}))
            elif data.get("method") == "Runtime.consoleAPICalled":
                args = data["params"].get("args", [])
                self.console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in args))
                del self.console[:-200]
            elif data.get("method") == "Runtime.exceptionThrown":
                self.console.append("exception: " + json.dumps(data["params"].get("exceptionDetails", {}))[:500])

    async def _send(self, method: str, params: dict) -> Any:
        msg_id = next(self._ids)
        future = self._loop.create_future()
        self._pending[msg_id] = future
        await self._ws.write_message(json.dumps({"id": msg_id, "method": method, "params": params}))
        return await future

    def _call(self, coro: Any, timeout_s: float = 60.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout_s)

    # --- API ---------------------------------------------------------------------------
    def send(self, method: str, timeout_s: float = 60.0, **params: Any) -> Any:
        """One DevTools command; its result."""
        return self._call(self._send(method, params), timeout_s)

    def goto(self, url: str) -> None:
        self.send("Page.navigate", url=url)

    def eval(self, expression: str, timeout_s: float = 30.0) -> Any:
        """Evaluate JS in the page; its value (JSON-able), or raise on a JS exception."""
        result = self.send("Runtime.evaluate", timeout_s, expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise BrowserError(f"JS error in {expression!r}: {result['exceptionDetails']}")
        return result.get("result", {}).get("value")

    def wait(self, expression: str, timeout_s: float, what: str | None = None) -> Any:
        """Poll a JS expression until truthy; raise AssertionError after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                value = self.eval(expression)
            except BrowserError:
                value = None  # page navigating or not loaded yet
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what or expression}; "
                                     f"console: {self.console[-10:]}")
            time.sleep(0.1)

    def screenshot(self) -> bytes:
        """PNG of the page as it is drawn now."""
        import base64

        return base64.b64decode(self.send("Page.captureScreenshot", format="png")["data"])

    def set_slider(self, element_id: str, value: float) -> None:
        """Move an <input type=range> the way a user does: set the value, fire `input` and `change`."""
        self.eval(
            f"(() => {{ const e = document.getElementById({json.dumps(element_id)});"
            f" e.value = {float(value)!r};"
            " e.dispatchEvent(new Event('input', {bubbles: true}));"
            " e.dispatchEvent(new Event('change', {bubbles: true})); return e.value; })()"
        )

    def click(self, element_id: str) -> None:
        """Click an element the way a user does: a mouse press and release at its centre.

        The events go through chromium's input pipeline (hit testing included), so a button
        hidden behind something else, or disabled, does not get the click.
        """
        x, y = self.eval(
            f"(() => {{ const r = document.getElementById({json.dumps(element_id)}).getBoundingClientRect();"
            " return [r.left + r.width / 2, r.top + r.height / 2]; })()"
        )
        for kind in ("mousePressed", "mouseReleased"):
            self.send("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)

    def key(self, key: str, down: bool) -> None:
        """Press (`down`) or release a key the way a user does: through chromium's input pipeline, to the
        focused page (`key` as KeyboardEvent.key names it: "w", " ")."""
        code = "Space" if key == " " else f"Key{key.upper()}" if len(key) == 1 and key.isalpha() else key
        vk = 32 if key == " " else ord(key.upper()) if len(key) == 1 else 0
        params: dict[str, Any] = {"type": "keyDown" if down else "keyUp", "key": key, "code": code,
                                  "windowsVirtualKeyCode": vk}
        if down and len(key) == 1:
            params["text"] = key
        self.send("Input.dispatchKeyEvent", **params)

    def select(self, element_id: str, value: str) -> None:
        """Choose an option of a <select> as a user does (the value changes, `change` fires)."""
        self.eval(
            f"(() => {{ const e = document.getElementById({json.dumps(element_id)});"
            f" e.focus(); e.value = {json.dumps(value)};"
            " e.dispatchEvent(new Event('change', {bubbles: true})); e.blur(); return e.value; })()"
        )

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def close(self) -> None:
        if self._ws is not None:
            try:
                self._call(self._close_ws(), 5)
            except Exception:  # noqa: BLE001 - closing a browser that may be gone already
                pass
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        if not self._loop.is_running():
            self._loop.close()
        self._log.close()
        shutil.rmtree(self.profile, ignore_errors=True)
        self.log_path.unlink(missing_ok=True)

    async def _close_ws(self) -> None:
        # Wait for the close to finish (the reader sees it), so the socket is not left to the garbage collector.
        self._ws.close()
        await asyncio.wait_for(self._reading, 2.0)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def decode_png(data: bytes) -> np.ndarray:
    """RGB pixels (H, W, 3) of a PNG (Pillow comes with meshcat, a project dependency)."""
    from PIL import Image

    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("RGB"))
