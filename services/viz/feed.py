"""One robot as the viewer hears it: its newest states, targets and status, its services that are up,
its plot samples, and where its sliders write. The viewer holds one per robot it shows.

Reads (under `zensim/{robot}/`):
    state/joints (JointState), state/odom (Odometry): the pose, latest wins.
    state/targets (JointTargets): the ghost (the commanded pose the bridge holds), latest wins.
    state/sim (SimStatus): the status panel, latest wins.
    state/loco (LocoStatus): the walking controller's commanded and achieved velocity, latest wins.
    state/joints, cmd/motors, state/targets, state/applied (every sample): the plot panel (plots.py).
    alive/* (liveliness): which services are up; the sim coming or going is reported to `on_sim`.
Writes:
    cmd/joints (JointTargets): slider moves.
    cmd/velocity (VelocityCommand), cmd/remote (RemoteState): the page's keys and gamepad (drive.py paces them).
    alive/viz (liveliness token): a viewer shows this robot.

Zenoh callbacks only decode and store (or feed the plots); every bad sample is dropped and logged at a
bounded rate.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, Final

import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.wire import TypedPublisher, decode_input
from zensim.schemas import (
    AppliedCommand,
    Codec,
    DecodeError,
    JointState,
    JointTargets,
    Keys,
    LocoStatus,
    MotorCommand,
    Odometry,
    RemoteState,
    SimStatus,
    VelocityCommand,
    bounded,
    topics,
)
from zensim.schemas.bounds import STATE_CAP_BYTES
from zensim.schemas.keys import SERVICES

from . import plots
from .drive import DriveGate

logger = logging.getLogger(__name__)
bad_input = RateLimitedLog(logger)
"""Dropped samples, every robot's: bounded, any session may publish on these keys."""
alive_log = RateLimitedLog(logger)
"""The line per liveliness change: bounded, any session may declare tokens."""
MAX_ALIVE_NAMES: Final = 32
"""Distinct names shown as alive per robot; other tokens past this are ignored (counted). zensim's own
services (keys.SERVICES, six) always show."""
MAX_ALIVE_NAME_CHARS: Final = 32

CODECS: Final[dict[type, Codec[Any]]] = {t: Codec(t) for t in (JointState, Odometry, JointTargets, SimStatus,
                                                                 MotorCommand, AppliedCommand, LocoStatus)}
"""One decoder per type, shared by every robot's callbacks (msgspec decoders hold no state between calls)."""


class Latest:
    """The newest decoded sample of one key, with a counter that says when it changed.

    Zenoh callbacks run on their own threads; a single attribute store is atomic
    in CPython, so the reader sees either the old or the new (value, count).
    """

    def __init__(self) -> None:
        self.item: tuple[Any, int] = (None, 0)

    def set(self, value: Any) -> None:
        self.item = (value, self.item[1] + 1)


class RobotFeed:
    """One robot's subscriptions, slider publisher and token, declared at once and undeclared by `close`.

    Args:
        session: the viz's zenoh session.
        robot_id: the robot (its keys are `zensim/{robot_id}/...`).
        ghost: also keep the newest state/targets (the ghost).
        on_sim: called with True when the robot's `alive/sim` appears, False when it leaves (zenoh thread).
        label: put before this robot's liveliness log lines (a world's viewer names the robot).
    """

    def __init__(self, session: zenoh.Session, robot_id: str, ghost: bool, on_sim: Callable[[bool], None],
                 label: str = "") -> None:
        self.keys = keys = Keys(robot_id)
        self.on_sim = on_sim
        self.label = label
        self.joints = Latest()
        self.odom = Latest()
        self.targets = Latest()
        self.status = Latest()
        self.loco = Latest()
        self.drive_gate = DriveGate()
        """Paces this robot's cmd/velocity and cmd/remote puts, every page's together (the loop thread)."""
        self.alive: set[str] = set()
        self.alive_ignored = 0
        self.alive_logs: dict[str, RateLimitedLog] = {}
        self.alive_lock = threading.Lock()
        self.plot_feed = plots.PlotFeed()
        self.cmd_publisher = TypedPublisher.of(session, keys, topics.JOINT_TARGETS)
        self.velocity_publisher: TypedPublisher[VelocityCommand] = TypedPublisher.of(session, keys, topics.VELOCITY)
        self.remote_publisher: TypedPublisher[RemoteState] = TypedPublisher.of(session, keys, topics.REMOTE)
        self._declared = [
            session.declare_subscriber(keys.joints, self._store(self.joints, JointState)),
            session.declare_subscriber(keys.odom, self._store(self.odom, Odometry)),
            session.declare_subscriber(keys.sim_status, self._store(self.status, SimStatus)),
            session.declare_subscriber(keys.loco_status, self._store(self.loco, LocoStatus)),
            session.liveliness().declare_subscriber(keys.alive_any, self._on_alive, history=True),
            session.declare_subscriber(keys.joints, self._plot_sample(JointState)),
            session.declare_subscriber(keys.motors, self._plot_sample(MotorCommand)),
            session.declare_subscriber(keys.bridge_targets, self._plot_sample(JointTargets)),
            session.declare_subscriber(keys.applied, self._plot_sample(AppliedCommand)),
        ]
        if ghost:
            self._declared.append(session.declare_subscriber(keys.bridge_targets, self._store(self.targets, JointTargets)))
        self.token = session.liveliness().declare_token(keys.alive("viz"))

    # --- zenoh callbacks: decode, store, return ----------------------------------------
    def _store(self, slot: Latest, message_type: type) -> Any:
        codec = CODECS[message_type]

        def callback(sample: zenoh.Sample) -> None:
            try:
                slot.set(decode_input(sample, codec, STATE_CAP_BYTES))
            except DecodeError as exc:
                bad_input.warning("dropped a sample on %s: %s", bounded(str(sample.key_expr), 120), exc)

        return callback

    def _plot_sample(self, message_type: type) -> Any:
        """Every sample (not just the newest) feeds the plots; bad ones are dropped like the others."""
        codec, feed = CODECS[message_type], self.plot_feed

        def callback(sample: zenoh.Sample) -> None:
            try:
                message = decode_input(sample, codec, STATE_CAP_BYTES)
            except DecodeError as exc:
                bad_input.warning("dropped a sample on %s: %s", bounded(str(sample.key_expr), 120), exc)
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
            with self.alive_lock:
                self.alive_ignored += 1
            alive_log.warning("ignored a liveliness token with a %d-character name (%d ignored so far)",
                              len(service), self.alive_ignored)
            return
        up = sample.kind == zenoh.SampleKind.PUT
        with self.alive_lock:
            if up:
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
        line.info("%s%s %s", self.label, service, "is alive" if up else "left")
        if service == "sim":
            self.on_sim(up)

    def alive_names(self) -> set[str]:
        """The services up for this robot now (a copy)."""
        with self.alive_lock:
            return set(self.alive)

    def close(self) -> None:
        self.token.undeclare()
        for declared in self._declared:
            declared.undeclare()
        self.cmd_publisher.undeclare()
        self.velocity_publisher.undeclare()
        self.remote_publisher.undeclare()
