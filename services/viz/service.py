"""`zensim viz` wiring: zenoh in, web page out. The drawing and checks live in scene.py and panel.py.

It shows one robot (`--robot-id`) or every robot of a world (`--world`, world.py), each robot's keys
read and written by its own RobotFeed (feed.py); the page's sliders, buttons, status and plots act on
the robot selected on the page.

Reads (under each robot's `zensim/{robot}/`):
    state/joints (JointState), state/odom (Odometry): the robot's pose, latest wins.
    state/targets (JointTargets): the ghost (the commanded pose the bridge holds).
    state/sim (SimStatus): the status panel.
    state/loco (LocoStatus): the drive panel (commanded and achieved velocity).
    state/joints, cmd/motors, state/targets, state/applied (every sample): the plot panel (plots.py).
    alive/* (liveliness): which services are up; `alive/sim` appearing triggers a description fetch.
    zensim/@router/alive (liveliness): the router badge, whatever robot id the router was started with.
    info/robot, info/urdf, info/mesh/{path} (gets): the description (and its terrain, terrain.py), fetched again after each sim start.
    zensim/{world}/world/info (get, with --world): the world's robots, fetched again after its sim restarts.
Writes (under the selected robot's `zensim/{robot}/`):
    cmd/joints (JointTargets): slider moves.
    cmd/velocity (VelocityCommand), cmd/remote (RemoteState): the page's keys and gamepad, paced per
        robot (drive.py: at most 30 puts a second, latest wins, the rest shed and counted).
    ctl/reset, ctl/pause, ctl/resume, ctl/step, ctl/mode (gets): the panel's buttons.
    zensim/{world}/world/pause, world/resume, world/step (gets, with --world): the pause, resume and step
        buttons (a world's robots share one clock: a robot's own ctl/pause etc. refuse).
    ctl/loco (get): the drive panel's Stand and Damp buttons, a gamepad's A and B.
    ctl/band, ctl/push (gets): the band panel's On, Lower, Raise, Off and Push buttons.
    alive/viz (liveliness token, one per robot shown).

Threads: the tornado loop (main thread) owns the hub, the web server and what is shown;
zenoh callbacks only store the newest sample; one worker thread fetches
descriptions; ctl gets run in a small executor so a slow sim never blocks the page.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import tornado.httpserver
import tornado.ioloop
import tornado.netutil
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.session import StartupError
from zensim.common.wire import error_text, read_payload
from zensim.robots.description import RobotModelError, load_description, parse_urdf
from zensim.robots.mesh_files import resolve_mesh
from zensim.schemas import topics
from zensim.schemas import (
    BandRequest,
    Codec,
    CtlReply,
    JointTargets,
    Keys,
    LocoRequest,
    LocoStatus,
    ModeRequest,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    StepRequest,
    bounded,
    check_robot_id,
    encoding_of,
    short_repr,
)
from zensim.schemas.bounds import DESCRIPTION_CAP_BYTES, STATE_CAP_BYTES
from zensim.schemas.messages import Terrain

from . import fetch, panel, plots, scene, world
from .drive import Drive
from .feed import RobotFeed
from .settings import VizSettings
from .terrain import terrain_commands
from .access import Guard
from .web import Client, Hub, make_app

logger = logging.getLogger(__name__)
WORLD_CLOCK_VERBS = ("pause", "resume", "step")
"""The buttons that act on a world's one clock: under `--world` they are the world's verbs."""
ctl_logs = {verb: RateLimitedLog(logger) for verb in ("reset", "pause", "resume", "step", "mode", "loco", "band", "push")}
"""The line per control request a page sends, one limiter per verb: bounded, a page may send many."""
shed_log = RateLimitedLog(logger, 10.0)
"""The line when pages drive a robot faster than drive.PUTS_PER_S: every 10 s at most, with the counts."""
world_wait_log = RateLimitedLog(logger, 30.0)
"""The line while the world does not answer (the viewer may start before it): every 30 s at most."""

STATUS_PERIOD_S = 0.2
PLOT_PERIOD_S = 0.1
DESCRIPTION_RETRY_S = 2.0


@dataclass(frozen=True)
class Shown:
    """One robot on the page: where its samples come from, its drawing and the limits its sliders cover."""

    feed: RobotFeed
    drawing: scene.Drawing
    limits: panel.JointLimits
    ghost_offset_m: tuple[float, ...]
    """Where its ghost stands relative to it (a world's: clear of the neighbours, world.ghost_offsets)."""


class VizService:
    """The viz process: holds the zenoh session's declarations and the web server."""

    def __init__(self, session: zenoh.Session, settings: VizSettings, stop: threading.Event) -> None:
        self.session = session
        self.settings = settings
        self.world = settings.world
        self.stop = stop
        self.loop = tornado.ioloop.IOLoop.current()
        self.hub = Hub(self._on_client_message)
        self.executor = ThreadPoolExecutor(max_workers=2, thread_name_prefix="viz-ctl")

        self.router_alive = False
        """The router's own token (topics.ROUTER_ALIVE) is up: the badge is green for every robot."""
        self.alive_lock = threading.Lock()
        self.feeds: dict[str, RobotFeed] = {}
        """Robot id -> its feed. One robot: made here, kept for good. A world: made for the robots of each
        world/info by the fetch thread, installed (and the others closed) on the loop. Replaced whole."""
        self.shown: list[Shown] = []
        """What the page draws, in frame order (loop thread)."""
        self.views: dict[str, Shown] = {}
        self.description_state = f"waiting for the world {self.world}" if self.world else "waiting for the sim"
        self._fetch_wanted = threading.Event()
        self._world_left = False
        """A world's sim went away since its world/info was fetched: fetch again when it is back."""
        self._last_drawn: tuple[int, ...] = ()
        self._codecs: dict[type, Codec[Any]] = {t: Codec(t) for t in (RobotInfo, CtlReply, LocoStatus)}
        self.plot_subs: dict[Client, tuple[plots.PlotFeed, plots.Subscription]] = {}
        self._declared = [
            session.liveliness().declare_subscriber(topics.ROUTER_ALIVE.full_key(), self._on_router_alive, history=True),
        ]
        if self.world is None:  # last: its callbacks start at once and use the above
            self.feeds = {settings.robot_id: RobotFeed(session, settings.robot_id, settings.ghost, self._on_sim)}

    # --- zenoh callbacks ----------------------------------------------------------------
    def _on_sim(self, up: bool) -> None:
        """A robot's `alive/sim` came or went (a zenoh thread)."""
        if self.world is None:
            if up:  # a (re)started sim may serve another robot or mode: fetch the description again
                self._fetch_wanted.set()
        elif not up:  # the world stopped: fetch it again, retried until it answers (it may come back changed)
            self._world_left = True
            self._fetch_wanted.set()
        elif self._world_left:
            self._world_left = False
            self._fetch_wanted.set()

    def _on_router_alive(self, sample: zenoh.Sample) -> None:
        with self.alive_lock:
            self.router_alive = sample.kind == zenoh.SampleKind.PUT
        logger.info("the router %s", "is alive" if self.router_alive else "left")

    # --- description ------------------------------------------------------------------
    def fetch_loop(self) -> None:
        """Worker thread: fetch the description whenever asked (startup, each sim start)."""
        if self.settings.urdf or self.world:
            self._fetch_wanted.set()
        while not self.stop.is_set():
            if not self._fetch_wanted.wait(0.2):
                continue
            self._fetch_wanted.clear()
            try:
                if self.world:
                    self._fetch_world()
                else:
                    self._fetch_robot()
            except (OSError, ValueError, TimeoutError, zenoh.ZError) as exc:
                self.description_state = f"description failed: {exc}"
                # A world is asked again until it answers (the viewer may start first; its robots are
                # known only from its answer); one robot, while its sim is up.
                retry = self.world is not None or "sim" in self.feeds[self.settings.robot_id].alive_names()
                (world_wait_log if self.world else logger).warning("%s", self.description_state)
                if retry and not self.stop.wait(DESCRIPTION_RETRY_S):
                    self._fetch_wanted.set()

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

    def _get(self, key: str, cap_bytes: int) -> bytes:
        """fetch.Getter: a description get."""
        return self._get_bytes(key, cap_bytes=cap_bytes)

    def _fetch_robot(self) -> None:
        """One robot's description, drawn once the loop installs it."""
        feed = self.feeds[self.settings.robot_id]
        drawing, terrain = self._fetch_description(feed)
        shown = Shown(feed, drawing, panel.JointLimits(drawing.joint_names, drawing.lower, drawing.upper),
                      self.settings.ghost_offset_m)
        self.loop.add_callback(self._install, [shown], drawing.commands + terrain_commands(terrain), drawing.meta)

    def _fetch_description(self, feed: RobotFeed) -> tuple[scene.Drawing, Terrain | None]:
        """The robot's drawing, and the terrain its sim stands it on (info/robot's; None: flat or no sim)."""
        self.description_state = "fetching the description"
        started = time.monotonic()
        keys = feed.keys
        info: RobotInfo | None = None
        if "sim" in feed.alive_names() or not self.settings.urdf:
            info = fetch.robot_info(self._get, keys)
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
            robot = parse_urdf(fetch.urdf(self._get, keys))
            source = f"zenoh {keys.urdf}"
            meshes = fetch.meshes(self._get, keys, robot, info)
        drawing = scene.build_drawing(
            robot, meshes,
            joint_names=info.joint_names if info else None,
            q_min=info.q_min if info else None, q_max=info.q_max if info else None,
            ghost=self.settings.ghost, source=source,
        )
        logger.info("description of %s from %s: %d links, %d joints, %d meshes (%.0f kB) in %.2f s",
                    drawing.robot.name, source, len(drawing.kin.links), len(drawing.joint_names), len(meshes),
                    sum(map(len, meshes.values())) / 1e3, time.monotonic() - started)
        return drawing, info.terrain if info else None

    def _fetch_world(self) -> None:
        """The world's robots and their descriptions; a feed for each (kept for robots already shown)."""
        assert self.world is not None
        self.description_state = f"fetching the world {self.world}"
        started = time.monotonic()
        fetched = world.fetch_world(self._get, self.world, self.settings.ghost)
        self._world_left = False
        known = self.feeds
        feeds = {robot_id: known.get(robot_id) or RobotFeed(self.session, robot_id, self.settings.ghost, self._on_sim,
                                                             label=f"{robot_id}: ")
                 for robot_id, _ in fetched.drawings}
        offsets = world.ghost_offsets(fetched.spawns, self.settings.ghost_offset_m)
        shown = [Shown(feeds[robot_id], d, panel.JointLimits(d.joint_names, d.lower, d.upper), offsets[robot_id])
                 for robot_id, d in fetched.drawings]
        state = "ok" if not fetched.left_out else \
            f"showing the first {len(shown)} robots of {len(shown) + fetched.left_out} (at most {world.MAX_ROBOTS})"
        logger.info("description of world %s: %d robots in %.2f s", self.world, len(shown), time.monotonic() - started)
        self.loop.add_callback(self._install, shown, fetched.commands, fetched.meta, feeds, state)

    def _install(self, shown: list[Shown], commands: list[bytes], meta: dict, feeds: dict[str, RobotFeed] | None = None,
                 state: str = "ok") -> None:
        """(loop) Show `shown` from now on; with `feeds`, those replace the feeds (others are closed)."""
        if feeds is not None:
            old, self.feeds = self.feeds, feeds
            for feed in old.values():
                if feeds.get(feed.keys.robot) is not feed:
                    feed.close()
        self.shown = shown
        self.views = {view.feed.keys.robot: view for view in shown}
        for view in shown:
            view.feed.plot_feed.set_joints(view.drawing.joint_names)
        self.plot_subs.clear()  # pages pick their joints again for the new robot
        self.description_state = state
        self._last_drawn = ()
        self.hub.set_scene(commands, meta)

    # --- periodic work on the loop ------------------------------------------------------
    def tick(self) -> None:
        """Draw the newest poses of every robot shown, in one frame, for browsers that are ready (at most rate_hz)."""
        if self.stop.is_set():
            self.loop.stop()
            return
        self.hub.sweep()  # pages stalled on their scene
        for feed in list(self.feeds.values()):  # drive inputs that came faster than the rate: the newest now
            drive = feed.drive_gate.flush()
            if drive is not None:
                self._put_drive(feed, drive)
        shown = self.shown
        if not shown or not self.hub.any_ready():
            return
        items = [(view, view.feed.joints.item, view.feed.odom.item, view.feed.targets.item) for view in shown]
        counts = tuple(n for _, (_, n_j), (_, n_o), (_, n_t) in items for n in (n_j, n_o, n_t))
        if counts == self._last_drawn and self.hub.frame is not None:
            return  # nothing new: ready browsers already have the newest frame
        self._last_drawn = counts
        parts: list[Any] = []
        for view, (js, _), (odom, _), (targets, _) in items:
            parts += self._transforms(view, js, odom, targets)
        self.hub.publish_frame(scene.frame_payload(*parts))

    def _transforms(self, view: Shown, js: Any, odom: Any, targets: JointTargets | None) -> list[Any]:
        """One robot's link transforms (and its ghost's), in the order of its drawing's paths."""
        drawing = view.drawing
        pos = odom.pos if odom is not None else None
        quat = odom.quat_wxyz if odom is not None else None
        q = js.q if js is not None and len(js.q) == len(drawing.joint_names) else None
        actual = drawing.kin.transforms(q, scene.base_transform(pos, quat))
        if not self.settings.ghost:
            return [actual]
        return [actual, drawing.kin.transforms(
            self._ghost_q(drawing, targets, q), scene.base_transform(pos, quat, view.ghost_offset_m))]

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

    def _feed_of(self, client: Client) -> RobotFeed | None:
        """The robot a page acts on: the one it selected, else the first (None before a world is known)."""
        feeds = self.feeds
        return (feeds.get(client.robot) if client.robot else None) or next(iter(feeds.values()), None)

    def _view_of(self, client: Client) -> Shown | None:
        """The drawn robot a page acts on (None before a description)."""
        view = self.views.get(client.robot) if client.robot else None
        return view or (self.shown[0] if self.shown else None)

    def publish_status(self) -> None:
        """Each page the status of its robot (pages that selected the same robot share one message)."""
        with self.alive_lock:
            router = {"router"} if self.router_alive else set()
        pages: dict[RobotFeed | None, list[Client]] = {}
        for client in list(self.hub.clients):
            pages.setdefault(self._feed_of(client), []).append(client)
        for feed, clients in pages.items():
            self.hub.publish_json(self._status(feed, router), clients)

    def _status(self, feed: RobotFeed | None, router: set[str]) -> dict[str, Any]:
        status = targets = joints = loco = None
        alive: set[str] = set()
        if feed is not None:
            (status, _), (targets, _), (joints, _), (loco, _) = (feed.status.item, feed.targets.item, feed.joints.item,
                                                                  feed.loco.item)
            alive = feed.alive_names()
        message: dict[str, Any] = {
            "type": "status",
            "alive": sorted(alive | router),
            "description": self.description_state,
            "sim": _bounded_texts(msgspec.to_builtins(status)) if status is not None else None,
            "targets": {"names": list(targets.names), "q": list(targets.q)} if targets is not None else None,
            "state_seq": joints.seq if joints is not None else None,
            "loco": _loco_summary(loco) if loco is not None else None,
            "drive": feed.drive_gate.counts() if feed is not None else None,
            "frames_sent": self.hub.frames_sent,
        }
        if self.world is not None:
            message["robot"] = feed.keys.robot if feed is not None else None
        return message

    def publish_plots(self) -> None:
        """Send each plotting page what it has not had, once its previous batch was written."""
        for client in list(self.plot_subs):
            if client not in self.hub.clients:
                del self.plot_subs[client]
                continue
            feed, sub = self.plot_subs[client]
            if sub.busy:
                continue
            batch = feed.batch(sub)
            if batch is None:
                continue
            future = client.send(json.dumps(batch), binary=False)
            if future is not None:
                sub.busy = True
                future.add_done_callback(lambda _f, s=sub: setattr(s, "busy", False))

    # --- browser input -----------------------------------------------------------------
    def _on_client_message(self, client: Client, data: Any) -> None:
        view = self._view_of(client)
        try:
            command = panel.parse_client_message(data, view.limits if view is not None else None, client.may_drive)
        except panel.PanelError as exc:
            self.hub.refuse(client, str(exc))
            return
        if isinstance(command, Drive):
            feed = self._feed_of(client)
            if feed is None:
                self.hub.refuse(client, f"drive: no robot yet ({self.description_state})")
                return
            gate = feed.drive_gate
            shed_before = gate.shed
            now = gate.offer(command)
            if now is not None:
                self._put_drive(feed, now)
            elif gate.shed > shed_before:
                shed_log.warning("%sdrive inputs from pages come faster than %g a second: newest kept, %d shed so far "
                                 "(%d received)", feed.label, gate.rate, gate.shed, gate.received)
            return
        if isinstance(command, panel.Select):
            if command.robot not in self.views:
                self.hub.refuse(client, f"no robot {short_repr(command.robot)} is shown here")
                return
            client.robot = command.robot
            self.plot_subs.pop(client, None)  # the page asks again for the new robot's joints
            return
        if isinstance(command, JointTargets):
            assert view is not None  # parse_client_message refuses targets before a description
            view.feed.cmd_publisher.put(command)
            return
        if isinstance(command, panel.PlotRequest):
            if command.joints:
                assert view is not None  # likewise for joints to plot
                plot_feed = view.feed.plot_feed
                self.plot_subs[client] = (plot_feed, plot_feed.subscribe(command.joints))
            else:
                self.plot_subs.pop(client, None)
            return
        feed = self._feed_of(client)
        # What the page's reply calls the request: "pause", "loco walk", "band lower", "push".
        verb = f"{command.__class__.__name__.lower()} {command.verb}" if isinstance(command, (panel.Loco, panel.Band)) \
            else command.verb
        if feed is None:
            self.hub.refuse(client, f"ctl/{verb}: no robot yet ({self.description_state})")
            return
        if client.ctl_in_flight:
            self.hub.refuse(client, f"ctl/{verb}: this page's previous control request is still in flight")
            return
        client.ctl_in_flight = True
        work: Any = {panel.Loco: self._loco, panel.Band: self._band, panel.Push: self._push}.get(type(command), self._ctl)
        future = self.loop.run_in_executor(self.executor, work, command, feed)
        future.add_done_callback(lambda f: self._ctl_done(client, verb, f))

    def _ctl_done(self, client: Client, verb: str, future: Any) -> None:
        client.ctl_in_flight = False
        if future.cancelled():
            return
        error = future.exception()
        out = future.result() if error is None else {"type": "ctl_reply", "verb": verb, "ok": False,
                                                     "error": bounded(f"{type(error).__name__}: {error}")}
        self.hub.reply(client, out)

    def _ctl(self, command: panel.Ctl, feed: RobotFeed) -> dict:
        """Executor thread: one ctl get to `feed`'s robot; the page's reply as a dict."""
        request = {
            "reset": ResetRequest(),
            "pause": PauseRequest(),
            "resume": ResumeRequest(),
            "step": StepRequest(n=1),
        }.get(command.verb) or ModeRequest(mode=command.mode)  # type: ignore[arg-type]
        key = feed.keys.ctl(command.verb)
        if self.world is not None and command.verb in WORLD_CLOCK_VERBS:  # every robot's clock: the world's verb
            key = getattr(Keys(self.world), f"world_{command.verb}")
        return self._ctl_get(feed, key, request, command.verb)

    def _band(self, command: panel.Band, feed: RobotFeed) -> dict:
        """Executor thread: one ctl/band get (a band button) to `feed`'s robot."""
        return self._ctl_get(feed, feed.keys.ctl_band, BandRequest(verb=command.verb),  # type: ignore[arg-type]
                             "band", f"band {command.verb}")

    def _push(self, command: panel.Push, feed: RobotFeed) -> dict:
        """Executor thread: one ctl/push get (the Push button) to `feed`'s robot, its direction turned from the
        robot's heading frame into the world frame by the robot's yaw (state/odom; none yet: the world frame)."""
        odom, _ = feed.odom.item
        x, y, z = command.request.direction
        if odom is not None:
            yaw = _yaw(odom.quat_wxyz)
            x, y = x * math.cos(yaw) - y * math.sin(yaw), x * math.sin(yaw) + y * math.cos(yaw)
        request = msgspec.structs.replace(command.request, direction=(x, y, z))
        return self._ctl_get(feed, feed.keys.ctl_push, request, "push")

    def _ctl_get(self, feed: RobotFeed, key: str, request: Any, log_verb: str, verb: str | None = None) -> dict:
        """Executor thread: one ctl get answered by a CtlReply; the page's reply as a dict (`verb` names it)."""
        out: dict[str, Any] = {"type": "ctl_reply", "verb": verb or log_verb}
        try:
            raw = self._get_bytes(key, Codec(type(request)).encode(request), STATE_CAP_BYTES)
            reply = self._codecs[CtlReply].decode(raw)
        except (TimeoutError, ValueError, zenoh.ZError) as exc:
            out.update(ok=False, error=bounded(str(exc)))
            return out
        out.update(_bounded_texts(msgspec.to_builtins(reply)))
        out["type"] = "ctl_reply"
        ctl_logs[log_verb].info("%s%s -> ok=%s %s", feed.label, key.split("/", 2)[2], reply.ok, reply.error or "")
        return out

    @staticmethod
    def _put_drive(feed: RobotFeed, drive: Drive) -> None:
        """(loop) One input of the page's keys or gamepad: the velocity, then the remote as held."""
        feed.velocity_publisher.put(drive.velocity)
        feed.remote_publisher.put(drive.remote)

    def _loco(self, command: panel.Loco, feed: RobotFeed) -> dict:
        """Executor thread: one ctl/loco get (a walking verb) to `feed`'s robot; the page's reply as a dict."""
        verb = f"loco {command.verb}"
        out: dict[str, Any] = {"type": "ctl_reply", "verb": verb}
        request = LocoRequest(verb=command.verb)  # type: ignore[arg-type]
        try:
            raw = self._get_bytes(feed.keys.ctl_loco, Codec(LocoRequest).encode(request), STATE_CAP_BYTES)
            reply = self._codecs[LocoStatus].decode(raw)
        except (TimeoutError, ValueError, zenoh.ZError) as exc:
            out.update(ok=False, error=bounded(str(exc)))
            return out
        out.update(ok=reply.ok, error=bounded(reply.error) if reply.error else None)
        ctl_logs["loco"].info("%sctl/loco %s -> ok=%s %s", feed.label, command.verb, reply.ok, reply.error or "")
        return out

    def close(self) -> None:
        for feed in self.feeds.values():
            feed.close()
        for declared in self._declared:
            declared.undeclare()
        self.executor.shutdown(wait=False, cancel_futures=True)


def _loco_summary(status: LocoStatus) -> dict[str, Any]:
    """What the drive panel shows of the walking controller's state."""
    return {"fsm_id": status.fsm_id, "active": status.active, "walking": status.walking, "stepping": status.stepping,
            "commanded": list(status.commanded), "achieved": list(status.achieved),
            "velocity_limits": list(status.velocity_limits), "seq": status.seq}


def _yaw(quat_wxyz: tuple[float, ...]) -> float:
    """The heading (rotation about the world's z) of an orientation, rad."""
    w, x, y, z = quat_wxyz
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _bounded_texts(fields: dict[str, Any]) -> dict[str, Any]:
    """A message's fields with every string cut to a bounded length: they go to every browser."""
    return {name: bounded(value) if isinstance(value, str) else value for name, value in fields.items()}


def url_authority(host: str, port: int) -> str:
    """`host:port` as a URL writes it (an IPv6 address in brackets)."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def run(session: zenoh.Session, settings: VizSettings, stop: threading.Event) -> int:
    """Serve the page until `stop` is set; returns the exit code."""
    if settings.world is not None:
        try:
            check_robot_id(settings.world)
        except ValueError as exc:
            raise StartupError(f"--world / ZENSIM_VIZ_WORLD: the world's id: {exc}") from None
        if settings.urdf:
            raise StartupError("--urdf draws one robot from a local file, --world every robot of a world from its sim: "
                               "give one of them")
    service = VizService(session, settings, stop)
    try:
        sockets = tornado.netutil.bind_sockets(settings.port, address=settings.host)
    except OSError as exc:
        service.close()
        raise StartupError(f"cannot serve the page on {settings.host}:{settings.port} "
                           f"(--host / ZENSIM_VIZ_HOST, --port / ZENSIM_VIZ_PORT): {exc.strerror or exc}") from None
    port = sockets[0].getsockname()[1]
    try:
        guard = Guard(settings.host, settings.published_on, settings.allowed_hosts, settings.token,
                      always_token=bool(settings.zenoh.secure_dir), viewer_token=settings.viewer_token)
    except ValueError as exc:
        service.close()
        raise StartupError(str(exc)) from None
    guard.cookie_name = f"zensim_viz_token_{port}"
    server = tornado.httpserver.HTTPServer(make_app(service.hub, guard))
    server.add_sockets(sockets)
    logger.info("viz up: http://%s:%d/%s", settings.host, port,
                f" (every robot of the world {settings.world})" if settings.world else "")
    if guard.token is not None:
        # Once, like Jupyter: whoever can read this log can open the page. No other line carries the token
        # (requests are logged without their query, web.py log_request).
        why = "the network is secured" if settings.zenoh.secure_dir else "the page is reachable beyond loopback"
        logger.info("%s: open the page with its token: http://%s/?token=%s", why,
                    url_authority(guard.url_host, port), guard.token)
    if guard.viewer_token is not None:
        logger.info("pages that may watch, not drive: http://%s/?token=%s", url_authority(guard.url_host, port),
                    guard.viewer_token)
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
