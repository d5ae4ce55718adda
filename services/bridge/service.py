"""The bridge's zenoh wiring: joint targets in, motor commands out at a fixed rate.

Reads:
    {robot}/cmd/joints          JointTargets (msgpack or JSON), partial, merged into the held targets
    {robot}/cmd/joint/{joint}   a bare number (JSON, plain text or msgpack) for one joint
    {robot}/state/sim           SimStatus: a new `episode` -> hold the default pose of `mode`;
                                with a new `run_id` the sim restarted -> learn the robot again
    {robot}/info/robot          RobotInfo, queried at start and after a sim restart
Writes:
    {robot}/cmd/motors          MotorCommand (q, dq; kp, kd only with local robot files) at rate_hz
    {robot}/state/targets       JointTargets, every joint, the commanded q, at targets_rate_hz
    {robot}/report/bridge       BridgeReport per rejected or clamped input
    {robot}/alive/bridge        liveliness token, once the robot is known

The rules (validation, clamping, slew limit, resets) live in targets.py.
"""

from __future__ import annotations

import logging
import threading
import time

import zenoh

from zensim.common.follow import SimFollower
from zensim.common.logs import RateLimitedLog
from zensim.common.robot_info import fetch_robot
from zensim.common.session import StartupError
from zensim.common.pacing import Pacer
from zensim.common.wire import TypedPublisher, decode_input, read_payload
from zensim.schemas import topics
from zensim.schemas import (
    BridgeReport,
    Codec,
    DecodeError,
    JointTargets,
    Keys,
    MotorCommand,
    SimStatus,
    bounded,
    decode_scalar,
)
from zensim.schemas.bounds import SCALAR_CAP_BYTES, vector_cap_bytes

from .settings import BridgeSettings
from .targets import HeldTargets, RobotModel, UnusableRobotInfo, Verdict, carries_targets

logger = logging.getLogger("zensim.bridge")

class Bridge:
    """The running bridge: callbacks merge inputs into the held targets, `tick` publishes.

    Callbacks run on zenoh's threads. Each decodes, validates and merges its input into
    the held targets under one lock and returns: the held targets are the latest value, so
    nothing ever queues behind old samples, and two partial inputs that arrive between two
    ticks (two sliders) are both kept, which a keep-the-last-sample buffer would not do.
    """

    def __init__(self, session: zenoh.Session, keys: Keys, model: RobotModel, settings: BridgeSettings,
                 from_files: bool = False) -> None:
        self._keys = keys
        self._slew_rad_s = settings.slew_rad_s
        self._from_files = from_files
        self._lock = threading.Lock()
        self._rejected_total = 0
        self._clamped_total = 0
        self._targets_codec = Codec(topics.JOINT_TARGETS.message_type())
        self._reject_log = RateLimitedLog(logger, 1.0)
        self._clamp_log = RateLimitedLog(logger, 1.0)
        self._status_log = RateLimitedLog(logger, 5.0)
        # The bridge's commands are what keeps the robot standing: they go out at real-time priority,
        # ahead of whatever else a flooding client pushes through the same router.
        self._motors = TypedPublisher.of(session, keys, topics.MOTORS, priority=zenoh.Priority.REAL_TIME)
        self._targets = TypedPublisher.of(session, keys, topics.BRIDGE_TARGETS)
        self._reports = TypedPublisher.of(session, keys, topics.BRIDGE_REPORT)
        # Sized from the robot, like the sim's caps; the sim's own statuses are far smaller.
        self._cap_bytes = vector_cap_bytes(model.joint_names)
        self._hold(model)
        # A robot from local files is the user's, not the sim's: a restarted sim does not change it.
        self.sim = SimFollower(session, keys, self._cap_bytes, self._on_status, "" if from_files else model.run_id)
        """state/sim: `sim.restarted` is set when a new sim run's robot must be learned again."""
        self._subscribers = [
            session.declare_subscriber(keys.joint_targets, self._on_targets),
            session.declare_subscriber(keys.joint_target_any, self._on_joint),
        ]

    def adopt(self, model: RobotModel) -> None:
        """Take `model` as the robot after a sim restart: hold its default pose, follow the new run."""
        self._hold(model)
        self.sim.adopt("" if self._from_files else model.run_id)

    def _hold(self, model: RobotModel) -> None:
        """Hold `model`'s default pose with its gains."""
        with self._lock:
            self._held = HeldTargets(model, self._slew_rad_s)
            self._gains: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
                mode: (tuple(model.kp[mode].tolist()), tuple(model.kd[mode].tolist())) for mode in model.kp
            }

    # --- inputs (zenoh threads) -------------------------------------------

    def _on_targets(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            message = decode_input(sample, self._targets_codec, self._cap_bytes)
        except DecodeError as exc:
            self._report(key, Verdict(False, str(exc)))
            return
        self._apply(key, message)

    def _on_joint(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            joint = self._keys.joint_from_target_key(key)
            value = decode_scalar(*read_payload(sample, SCALAR_CAP_BYTES))
        except (DecodeError, ValueError) as exc:
            self._report(key, Verdict(False, str(exc)))
            return
        self._apply(key, JointTargets(names=(joint,), q=(value,)))

    def _apply(self, key: str, targets: JointTargets) -> None:
        with self._lock:
            verdict = self._held.apply(targets)
        self._report(key, verdict)

    def _on_status(self, status: SimStatus) -> None:
        """A status of the known sim run (SimFollower): a new episode holds the mode's default pose."""
        try:
            with self._lock:
                if status.episode == self._held.episode:
                    return  # the common case: nothing happened
                self._held.follow_sim(status.episode, status.mode)
        except UnusableRobotInfo as exc:
            self._status_log.warning("%s; keeping the current targets", exc)
            return
        logger.info("new sim episode (mode %s, resets %d): holding the default pose", status.mode, status.resets)

    def _report(self, key: str, verdict: Verdict) -> None:
        """Count, log (rate-limited) and publish the verdict on an input that was rejected or clamped."""
        if verdict.accepted and not verdict.clamped:
            return
        # Everything in a report may echo the input: cut it to a bounded size.
        key = bounded(key, 200)
        error = None if verdict.error is None else bounded(verdict.error)
        clamped = tuple(bounded(name, 64) for name in verdict.clamped)
        with self._lock:
            if verdict.accepted:
                self._clamped_total += 1
            else:
                self._rejected_total += 1
            rejected_total, clamped_total = self._rejected_total, self._clamped_total
        if verdict.accepted:
            self._clamp_log.warning("clamped to the joint limits on %s: %s", key, ", ".join(clamped))
        else:
            self._reject_log.warning("rejected input on %s: %s", key, error)
        self._reports.put(BridgeReport(
            key=key, accepted=verdict.accepted, error=error, clamped=clamped,
            rejected_total=rejected_total, clamped_total=clamped_total,
        ))

    # --- outputs (the loop's thread) --------------------------------------

    def tick(self, dt_s: float, publish_targets: bool) -> None:
        """Advance the slew limit by `dt_s` and publish the motor command (and the held targets)."""
        with self._lock:
            q = tuple(self._held.step(dt_s).tolist())
            dq = tuple(self._held.target_dq.tolist())
            # Gains the sim already has are not sent back to it: an absent kp/kd means "the sim's
            # configured gains". Only gains the user gave the bridge itself (--control) are sent.
            kp, kd = self._gains[self._held.mode] if self._from_files else (None, None)
        self._motors.put(MotorCommand(q=q, dq=dq, kp=kp, kd=kd))
        if publish_targets:
            self._targets.put(JointTargets(names=self._held.joint_names, q=q))

    def close(self) -> None:
        self.sim.close()
        for subscriber in self._subscribers:
            subscriber.undeclare()
        for publisher in (self._motors, self._targets, self._reports):
            publisher.undeclare()


def run(session: zenoh.Session, settings: BridgeSettings, stop: threading.Event) -> int:
    """Learn the robot, then publish motor commands at `rate_hz` until `stop` is set.

    Returns:
        The process exit code.
    """
    keys = Keys(settings.robot_id)
    model: RobotModel | None
    if settings.robot or settings.urdf:
        try:
            model = RobotModel.from_files(settings.robot, settings.urdf, settings.control)
        except (OSError, ValueError) as exc:
            raise StartupError(f"cannot load the robot files (--robot / --urdf / --control): {bounded(str(exc), 400)}") from None
        logger.info("robot from local files: %d joints", len(model.joint_names))
    else:
        logger.info("asking the sim on %s", keys.robot_info)
        model = fetch_robot(session, keys, settings.info_timeout_s, stop, RobotModel.from_info, logger)
        if model is None:
            return 0
        logger.info("robot from the sim: %d joints, mode %s", len(model.joint_names), model.mode)

    bridge = Bridge(session, keys, model, settings, from_files=bool(settings.robot or settings.urdf))
    token = session.liveliness().declare_token(keys.alive("bridge"))
    # The shared pacer keeps an absolute schedule (no drift) and drops debt after a stall.
    pacer = Pacer(1.0 / settings.rate_hz, rtf=1.0)
    logger.info("bridge up: %s at %.0f Hz, slew limit %s", keys.motors, settings.rate_hz,
                f"{settings.slew_rad_s} rad/s" if settings.slew_rad_s else "off")
    ticks = 0
    last = time.monotonic() - 1.0 / settings.rate_hz
    try:
        while not stop.is_set():
            if bridge.sim.restarted.is_set():
                model = fetch_robot(session, keys, settings.info_timeout_s, stop, RobotModel.from_info, logger)
                if model is None:
                    break
                bridge.adopt(model)
                logger.info("robot from the restarted sim: %d joints, mode %s", len(model.joint_names), model.mode)
            now = time.monotonic()
            bridge.tick(now - last, carries_targets(ticks, settings.rate_hz, settings.targets_rate_hz))
            last = now
            ticks += 1
            pacer.stepped()
            pacer.wait()
    finally:
        token.undeclare()
        bridge.close()
    logger.info("%d ticks, %d schedule restarts after stalls", ticks, pacer.resyncs)
    return 0
