"""`zensim viz` wiring: zenoh in, web page out. The drawing and checks live in scene.py and panel.py.

Reads:
    state/joints (JointState), state/odom (Odometry): the robot's pose, latest wins.
    state/targets (JointTargets): the ghost (the commanded pose the bridge holds).
    state/sim (SimStatus): the status panel.
    state/joints, cmd/motors, state/targets, state/applied (every sample): the plot panel (plots.py).
    alive/* (liveliness): which services are up; `alive/sim` appearing triggers a description fetch.
    zensim/@router/alive (liveliness): the router badge, whatever robot id the router was started with.
    info/robot, info/urdf, info/mesh/{path} (gets): the description, fetched again after each sim start.
Writes:
    cmd/joints (JointTargets): slider moves.
    ctl/reset, ctl/pause, ctl/resume, ctl/step, ctl/mode (gets): the panel's buttons.
    alive/viz (liveliness token).

Threads: the tornado loop (main thread) owns the hub and the web server;
zenoh callbacks only store the newest sample; one worker thread fetches
descriptions; ctl gets run in a small executor so a slow sim never blocks the page.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import msgspec
import tornado.httpserver
import tornado.ioloop
import tornado.netutil
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.session import StartupError
from zensim.common.wire import TypedPublisher, decode_input, error_text, read_payload
from zensim.robots.description import RobotModelError, load_description, parse_urdf
from zensim.robots.mesh_files import resolve_mesh
from zensim.schemas import topics
from zensim.schemas.keys import SERVICES
from zensim.schemas import (
    AppliedCommand,
    Codec,
    CtlReply,
    DecodeError,
    JointState,
    JointTargets,
    Keys,
    ModeRequest,
    MotorCommand,
    Odometry,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    SimStatus,
    StepRequest,
    bounded,
    encoding_of,
)
from zensim.schemas.bounds import DESCRIPTION_CAP_BYTES, INFO_CAP_BYTES, STATE_CAP_BYTES

from . import panel, plots, scene
from .settings import VizSettings
from .access import Guard
from .web import Client, Hub, make_app

logger = logging.getLogger(__name__)
ctl_logs = {verb: RateLimitedLog(logger) for verb in ("reset", "pause", "resume", "step", "mode")}
"""The line per control request a page sends, one limiter per verb: bounded, a page may send many."""
alive_log = RateLimitedLog(logger)
"""The line per liveliness change: bounded, any session may declare tokens."""
MAX_ALIVE_NAMES = 32
"""Distinct names shown as alive; other tokens past this are ignored (counted). zensim's own services
(keys.SERVICES, six) always show."""
MAX_ALIVE_NAME_CHARS = 32

STATUS_PERIOD_S = 0.2
PLOT_PERIOD_S = 0.1
DESCRIPTION_RETRY_S = 2.0


class Latest:
    """The newest decoded sample of one key, with a counter that says when it changed.

    Zenoh callbacks run on their own threads; a single attribute store is atomic
    in CPython, so the reader sees either the old or the new (value, count).
    """

    def __init__(self) -> None:
        self.item: tuple[Any, int] = (None, 0)

    def set(self, value: Any) -> None:
        self.item = (value, self.item[1] + 1)


class VizService:
    """The viz process: holds the zenoh session's declarations and the web server."""

    def __init__(self, session: zenoh.Session, settings: VizSettings, stop: threading.Event) -> None:
        self.session = session
        self.settings = settings
        self.stop = stop
        self.keys = Keys(settings.robot_id)
        self.loop = tornado.ioloop.IOLoop.current()
        self.hub = Hub(self._on_client_message)
        self.executor = ThreadPoolExecutor(max_workers=2, thread_name_prefix="viz-ctl")
        self.bad_input = RateLimitedLog(logger)

        self.joints = Latest()
        self.odom = Latest()
        self.targets = Latest()
        self.status = Latest()
        self.alive: set[str] = set()
        self.alive_ignored = 0
        self.alive_logs: dict[str, RateLimitedLog] = {}
        self.router_alive = False
        """The router's own token (topics.ROUTER_ALIVE) is up: the badge is green for every robot."""
        self.alive_lock = threading.Lock()

        self.drawing: scene.Drawing | None = None
        self.limits: panel.JointLimits | None = None
        self.description_state = "waiting for the sim"
        self._fetch_wanted = threading.Event()
        self._last_drawn = (-1, -1, -1)

        # Any: each callback knows which type its codec gives (the key says it).
        self._codecs: dict[type, Codec[Any]] = {t: Codec(t) for t in (JointState, Odometry, JointTargets, SimStatus, RobotInfo,
                                                                      CtlReply, MotorCommand, AppliedCommand)}
        self.plot_feed = plots.PlotFeed()
        self.plot_subs: dict[Client, plots.Subscription] = {}
        self.cmd_publisher = TypedPublisher.of(session, self.keys, topics.JOINT_TARGETS)
        self._declared = [
            session.declare_subscriber(self.keys.joints, self._store(self.joints, JointState)),
            session.declare_subscriber(self.keys.odom, self._store(self.odom, Odometry)),
            session.declare_subscriber(self.keys.sim_status, self._store(self.status, SimStatus)),
            session.liveliness().declare_subscriber(self.keys.alive_any, self._on_alive, history=True),
            session.liveliness().declare_subscriber(topics.ROUTER_ALIVE.full_key(), self._on_router_alive, history=True),
        ]
        self._declared += [
            session.declare_subscriber(self.keys.joints, self._plot_sample(JointState)),
            session.declare_subscriber(self.keys.motors, self._plot_sample(MotorCommand)),
            session.declare_subscriber(self.keys.bridge_targets, self._plot_sample(JointTargets)),
            session.declare_subscriber(self.keys.applied, self._plot_sample(AppliedCommand)),
        ]
        if settings.ghost:
            self._declared.append(
                session.declare_subscriber(self.keys.bridge_targets, self._store(self.targets, JointTargets)))
        self.token = session.liveliness().declare_token(self.keys.alive("viz"))

    # --- zenoh callbacks: decode, store, return ----------------------------------------
    def _store(self, slot: Latest, message_type: type) -> Any:
        codec = self._codecs[message_type]

        def callback(sample: zenoh.Sample) -> None:
            try:
                slot.set(decode_input(sample, codec, STATE_CAP_BYTES))
            except DecodeError as exc:
                self.bad_input.warning("dropped a sample on %s: %s", bounded(str(sample.key_expr), 120), exc)

        return callback

    def _plot_sample(self, message_type: type) -> Any:
        """Every sample (not just the newest) feeds the plots; bad ones are dropped like the others."""
        codec, feed = self._codecs[message_type], self.plot_feed

        def callback(sample: zenoh.Sample) -> None:
            try:
                message = decode_input(sample, codec, STATE_CAP_BYTES)
            except DecodeError as exc:
                self.bad_input.warning("dropped a sample on %s: %s", bounded(str(sample.key_expr), 120), exc)
                return
            if isinstance(message, JointState):
                feed.on_state(message.sim_time_s, message.q, message.tau)
            elif isinstance(message, AppliedCommand):
                feed.on_applied(message.sim_time_s, message.command.names, message.command.q)
            else:
                feed.on_command(message.names, message.q)

        return callback

    def _on_alive(self, sample: zenoh.Sample) -> None:
        # Any session may declare tokens here: names are bounded in length and count, and so is what the
        # status shows and the log says (3000 invented tokens once made every page's status 624 KB).
        service = str(sample.key_expr).rsplit("/", 1)[-1]
        if len(service) > MAX_ALIVE_NAME_CHARS:
            self.alive_ignored += 1
            alive_log.warning("ignored a liveliness token with a %d-character name (%d ignored so far)",
                              len(service), self.alive_ignored)
            return
        with self.alive_lock:
            if sample.kind == zenoh.SampleKind.PUT:
                # zensim's own services always show (a flood of invented names must not hide the sim);
                # other names share the cap.
                if service not in SERVICES and service not in self.alive and len(self.alive) >= MAX_ALIVE_NAMES:
                    self.alive_ignored += 1
                    alive_log.warning("ignored liveliness token %r: already %d services shown (%d ignored so far)",
                                      service, MAX_ALIVE_NAMES, self.alive_ignored)
                    return
                self.alive.add(service)
            else:
                self.alive.discard(service)
        # zensim's own services each have their line (bounded: a few names); any other name shares one limiter.
        line = self.alive_logs.setdefault(service, RateLimitedLog(logger)) if service in SERVICES else alive_log
        line.info("%s %s", service, "is alive" if sample.kind == zenoh.SampleKind.PUT else "left")
        if service == "sim" and sample.kind == zenoh.SampleKind.PUT:
            # A (re)started sim may serve another robot or mode: fetch the description again.
            self._fetch_wanted.set()

    def _on_router_alive(self, sample: zenoh.Sample) -> None:
        with self.alive_lock:
            self.router_alive = sample.kind == zenoh.SampleKind.PUT
        logger.info("the router %s", "is alive" if self.router_alive else "left")

    # --- description ------------------------------------------------------------------
    def fetch_loop(self) -> None:
        """Worker thread: fetch the description whenever asked (startup, each sim start)."""
        if self.settings.urdf:
            self._fetch_wanted.set()
        while not self.stop.is_set():
            if not self._fetch_wanted.wait(0.2):
                continue
            self._fetch_wanted.clear()
            try:
                drawing = self._fetch_description()
            except (OSError, ValueError, TimeoutError, zenoh.ZError) as exc:
                self.description_state = f"description failed: {exc}"
                logger.warning("%s", self.description_state)
                with self.alive_lock:
                    sim_alive = "sim" in self.alive
                if sim_alive and not self.stop.wait(DESCRIPTION_RETRY_S):
                    self._fetch_wanted.set()
                continue
            self.loop.add_callback(self._install, drawing)

    def _get_bytes(self, key: str, payload: bytes | None = None, cap_bytes: int = DESCRIPTION_CAP_BYTES) -> bytes:
        """One zenoh get; the first good reply's payload, at most `cap_bytes` long.

        Raises:
            TimeoutError: no reply within query_timeout_s.
            ValueError: the queryable answered with an error, or a reply over the cap (DecodeError).
        """
        replies = self.session.get(key, payload=payload, encoding=zenoh.Encoding(encoding_of("msgpack")) if payload is not None else None,
                                   timeout=self.settings.query_timeout_s)
        for reply in replies:
            if reply.ok is not None:
                return read_payload(reply.ok, cap_bytes)[0]
            raise ValueError(f"{key}: {error_text(reply.err)}")
        raise TimeoutError(f"no reply on {key} within {self.settings.query_timeout_s} s")

    def _fetch_description(self) -> scene.Drawing:
        self.description_state = "fetching the description"
        started = time.monotonic()
        info: RobotInfo | None = None
        with self.alive_lock:
            sim_alive = "sim" in self.alive
        if sim_alive or not self.settings.urdf:
            info = self._codecs[RobotInfo].decode(self._get_bytes(self.keys.robot_info, cap_bytes=INFO_CAP_BYTES))
        meshes: dict[str, bytes] = {}
        if self.settings.urdf:
            urdf_path = Path(self.settings.urdf).expanduser().resolve()
            robot = load_description(urdf_path)
            source = str(urdf_path)
            for filename in scene.visual_mesh_filenames(robot):
                try:
                    meshes[filename] = resolve_mesh(filename, urdf_path.parent).read_bytes()
                except (OSError, RobotModelError) as exc:  # not drawn, as the sim would not serve it
                    logger.warning("not sent to browsers: %s", exc)
        else:
            assert info is not None
            robot = parse_urdf(self._get_bytes(self.keys.urdf))
            source = f"zenoh {self.keys.urdf}"
            for filename in scene.visual_mesh_filenames(robot):
                served = scene.match_mesh(filename, info.mesh_paths)
                if served is None:
                    logger.warning("mesh %s is not among RobotInfo.mesh_paths: not drawn", filename)
                    continue
                meshes[filename] = self._get_bytes(self.keys.mesh(served))
        drawing = scene.build_drawing(
            robot, meshes,
            joint_names=info.joint_names if info else None,
            q_min=info.q_min if info else None, q_max=info.q_max if info else None,
            ghost=self.settings.ghost, source=source,
        )
        logger.info("description of %s from %s: %d links, %d joints, %d meshes (%.0f kB) in %.2f s",
                    drawing.robot.name, source, len(drawing.kin.links), len(drawing.joint_names), len(meshes),
                    sum(map(len, meshes.values())) / 1e3, time.monotonic() - started)
        return drawing

    def _install(self, drawing: scene.Drawing) -> None:
        self.drawing = drawing
        self.limits = panel.JointLimits(drawing.joint_names, drawing.lower, drawing.upper)
        self.plot_feed.set_joints(drawing.joint_names)
        self.plot_subs.clear()  # pages pick their joints again for the new robot
        self.description_state = "ok"
        self._last_drawn = (-1, -1, -1)
        self.hub.set_scene(drawing.commands, drawing.meta)

    # --- periodic work on the loop ------------------------------------------------------
    def tick(self) -> None:
        """Draw the newest pose for browsers that are ready (at most rate_hz)."""
        if self.stop.is_set():
            self.loop.stop()
            return
        drawing = self.drawing
        if drawing is None or not self.hub.any_ready():
            return
        (js, n_j), (odom, n_o), (targets, n_t) = self.joints.item, self.odom.item, self.targets.item
        if (n_j, n_o, n_t) == self._last_drawn and self.hub.frame is not None:
            return  # nothing new: ready browsers already have the newest frame
        self._last_drawn = (n_j, n_o, n_t)
        pos = odom.pos if odom is not None else None
        quat = odom.quat_wxyz if odom is not None else None
        q = js.q if js is not None and len(js.q) == len(drawing.joint_names) else None
        actual = drawing.kin.transforms(q, scene.base_transform(pos, quat))
        parts = [actual]
        if self.settings.ghost:
            parts.append(drawing.kin.transforms(
                self._ghost_q(drawing, targets, q), scene.base_transform(pos, quat, self.settings.ghost_offset_m)))
        self.hub.publish_frame(scene.frame_payload(*parts))

    @staticmethod
    def _ghost_q(drawing: scene.Drawing, targets: JointTargets | None, q: Any) -> list[float] | None:
        """Targets in canonical order; joints the bridge did not name follow the actual pose."""
        if targets is None:
            return q
        ghost = list(q) if q is not None else [0.0] * len(drawing.joint_names)
        index = {n: i for i, n in enumerate(drawing.joint_names)}
        for name, value in zip(targets.names, targets.q):
            i = index.get(name)
            if i is not None:
                ghost[i] = value
        return ghost

    def publish_status(self) -> None:
        status, _ = self.status.item
        targets, _ = self.targets.item
        joints, _ = self.joints.item
        with self.alive_lock:
            alive = sorted(self.alive | ({"router"} if self.router_alive else set()))
        message: dict[str, Any] = {
            "type": "status",
            "alive": alive,
            "description": self.description_state,
            "sim": _bounded_texts(msgspec.to_builtins(status)) if status is not None else None,
            "targets": {"names": list(targets.names), "q": list(targets.q)} if targets is not None else None,
            "state_seq": joints.seq if joints is not None else None,
            "frames_sent": self.hub.frames_sent,
        }
        self.hub.publish_json(message)

    def publish_plots(self) -> None:
        """Send each plotting page what it has not had, once its previous batch was written."""
        for client in list(self.plot_subs):
            if client not in self.hub.clients:
                del self.plot_subs[client]
                continue
            sub = self.plot_subs[client]
            if sub.busy:
                continue
            batch = self.plot_feed.batch(sub)
            if batch is None:
                continue
            future = client.send(json.dumps(batch), binary=False)
            if future is not None:
                sub.busy = True
                future.add_done_callback(lambda _f, s=sub: setattr(s, "busy", False))

    # --- browser input -----------------------------------------------------------------
    def _on_client_message(self, client: Client, data: Any) -> None:
        try:
            command = panel.parse_client_message(data, self.limits)
        except panel.PanelError as exc:
            self.hub.refuse(client, str(exc))
            return
        if isinstance(command, JointTargets):
            self.cmd_publisher.put(command)
            return
        if isinstance(command, panel.PlotRequest):
            if command.joints:
                self.plot_subs[client] = self.plot_feed.subscribe(command.joints)
            else:
                self.plot_subs.pop(client, None)
            return
        if client.ctl_in_flight:
            self.hub.refuse(client, f"ctl/{command.verb}: this page's previous control request is still in flight")
            return
        client.ctl_in_flight = True
        future = self.loop.run_in_executor(self.executor, self._ctl, command)
        future.add_done_callback(lambda f: self._ctl_done(client, command.verb, f))

    def _ctl_done(self, client: Client, verb: str, future: Any) -> None:
        client.ctl_in_flight = False
        if future.cancelled():
            return
        error = future.exception()
        out = future.result() if error is None else {"type": "ctl_reply", "verb": verb, "ok": False,
                                                     "error": bounded(f"{type(error).__name__}: {error}")}
        self.hub.reply(client, out)

    def _ctl(self, command: panel.Ctl) -> dict:
        """Executor thread: one ctl get; the page's reply as a dict."""
        request = {
            "reset": ResetRequest(),
            "pause": PauseRequest(),
            "resume": ResumeRequest(),
            "step": StepRequest(n=1),
        }.get(command.verb) or ModeRequest(mode=command.mode)  # type: ignore[arg-type]
        out: dict[str, Any] = {"type": "ctl_reply", "verb": command.verb}
        try:
            raw = self._get_bytes(self.keys.ctl(command.verb), Codec(type(request)).encode(request), STATE_CAP_BYTES)
            reply = self._codecs[CtlReply].decode(raw)
        except (TimeoutError, ValueError, zenoh.ZError) as exc:
            out.update(ok=False, error=bounded(str(exc)))
            return out
        out.update(_bounded_texts(msgspec.to_builtins(reply)))
        out["type"] = "ctl_reply"
        ctl_logs[command.verb].info("ctl/%s -> ok=%s %s", command.verb, reply.ok, reply.error or "")
        return out

    def close(self) -> None:
        self.token.undeclare()
        for declared in self._declared:
            declared.undeclare()
        self.cmd_publisher.undeclare()
        self.executor.shutdown(wait=False, cancel_futures=True)


def _bounded_texts(fields: dict[str, Any]) -> dict[str, Any]:
    """A message's fields with every string cut to a bounded length: they go to every browser."""
    return {name: bounded(value) if isinstance(value, str) else value for name, value in fields.items()}


def url_authority(host: str, port: int) -> str:
    """`host:port` as a URL writes it (an IPv6 address in brackets)."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def run(session: zenoh.Session, settings: VizSettings, stop: threading.Event) -> int:
    """Serve the page until `stop` is set; returns the exit code."""
    service = VizService(session, settings, stop)
    try:
        sockets = tornado.netutil.bind_sockets(settings.port, address=settings.host)
    except OSError as exc:
        service.close()
        raise StartupError(f"cannot serve the page on {settings.host}:{settings.port} "
                           f"(--host / ZENSIM_VIZ_HOST, --port / ZENSIM_VIZ_PORT): {exc.strerror or exc}") from None
    port = sockets[0].getsockname()[1]
    guard = Guard(settings.host, settings.published_on, settings.allowed_hosts, settings.token,
                  always_token=bool(settings.zenoh.secure_dir))
    guard.cookie_name = f"zensim_viz_token_{port}"
    server = tornado.httpserver.HTTPServer(make_app(service.hub, guard))
    server.add_sockets(sockets)
    logger.info("viz up: http://%s:%d/", settings.host, port)
    if guard.token is not None:
        # Once, like Jupyter: whoever can read this log can open the page. No other line carries the token
        # (requests are logged without their query, web.py log_request).
        why = "the network is secured" if settings.zenoh.secure_dir else "the page is reachable beyond loopback"
        logger.info("%s: open the page with its token: http://%s/?token=%s", why,
                    url_authority(guard.url_host, port), guard.token)
    fetcher = threading.Thread(target=service.fetch_loop, name="viz-description", daemon=True)
    fetcher.start()
    tornado.ioloop.PeriodicCallback(service.tick, 1000.0 / settings.rate_hz).start()
    tornado.ioloop.PeriodicCallback(service.publish_status, STATUS_PERIOD_S * 1000).start()
    tornado.ioloop.PeriodicCallback(service.publish_plots, PLOT_PERIOD_S * 1000).start()
    def stop_when_asked() -> None:
        if stop.is_set():
            service.loop.stop()

    tornado.ioloop.PeriodicCallback(stop_when_asked, 50).start()
    try:
        service.loop.start()
    finally:
        server.stop()
        service.close()
        fetcher.join(timeout=0.3)  # a daemon: a get in flight must not hold the exit past 2 s
    logger.info("viz stopped")
    return 0
