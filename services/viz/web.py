"""The viewer's web server: one page, meshcat's own viewer JS, and one websocket per browser.

No meshcat-server is spawned (NOTES.md: its unread pipes fill, it binds every
interface, it replays every command to new browsers and has no backpressure).
Instead this tornado app serves meshcat's viewer bundle from the installed
wheel and pushes meshcat commands over its own websocket.

Flow control is latest-wins per browser: the hub keeps only the newest pose
frame; a browser gets a frame only after it acknowledged the previous one
(the page acks after the frame was drawn), so a slow browser sees fewer
frames, never older ones, and nothing queues on the server. Status messages
are skipped for a browser whose previous one is still being written.

Binary messages carry an 8-byte header of two little-endian uint32:
`kind` (1: a msgpack meshcat command, 2: a pose frame of float32 4x4s) and the
scene generation, so a frame never lands on a scene it was not made for.
Text messages are JSON in both directions; what browsers send is validated by
`panel.parse_client_message` before anything reaches zenoh.

Every write to a page is bounded: a page may have at most `MAX_PENDING_WRITES`
writes not yet taken by its socket; past that it is a page that does not read
(slow or hostile) and it is dropped (closed, counted), so it never holds memory
or the loop for the others. A page's own messages are rate-limited (a token
bucket), and every write's failure is collected, never left unretrieved.

The scene (the robot's meshes: ~5.7 MB for the G1's shells, in ~150 messages) is
framed once per robot, and every page's socket is handed those same bytes (tornado's
`write_message` would copy each message into a new frame per page), at most
`SCENE_WINDOW` messages ahead of what the page's socket has taken. So a page that
never reads costs a few references, not a copy of the scene (1000 such pages took
the viz from 197 to 3 517 MB, kept after they left); a page that takes no scene
message for `SCENE_STALL_S` is dropped, which frees its socket's kernel buffers too.
"""

from __future__ import annotations

import gzip
import importlib.util
import json
import logging
import struct
import time
from collections import deque
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import meshcat
import tornado.iostream
import tornado.web
import tornado.websocket

from zensim.common.logs import RateLimitedLog
from zensim.common.token_bucket import TokenBucket

from .access import Guard

logger = logging.getLogger(__name__)
refusals = RateLimitedLog(logger)
access_log = logging.getLogger("zensim.viz.access")
refused_requests = RateLimitedLog(access_log)
drops = RateLimitedLog(logger)
connections = RateLimitedLog(logger)
"""A page coming or going is a line, but at most one a second: a script opening thousands is not thousands."""

KIND_COMMAND = 1
KIND_FRAME = 2
MAX_CLIENT_MESSAGE_BYTES = 64 * 1024
MAX_PENDING_WRITES = 256
"""Writes a page may leave unread (the scene is ~40 commands; frames and status wait for the previous one)."""
PAGE_MESSAGES_PER_S = 200.0
"""A page's sustained message rate (sliders send at the display rate); past it messages are refused."""
PAGE_MESSAGE_BURST = 400.0
MAX_OVER_RATE = 2000
"""Messages past the rate a page may send before it is dropped as hostile (ten seconds' worth)."""
SCENE_WINDOW = 4
"""Scene messages handed to a page's socket and not yet taken by it (the rest wait in the hub, shared)."""
SCENE_STALL_S = 30.0
"""A page that takes no scene message for this long is dropped (a browser on a slow link still takes one
of the largest, 0.5 MB, in well under that)."""
DROPPED_CLOSE_CODE = 1008
"""Websocket close code "policy violation": the page did not read what it was sent."""
STATIC_DIR = Path(str(resources.files("zensim.viz") / "static" / "index.html")).resolve().parent
"""The page's folder itself: an editable install's tree links each file (to the checkout), and tornado
serves a link only when its real path is inside the folder it serves."""
MESHCAT_JS = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"
# Located without importing plotly (its Python side is not needed, only the bundled JS).
PLOTLY_JS = Path(importlib.util.find_spec("plotly").origin).parent / "package_data" / "plotly.min.js"  # type: ignore[union-attr,arg-type]


def header(kind: int, generation: int) -> bytes:
    return struct.pack("<II", kind, generation)


def binary_frame(payload: bytes) -> bytes:
    """`payload` as one websocket binary message, server to client (FIN, opcode 2, unmasked; RFC 6455 5.2)."""
    n = len(payload)
    if n < 126:
        length = struct.pack("!B", n)
    elif n <= 0xFFFF:
        length = struct.pack("!BH", 126, n)
    else:
        length = struct.pack("!BQ", 127, n)
    return b"\x82" + length + payload


def _collect(future: Any) -> None:
    """A write to a page that left fails: collected here, not reported as "never retrieved"."""
    if not future.cancelled():
        future.exception()


class Client:
    """One connected browser and what it has been sent."""

    def __init__(self, handler: VizSocket) -> None:
        self.handler = handler
        self.ready = True
        """False from sending a frame until the browser acks it."""
        self.sent_seq = -1
        self.frames_sent = 0
        self.status_busy = False
        self.unwritten: deque[Any] = deque()
        """Futures of writes handed to tornado that the socket has not taken yet, oldest first."""
        self.dropped = False
        self.on_drop: Callable[[Client], None] | None = None
        self.messages = TokenBucket(PAGE_MESSAGES_PER_S, PAGE_MESSAGE_BURST)
        self.over_rate = 0
        self.over_rate_told = TokenBucket(1.0, 1.0)
        """The page hears why at most once a second: a reply per refused message would amplify a flood."""
        self.ctl_in_flight = False
        """One control request per page at a time: a page cannot queue resets faster than the sim answers."""
        self.may_drive = True
        """False for a page opened with the viewer's token: it watches, every driving message is refused."""
        self.robot: str | None = None
        """The robot this page's panel acts on (a world's viewer); None: the first robot shown."""
        self.scene_next: int | None = None
        """Index of the next scene message to hand this page; None once it has the whole scene."""
        self.scene_generation = -1
        self.scene_progress_at = time.monotonic()
        """When this page's socket last took a scene message (or the scene started)."""

    def send(self, data: bytes | str, binary: bool) -> Any:
        """Write to the page; None when it is gone or was dropped for not reading."""
        if self.dropped:
            return None
        while self.unwritten and self.unwritten[0].done():  # writes complete in order
            self.unwritten.popleft()
        if len(self.unwritten) >= MAX_PENDING_WRITES:
            self.drop(f"{len(self.unwritten)} writes unread")
            return None
        try:
            future = self.handler.write_message(data, binary=binary)
        except tornado.websocket.WebSocketClosedError:
            return None
        self.unwritten.append(future)
        future.add_done_callback(_collect)
        return future

    def send_framed(self, frame: bytes) -> Any:
        """Hand the socket a message framed beforehand (binary_frame), without copying it: every page is
        handed the same bytes. None when the page is gone or was dropped."""
        if self.dropped:
            return None
        connection = self.handler.ws_connection
        stream = None if connection is None or connection.is_closing() else connection.stream
        if stream is None:
            return None
        try:
            future = stream.write(frame)
        except tornado.iostream.StreamClosedError:
            return None
        self.unwritten.append(future)
        future.add_done_callback(_collect)
        return future

    def scene_in_flight(self) -> int:
        """Writes handed to the socket and not yet taken by it."""
        while self.unwritten and self.unwritten[0].done():  # writes complete in order
            self.unwritten.popleft()
        return len(self.unwritten)

    def drop(self, why: str) -> None:
        """Close a page that does not read what it is sent, or floods (counted by the hub)."""
        if self.dropped:
            return
        self.dropped = True
        if self.on_drop is not None:
            self.on_drop(self)
        drops.warning("dropped a page that does not read or floods: %s", why)
        connection = self.handler.ws_connection  # handler.close() forgets it
        self.handler.close(DROPPED_CLOSE_CODE, "too many unread messages")
        # tornado would go on reading (and parsing) the page's flood for 5 s waiting for its close reply:
        # a page dropped for misbehaving gets its socket shut at once.
        stream = getattr(connection, "stream", None)
        if stream is not None:
            stream.close()


class Hub:
    """The current scene, the newest frame and status, and the browsers that want them.

    Runs on the tornado loop only; other threads hand data over with
    `IOLoop.add_callback`.

    Args:
        on_message: called with (client, decoded JSON) for each text message except acks.
    """

    def __init__(self, on_message: Callable[[Client, Any], None]) -> None:
        self.on_message = on_message
        self.clients: set[Client] = set()
        self.refused = 0
        """Browser messages refused (not JSON, malformed, unknown joints, ...) since start."""
        self.generation = 0
        self.scene: list[bytes] = []
        """The scene's messages, each framed once (binary_frame) and handed to every page as is."""
        self._last_sweep = time.monotonic()
        self.robot_meta: dict | None = None
        self.frame: bytes | None = None
        self.frame_seq = 0
        self.frames_sent = 0
        self.dropped_pages = 0
        """Pages closed because they left too many writes unread (slow or hostile)."""

    # --- scene ---------------------------------------------------------------
    def set_scene(self, commands: list[bytes], robot_meta: dict) -> None:
        """Install a new robot drawing and send it to every browser."""
        self.generation += 1
        self.scene = [binary_frame(header(KIND_COMMAND, self.generation) + c) for c in commands]
        self.robot_meta = dict(robot_meta, type="robot", generation=self.generation)
        self.frame = None
        for client in list(self.clients):
            self._send_scene(client)

    def _send_scene(self, client: Client) -> None:
        """Start handing `client` the current scene (it gets frames once it has all of it)."""
        client.ready = False
        client.sent_seq = -1
        client.scene_next = 0
        client.scene_generation = self.generation
        client.scene_progress_at = time.monotonic()
        self._pump_scene(client)

    def _pump_scene(self, client: Client) -> None:
        """Hand `client` scene messages while fewer than SCENE_WINDOW wait in its socket; once all are
        handed over, the robot message that completes the scene, and frames from then on."""
        if client.dropped or client.scene_next is None or client not in self.clients:
            return
        if client.scene_generation != self.generation:  # a newer scene started meanwhile: _send_scene has it
            return
        while client.scene_next < len(self.scene) and client.scene_in_flight() < SCENE_WINDOW:
            future = client.send_framed(self.scene[client.scene_next])
            if future is None:
                return
            client.scene_next += 1
            future.add_done_callback(lambda _f, c=client: self._scene_taken(c))
        if client.scene_next >= len(self.scene):
            client.scene_next = None
            if self.robot_meta is not None:
                client.send(json.dumps(self.robot_meta), binary=False)
            client.ready = True

    def _scene_taken(self, client: Client) -> None:
        client.scene_progress_at = time.monotonic()
        self._pump_scene(client)

    def sweep(self) -> None:
        """Drop pages that took no scene message for SCENE_STALL_S (checked at most once a second)."""
        now = time.monotonic()
        if now - self._last_sweep < 1.0:
            return
        self._last_sweep = now
        for client in list(self.clients):
            if client.scene_next is not None and now - client.scene_progress_at > SCENE_STALL_S:
                client.drop(f"took no scene message for {SCENE_STALL_S:g} s")

    # --- frames --------------------------------------------------------------
    def any_ready(self) -> bool:
        return any(c.ready for c in self.clients)

    def publish_frame(self, payload: bytes) -> None:
        """Make `payload` the newest frame and send it to every browser that is ready for one."""
        self.frame_seq += 1
        self.frame = header(KIND_FRAME, self.generation) + payload
        for client in list(self.clients):
            if client.ready:
                self._send_frame(client)

    def _send_frame(self, client: Client) -> None:
        if self.frame is None or client.sent_seq >= self.frame_seq:
            return
        client.ready = False
        client.sent_seq = self.frame_seq
        client.frames_sent += 1
        self.frames_sent += 1
        client.send(self.frame, binary=True)

    def ack(self, client: Client) -> None:
        # The next tick sends the newest frame: acking never triggers a burst above rate_hz.
        client.ready = True

    # --- status --------------------------------------------------------------
    def publish_json(self, message: dict, clients: list[Client] | None = None) -> None:
        """Send a small JSON message to every browser (or to `clients`) not still busy with the previous one."""
        text = json.dumps(message)
        for client in list(self.clients) if clients is None else clients:
            if client.status_busy:
                continue
            future = client.send(text, binary=False)
            if future is not None:
                client.status_busy = True
                future.add_done_callback(lambda _f, c=client: setattr(c, "status_busy", False))

    def reply(self, client: Client, message: dict) -> None:
        if client in self.clients:
            client.send(json.dumps(message), binary=False)

    def refuse(self, client: Client, reason: str) -> None:
        """Count a browser message that was refused, log it (rate-limited) and tell the page why."""
        self.refused += 1
        refusals.warning("refused a browser message: %s (%d refused so far)", reason, self.refused)
        self.reply(client, {"type": "error", "error": reason})

    # --- connections ---------------------------------------------------------
    def _dropped(self, client: Client) -> None:
        self.dropped_pages += 1
        self.clients.discard(client)

    def opened(self, client: Client) -> None:
        client.on_drop = self._dropped
        self.clients.add(client)
        connections.info("browser connected (%d now)", len(self.clients))
        self._send_scene(client)

    def closed(self, client: Client) -> None:
        self.clients.discard(client)
        connections.info("browser left (%d now)", len(self.clients))


class Guarded(tornado.web.RequestHandler):
    """Every handler's gate (access.py): the Host allow-list, then the token when one is needed.

    A valid `?token=` sets the cookie; on the page itself it then redirects to the bare URL, so the
    token does not linger in the address bar or history.
    """

    def prepare(self) -> None:
        guard: Guard = self.application.settings["guard"]
        if not guard.host_ok(self.request.host):
            self._refuse(guard, f"Host {self.request.host[:100]!r} is not allowed")
        if guard.token is None:
            return
        given = self.get_query_argument("token", None)
        if given is not None and guard.token_ok(given):
            self.set_cookie(guard.cookie_name, given, path="/", httponly=True, samesite="Strict")
            if self.request.path == "/":
                self.redirect("/")
            return
        if not guard.token_ok(self.get_cookie(guard.cookie_name)):
            self._refuse(guard, "no valid access token")

    def _refuse(self, guard: Guard, why: str) -> None:
        guard.refused += 1
        refusals.warning("refused %s %s from %s: %s (%d refused so far)", self.request.method,
                         self.request.path[:100], self.request.remote_ip, why, guard.refused)
        raise tornado.web.HTTPError(403, reason="Forbidden: open the URL the viz printed at start")


class VizSocket(Guarded, tornado.websocket.WebSocketHandler):
    """The page's websocket: meshcat commands and frames out, JSON panel input in."""

    def initialize(self, hub: Hub) -> None:
        self.hub = hub
        self.client = Client(self)

    def check_origin(self, origin: str) -> bool:
        # Same-origin only: another site open in the user's browser must not drive the robot.
        return super().check_origin(origin)

    def open(self, *args: str, **kwargs: str) -> None:
        self.set_nodelay(True)
        guard: Guard = self.application.settings["guard"]
        role = guard.role_of(self.get_query_argument("token", None) or self.get_cookie(guard.cookie_name))
        self.client.may_drive = role == "operator"
        # First, so the page shows its driving controls only where they work.
        self.client.send(json.dumps({"type": "hello", "role": role}), binary=False)
        self.hub.opened(self.client)

    def on_message(self, message: str | bytes) -> None:
        if isinstance(message, bytes) or self.client.dropped:
            return
        if not self.client.messages.take():
            self.client.over_rate += 1
            self.hub.refused += 1
            if self.client.over_rate > MAX_OVER_RATE:
                self.client.drop(f"{self.client.over_rate} messages over {PAGE_MESSAGES_PER_S:g} a second")
            elif self.client.over_rate_told.take():
                self.hub.refuse(self.client, f"more than {PAGE_MESSAGES_PER_S:g} messages a second from this page")
            return
        try:
            data = json.loads(message)
        except (ValueError, RecursionError) as exc:  # deep nesting surfaces as RecursionError
            self.hub.refuse(self.client, f"not a JSON message ({type(exc).__name__})")
            return
        if isinstance(data, dict) and data.get("type") == "ack":
            self.hub.ack(self.client)
            return
        self.hub.on_message(self.client, data)

    def on_close(self) -> None:
        self.hub.closed(self.client)


class NoCacheStatic(Guarded, tornado.web.StaticFileHandler):
    @classmethod
    def get_absolute_path(cls, root: str, path: str) -> str:
        # A NUL (`/static/x%00.js`) made os.stat raise: a 500 and a traceback per request.
        if "\x00" in path:
            raise tornado.web.HTTPError(404)
        return super().get_absolute_path(root, path)

    def set_extra_headers(self, path: str) -> None:
        # A restarted viz may serve a newer page: never let the browser keep an old one.
        self.set_header("Cache-Control", "no-cache")


class MeshcatJs(Guarded):
    """meshcat's viewer bundle straight from the installed wheel (works offline)."""

    def get(self) -> None:
        self.set_header("Content-Type", "application/javascript")
        self.set_header("Cache-Control", "max-age=3600")
        self.write(MESHCAT_JS.read_bytes())


class PlotlyJs(Guarded):
    """plotly.js for the plot panel, straight from the installed plotly wheel (MIT; works offline).

    4.8 MB: the page loads it only when the plot panel is opened; gzip (compressed once) where accepted.
    """

    _gzipped: bytes | None = None

    def get(self) -> None:
        self.set_header("Content-Type", "application/javascript")
        self.set_header("Cache-Control", "max-age=3600")
        self.set_header("Vary", "Accept-Encoding")
        if "gzip" in self.request.headers.get("Accept-Encoding", ""):
            if PlotlyJs._gzipped is None:
                PlotlyJs._gzipped = gzip.compress(PLOTLY_JS.read_bytes(), compresslevel=6)
            self.set_header("Content-Encoding", "gzip")
            self.write(PlotlyJs._gzipped)
        else:
            self.write(PLOTLY_JS.read_bytes())


class IndexPage(Guarded):
    def get(self) -> None:
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.set_header("Cache-Control", "no-cache")
        self.write((STATIC_DIR / "index.html").read_bytes())


def log_request(handler: tornado.web.RequestHandler) -> None:
    """The access log (replaces tornado's): the path without its query, so `?token=` never reaches a log;
    served requests at debug level, failed ones at a bounded rate (a curl loop must not flood the log)."""
    status = handler.get_status()
    request = handler.request
    line = "%d %s %s from %s (%.1f ms)"
    args = (status, request.method, request.path[:100], request.remote_ip, 1000.0 * request.request_time())
    if status < 400:
        access_log.debug(line, *args)
    else:
        refused_requests.warning(line, *args)


def make_app(hub: Hub, guard: Guard) -> tornado.web.Application:
    """The tornado application: `/`, `/static/*`, `/meshcat/main.min.js`, `/ws`, each behind `guard`."""
    return tornado.web.Application(
        [
            (r"/", IndexPage),
            (r"/meshcat/main\.min\.js", MeshcatJs),
            (r"/plotly/plotly\.min\.js", PlotlyJs),
            (r"/static/(.*)", NoCacheStatic, {"path": str(STATIC_DIR)}),
            (r"/ws", VizSocket, {"hub": hub}),
        ],
        log_function=log_request,
        websocket_max_message_size=MAX_CLIENT_MESSAGE_BYTES,
        websocket_ping_interval=5,
        websocket_ping_timeout=15,
        guard=guard,
    )


__all__ = ["Client", "Hub", "make_app"]
