"""zensim's state as both ROS gateways (`zensim ros1`, `zensim ros2`) take it in; each builds its own ROS messages.

Reads (one robot's keys):
    {robot}/state/joints, state/odom, state/imu   each handed to the gateway's publisher for it
    {robot}/state/sim          SimStatus: a new `run_id` sets `sim_run.restarted`; the others of the known run
                               are handed to the gateway

Every sample is size-capped (from the robot's joints) and decoded by the one input path (wire.py); a bad one
is logged at a bounded rate and dropped. Each state is thinned to the ROS rate on sim time (ros_rules.RateGate,
one gate per key), and a JointState whose joint count is not the robot's is not published (the sim restarted
with another robot: its JointStates are dropped until the gateway learns it). The JointStates published are
counted here, for the gateway's status.

The intake holds the robot the gateway serves (learned from info/robot): the states are checked against it,
and the gateway's commands read it from `robot`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Final, TypeVar

import zenoh

from zensim.schemas import Codec, DecodeError, Imu, JointState, Keys, Message, Odometry, SimStatus
from zensim.schemas.bounds import vector_cap_bytes

from .follow import SimRun
from .logs import RateLimitedLog
from .ros_rules import RateGate, RobotJoints
from .wire import decode_input

M = TypeVar("M", bound=Message)

BAD_STATE_LOG_PERIOD_S: Final = 5.0
"""At most one line per this many seconds about bad state samples (a flood of them is one line)."""


class StateIntake:
    """One robot's state/* into a ROS gateway (see the module docstring); callbacks run on zenoh's threads.

    Args:
        logger: the gateway's logger, for the bad samples.
        rate_hz: at most this many of each state a second of sim time go on to ROS.
        joints: publishes a JointState on ROS, with the robot whose joints it has.
        odom: publishes an Odometry on ROS.
        imu: publishes an Imu on ROS.
        sim_status: called with each SimStatus of the followed sim run, once the robot is known.
    """

    def __init__(self, logger: logging.Logger, rate_hz: float, *, joints: Callable[[JointState, RobotJoints], None],
                 odom: Callable[[Odometry], None], imu: Callable[[Imu], None],
                 sim_status: Callable[[SimStatus], None] = lambda status: None) -> None:
        self.sim_run = SimRun()
        """state/sim's run: `sim_run.restarted` is set when another sim run's robot must be learned again."""
        self._log = RateLimitedLog(logger, BAD_STATE_LOG_PERIOD_S)
        self._publish_joints = joints
        self._publish_odom = odom
        self._publish_imu = imu
        self._on_status = sim_status
        self._codecs: dict[type, Codec[Any]] = {t: Codec(t) for t in (JointState, Odometry, Imu, SimStatus)}
        self._gates = {t: RateGate(rate_hz) for t in (JointState, Odometry, Imu)}
        self._lock = threading.Lock()
        self._robot: RobotJoints | None = None
        self._cap_bytes = 0
        self._published = 0
        self._sim_time_s = 0.0
        self._rate_since = (0, time.monotonic())

    @property
    def robot(self) -> RobotJoints | None:
        """The robot the gateway serves (None: not learned yet)."""
        return self._robot

    def adopt(self, robot: RobotJoints) -> None:
        """Serve `robot` (at start and after a sim restart): the caps and checks follow it, and its sim run."""
        with self._lock:
            self._robot = robot
            self._cap_bytes = vector_cap_bytes(robot.names)
            self.sim_run.adopt(robot.run_id)

    def subscribe(self, session: zenoh.Session, keys: Keys) -> list[zenoh.Subscriber]:
        """Start the flow of states (after the first `adopt`); the caller undeclares what it returns."""
        return [
            session.declare_subscriber(keys.joints, self._on_joints),
            session.declare_subscriber(keys.odom, self._on_odom),
            session.declare_subscriber(keys.imu, self._on_imu),
            session.declare_subscriber(keys.sim_status, self._on_sim_status),
        ]

    def decode(self, sample: zenoh.Sample, codec: Codec[M], cap_bytes: int) -> M | None:
        """`sample` decoded, or None: a bad one is logged (at a bounded rate, with the gateway's other bad states)."""
        try:
            return decode_input(sample, codec, cap_bytes)
        except DecodeError as exc:
            self._log.warning("ignoring a bad %s on %s: %s", codec.message_type.__name__, sample.key_expr, exc)
            return None

    def published(self) -> tuple[int, float]:
        """JointStates published so far, and the sim time of the newest, s."""
        with self._lock:
            return self._published, self._sim_time_s

    def published_rate_hz(self) -> float:
        """JointStates published a second (wall clock) since the previous call (or since the intake began)."""
        now = time.monotonic()
        with self._lock:
            count = self._published
            (last_count, last_time), self._rate_since = self._rate_since, (count, now)
        return (count - last_count) / max(now - last_time, 1e-9)

    def _state(self, sample: zenoh.Sample, message_type: type) -> Any:
        return self.decode(sample, self._codecs[message_type], self._cap_bytes)

    def _on_joints(self, sample: zenoh.Sample) -> None:
        state = self._state(sample, JointState)
        robot = self._robot
        if state is None or robot is None or not self._gates[JointState].due(state.sim_time_s):
            return
        if len(state.q) != len(robot.names):
            self._log.warning("state/joints has %d positions for %d joints: not published",
                              len(state.q), len(robot.names))
            return
        self._publish_joints(state, robot)
        with self._lock:
            self._published += 1
            self._sim_time_s = state.sim_time_s

    def _on_odom(self, sample: zenoh.Sample) -> None:
        odom = self._state(sample, Odometry)
        if odom is not None and self._gates[Odometry].due(odom.sim_time_s):
            self._publish_odom(odom)

    def _on_imu(self, sample: zenoh.Sample) -> None:
        imu = self._state(sample, Imu)
        if imu is not None and self._gates[Imu].due(imu.sim_time_s):
            self._publish_imu(imu)

    def _on_sim_status(self, sample: zenoh.Sample) -> None:
        status = self._state(sample, SimStatus)
        if status is not None and self._robot is not None and self.sim_run.follows(status):
            self._on_status(status)
