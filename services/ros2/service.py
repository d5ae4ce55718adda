"""`zensim ros2`'s wiring: zensim's keys on one side, ROS 2 topics on rmw_zenoh's keys and on DDS on the other.

Reads:
    {robot}/state/joints, state/odom, state/imu   -> JointState + Clock, Odometry + TF, Imu on ROS 2
    {robot}/state/sim          SimStatus: a new `run_id` is a restarted sim (perhaps another robot):
                               learn it again and publish robot_description anew
    {robot}/info/robot, info/urdf   the robot and its URDF
    {world}/world/info         with --world: the world's robots, each served as above under its own keys
    {robot}/alive/loco         whether a walking controller is up: without one a /cmd_vel Twist is refused
    {robot}/state/loco         LocoStatus: whether it walks (a Twist to a standing controller is logged)
    ROS 2: the forward command, trajectory and /cmd_vel topics, on every transport
Writes:
    {robot}/cmd/joints         JointTargets, one per accepted joint command (the bridge clamps and slew-limits it)
    {robot}/cmd/velocity       VelocityCommand, one per accepted /cmd_vel Twist (for `zensim loco`)
    {robot}/state/ros2         Ros2Status at status_rate_hz
    {robot}/alive/ros2         liveliness token, once the robot is known
    ROS 2: robot_description (latched), joint_states, tf, odom, imu, clock

With --world, one process serves every robot of a world: one Face (a Gateway and its alive/ros2 token)
per robot, each its own rmw_zenoh node in the namespace of its id with its frames prefixed, all on one
DDS participant; the first robot's face alone publishes /clock (the world's time is one).

Each ROS 2 message is built once (messages.py: CDR bytes) and handed to every transport. Outputs go
out on zenoh's callback threads as each state arrives (taken in as `zensim ros1` takes it:
common/ros_state.py); commands come in on zenoh's callback threads
(rmw_zenoh) and on the DDS reader thread, are checked whole (mapping.py, common/ros_rules.py) and go to
zenoh at once. A flood of commands is shed beyond COMMAND_RATE_HZ before it is decoded, and counted.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, Final

import msgspec
import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.robot_info import description_bytes, fetch_robot
from zensim.common.ros_rules import InputError, P3dOdometry, RobotJoints, xyzw
from zensim.common.ros_state import StateIntake
from zensim.common.session import StartupError
from zensim.common.token_bucket import TokenBucket
from zensim.common.wire import Refusals, TypedPublisher, error_text, read_payload
from zensim.schemas import Codec, DecodeError, Imu, JointState, Keys, LocoStatus, Odometry, Ros2Status, WorldInfo, topics
from zensim.schemas.bounds import INFO_CAP_BYTES, MIN_CAP_BYTES

from . import messages as msg
from .cdr import CdrError
from .mapping import NO_WALKING, Ros2Names, forward_command, namespace_of, trajectory_goal, velocity_command
from .rmw_zenoh import Qos
from .settings import Ros2Settings
from .transport import Publisher, Transport

logger = logging.getLogger("zensim.ros2")

INPUT_CAP_BYTES: Final = 64 * 1024
"""Largest ROS 2 command accepted, bytes (a G1 trajectory of a few dozen points fits)."""
COMMAND_RATE_HZ: Final = 200.0
"""Commands per second the gateway decodes and passes on, over all command topics; more are refused as a
flood (a controller at 100 Hz fits twice). The bridge keeps only the newest command anyway."""
COMMAND_BURST: Final = 50
"""Commands that may come at once before the rate applies."""
STATE_QOS: Final = Qos(depth=10)
LATCHED_QOS: Final = Qos(transient_local=True, depth=1)


def names_of(settings: Ros2Settings) -> Ros2Names:
    s = settings
    return Ros2Names.of(s.namespace, robot_description=s.robot_description_topic, joint_states=s.joint_states_topic,
                        tf=s.tf_topic, odom=s.odom_topic, imu=s.imu_topic, clock=s.clock_topic,
                        forward_command=s.forward_command_topic, trajectory=s.trajectory_topic,
                        cmd_vel=s.cmd_vel_topic)


class Counters:
    """What the status reports; updated under the gateway's lock."""

    def __init__(self) -> None:
        self.commands_received = 0
        self.commands_forwarded = 0
        self.last_command: float | None = None


class Outputs:
    """One topic's publishers, one per transport."""

    def __init__(self, transports: list[Transport], topic: str, ros_type: msg.RosType, qos: Qos) -> None:
        self._publishers: list[Publisher] = [t.publisher(topic, ros_type, qos) for t in transports]

    def put(self, payload: bytes) -> None:
        for publisher in self._publishers:
            publisher.put(payload)


class Gateway:
    """The running face (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, settings: Ros2Settings, names: Ros2Names,
                 transports: list[Transport], publish_clock: bool = True) -> None:
        self._session = session
        self._keys = keys
        self._settings = settings
        self.names = names
        self.transports = transports
        self._lock = threading.Lock()
        self.counters = Counters()
        self.refusals = Refusals(logger, "ROS 2 message")
        self._flood = TokenBucket(COMMAND_RATE_HZ, COMMAND_BURST)
        self.intake = StateIntake(logger, settings.state_rate_hz, joints=self._on_joints, odom=self._on_odom,
                                  imu=self._on_imu)
        """state/*, and the robot: `intake.sim_run.restarted` is set when it must be learned again."""
        self._loco_status_codec = Codec(LocoStatus)
        self._loco_up = threading.Event()
        """A walking controller's alive/loco token is up for this robot: /cmd_vel goes to it."""
        self._loco_walking: bool | None = None
        """Whether its newest state/loco says it walks (None: none heard yet)."""
        self._walk_log = RateLimitedLog(logger, 10.0)
        # ROS 2 side: outputs, then inputs.
        self._description = Outputs(transports, names.robot_description, msg.STRING, LATCHED_QOS)
        self._joint_states = Outputs(transports, names.joint_states, msg.JOINT_STATE, STATE_QOS)
        # The robots of a world share one clock: only one face publishes it.
        self._clock = Outputs(transports if publish_clock else [], names.clock, msg.CLOCK, STATE_QOS)
        self._tf = Outputs(transports, names.tf, msg.TF_MESSAGE, Qos(depth=100))  # tf2's listener depth
        self._odom = Outputs(transports, names.odom, msg.ODOMETRY, STATE_QOS)
        self._imu = Outputs(transports, names.imu, msg.IMU, STATE_QOS)
        for transport in transports:
            for topic, ros_type, handle in (
                    (names.forward_command, msg.FLOAT64_MULTI_ARRAY, self._on_forward_command),
                    (names.trajectory, msg.JOINT_TRAJECTORY, self._on_trajectory),
                    (names.cmd_vel, msg.TWIST, self._on_cmd_vel)):
                transport.subscribe(topic, ros_type, self._command(topic, handle), self._bad(topic))
        # Zenoh side.
        self._targets = TypedPublisher.of(session, keys, topics.JOINT_TARGETS)
        self._velocity = TypedPublisher.of(session, keys, topics.VELOCITY)
        self._status = TypedPublisher.of(session, keys, topics.ROS2_STATUS)
        self._subscribers: list[zenoh.Subscriber] = []
        # Declared before the first Twist can come (history: a controller already up counts at once).
        self._loco_alive = session.liveliness().declare_subscriber(keys.alive("loco"), self._on_loco_alive,
                                                                   history=True)
        self._loco_status = session.declare_subscriber(keys.loco_status, self._on_loco_status)

    def start(self, robot: RobotJoints, urdf: str) -> None:
        """Take the robot, publish robot_description, then start the flow of states."""
        self.adopt(robot, urdf)
        self._subscribers = self.intake.subscribe(self._session, self._keys)

    def adopt(self, robot: RobotJoints, urdf: str) -> None:
        """Take `robot` (at start and after a sim restart) and publish its URDF on robot_description."""
        self.intake.adopt(robot)
        self._description.put(msg.string(urdf))
        logger.info("%s published: %d characters", self.names.robot_description, len(urdf))

    # --- zensim -> ROS 2 (zenoh threads; the intake decodes, thins and checks) ---------------------

    def _on_joints(self, state: JointState, robot: RobotJoints) -> None:
        self._clock.put(msg.clock(state.sim_time_s))
        self._joint_states.put(msg.joint_state(state.sim_time_s, robot.names, state.q, state.dq, state.tau))

    def _on_odom(self, odom: Odometry) -> None:
        p3d = P3dOdometry.of(odom)
        world, base = self._settings.world_frame, self._settings.base_frame
        self._odom.put(msg.odometry(odom.sim_time_s, world, base,
                                    msg.Pose(p3d.position, p3d.orientation_xyzw, p3d.linear, p3d.angular)))
        self._tf.put(msg.tf_message(odom.sim_time_s, [msg.Transform(world, base, p3d.position, p3d.orientation_xyzw)]))

    def _on_imu(self, imu: Imu) -> None:
        self._imu.put(msg.imu(imu.sim_time_s, self._settings.imu_frame, xyzw(imu.quat_wxyz), imu.gyro, imu.accel))

    def _on_loco_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            logger.info("a walking controller is up: %s goes to %s", self.names.cmd_vel, self._keys.velocity)
            self._loco_up.set()
        else:
            logger.info("the walking controller is gone: %s is refused until one runs", self.names.cmd_vel)
            self._loco_up.clear()
            self._loco_walking = None

    def _on_loco_status(self, sample: zenoh.Sample) -> None:
        status = self.intake.decode(sample, self._loco_status_codec, MIN_CAP_BYTES)
        if status is not None:
            self._loco_walking = status.walking

    # --- ROS 2 -> zensim (zenoh threads, the DDS thread) -------------------------------------------

    def _bad(self, topic: str) -> Callable[[str], None]:
        def refuse(reason: str) -> None:
            with self._lock:
                self.counters.commands_received += 1
            self.refusals.refuse(topic, reason)
        return refuse

    def _command(self, topic: str, handle: Callable[[RobotJoints, bytes], None]) -> Callable[[bytes], None]:
        def on_message(data: bytes) -> None:
            with self._lock:
                self.counters.commands_received += 1
                robot = self.intake.robot
            if not self._flood.take():
                self.refusals.refuse(topic, f"more than {COMMAND_RATE_HZ:g} commands a second: shed")
                return
            try:
                if robot is None:
                    raise InputError("the robot is not known yet")
                handle(robot, data)
            except (InputError, CdrError) as exc:
                self.refusals.refuse(topic, str(exc))
        return on_message

    def _forward(self, targets: Any) -> None:
        self._targets.put(targets)
        with self._lock:
            self.counters.commands_forwarded += 1
            self.counters.last_command = time.monotonic()

    def _on_forward_command(self, robot: RobotJoints, data: bytes) -> None:
        self._forward(forward_command(robot, msg.read_float64_multi_array(data)))

    def _on_trajectory(self, robot: RobotJoints, data: bytes) -> None:
        names, points = msg.read_joint_trajectory(data)
        self._forward(trajectory_goal(robot, names, points))

    def _on_cmd_vel(self, robot: RobotJoints, data: bytes) -> None:
        command = velocity_command(*msg.read_twist(data), self._settings.cmd_vel_timeout_s)
        if not self._loco_up.is_set():
            raise InputError(NO_WALKING)
        if self._loco_walking is False:
            # Passed on all the same: the controller keeps the newest and walks on it once asked to.
            self._walk_log.warning("the walking controller is up but not walking: %s moves nothing until it walks "
                                   "(ctl/loco {\"verb\": \"walk\"}, or `zensim loco --start walk`)", self.names.cmd_vel)
        self._velocity.put(command)
        with self._lock:
            self.counters.commands_forwarded += 1
            self.counters.last_command = time.monotonic()

    # --- status ------------------------------------------------------------------------------------

    def publish_status(self, seq: int) -> None:
        rate_hz = self.intake.published_rate_hz()
        published, sim_time_s = self.intake.published()
        with self._lock:
            c = self.counters
            status = Ros2Status(
                seq=seq, transports=tuple(t.name for t in self.transports), domain_id=self._settings.domain_id,
                joint_states_published=published, joint_states_rate_hz=rate_hz,
                sim_time_s=sim_time_s, commands_received=c.commands_received,
                commands_forwarded=c.commands_forwarded, rejected=self.refusals.count,
                last_error=self.refusals.last_error,
                command_age_s=None if c.last_command is None else time.monotonic() - c.last_command,
            )
        self._status.put(status)

    def close(self) -> None:
        for subscriber in (*self._subscribers, self._loco_status):
            subscriber.undeclare()
        self._loco_alive.undeclare()
        for transport in self.transports:
            if transport.name != "dds":  # shared by every robot of a world: run() closes it
                transport.close()
        self._targets.undeclare()
        self._velocity.undeclare()
        self._status.undeclare()


def read_urdf(session: zenoh.Session, keys: Keys, timeout_s: float) -> str:
    """The sim's URDF (info/urdf), size-capped; LookupError when there is none to read."""
    return description_bytes(session, keys.urdf, timeout_s).decode("utf-8", errors="replace")


def world_robots(session: zenoh.Session, world: str, timeout_s: float, stop: threading.Event) -> list[str] | None:
    """The robot ids a world's world/info lists, asked until it answers (None: stopped first)."""
    key = Keys(world).world_info
    codec = Codec(WorldInfo)
    waiting = RateLimitedLog(logger, 10.0)
    while not stop.is_set():
        for reply in session.get(key, timeout=timeout_s):
            if reply.ok is None:
                waiting.warning("%s: %s", key, error_text(reply.err))
                continue
            try:
                info = codec.decode(*read_payload(reply.ok, INFO_CAP_BYTES))
            except DecodeError as exc:
                raise StartupError(f"{key} answered something that is not a WorldInfo: {exc}") from None
            return [robot.robot for robot in info.robots]
        waiting.info("no world %r answers on %s yet (zensim sim --world): asking again", world, key)
        stop.wait(timeout_s)
    return None


def robot_settings(settings: Ros2Settings, robot_id: str) -> Ros2Settings:
    """One robot of a world as a face of its own: its id, its namespace and node, its frames prefixed."""
    ros_name = robot_id.replace("-", "_")
    return msgspec.structs.replace(
        settings, robot_id=robot_id, namespace=f"{settings.namespace.strip('/')}/{ros_name}".strip("/"),
        node_name=f"{settings.node_name or 'zensim'}_{ros_name}",
        base_frame=f"{ros_name}/{settings.base_frame}", imu_frame=f"{ros_name}/{settings.imu_frame}")


class Face:
    """One robot's face: its gateway and its liveliness token."""

    def __init__(self, session: zenoh.Session, settings: Ros2Settings, transports: list[Transport],
                 publish_clock: bool) -> None:
        self.settings = settings
        self.keys = Keys(settings.robot_id)
        try:
            names = names_of(settings)
        except ValueError as exc:
            raise StartupError(f"robot {settings.robot_id!r}: {exc}") from None
        self.gateway = Gateway(session, self.keys, settings, names, transports, publish_clock)
        self.token: zenoh.LivelinessToken | None = None
        self.seq = 0

    def start(self, session: zenoh.Session, stop: threading.Event) -> bool:
        """Learn the robot and start the flow (False: stopped first)."""
        robot = fetch_robot(session, self.keys, self.settings.info_timeout_s, stop, RobotJoints.from_info, logger)
        if robot is None:
            return False
        try:
            urdf = read_urdf(session, self.keys, self.settings.info_timeout_s)
        except LookupError as exc:
            raise StartupError(f"cannot read the robot's URDF: {exc}") from None
        self.gateway.start(robot, urdf)
        self.token = session.liveliness().declare_token(self.keys.alive("ros2"))
        logger.info("ros2 face up: node %s in %s, domain %d on %s; %s, %s", node_name_of(self.settings),
                    self.gateway.names.namespace, self.settings.domain_id, self.settings.transports,
                    self.gateway.names.joint_states, self.gateway.names.forward_command)
        return True

    def tick(self, session: zenoh.Session, stop: threading.Event) -> bool:
        """Learn a restarted sim's robot again, then publish the status (False: stopped while learning)."""
        gateway = self.gateway
        if gateway.intake.sim_run.restarted.is_set():
            robot = fetch_robot(session, self.keys, self.settings.info_timeout_s, stop, RobotJoints.from_info, logger)
            if robot is None:
                return False
            try:
                gateway.adopt(robot, read_urdf(session, self.keys, self.settings.info_timeout_s))
            except LookupError as exc:
                logger.warning("the restarted sim's URDF: %s; asking again", exc)
        gateway.publish_status(self.seq)
        self.seq += 1
        return True

    def close(self) -> None:
        if self.token is not None:
            self.token.undeclare()
        self.gateway.close()
        c = self.gateway.counters
        logger.info("%s: %d ROS 2 commands read, %d forwarded, %d rejected; %d joint states published",
                    self.settings.robot_id, c.commands_received, c.commands_forwarded, self.gateway.refusals.count,
                    self.gateway.intake.published()[0])


def node_name_of(settings: Ros2Settings) -> str:
    return settings.node_name or f"zensim_{settings.robot_id.replace('-', '_')}"


def open_dds(settings: Ros2Settings) -> Transport | None:
    """The DDS transport when the settings name it (one participant for every robot: it loads Cyclone DDS)."""
    if "dds" not in settings.transports.split(","):
        return None
    try:
        from .dds_edge import DdsEdge
    except ImportError as exc:
        raise StartupError(f"the DDS transport needs the Cyclone DDS binding ({exc}): install the `unitree` "
                           "extra (docs/unitree.md) or run with --transports zenoh") from None
    return DdsEdge(settings.domain_id, settings.dds_interface, INPUT_CAP_BYTES)


def open_zenoh(session: zenoh.Session, settings: Ros2Settings, ids: Iterator[int]) -> Transport | None:
    """One robot's node on rmw_zenoh's keys, when the settings name the Zenoh transport."""
    if "zenoh" not in settings.transports.split(","):
        return None
    from .zenoh_edge import ZenohEdge

    return ZenohEdge(session, settings.domain_id, namespace_of(settings.namespace), node_name_of(settings),
                     INPUT_CAP_BYTES, settings.humble, ids)


def run(session: zenoh.Session, settings: Ros2Settings, stop: threading.Event) -> int:
    """Learn the robot (or every robot of the world), join the ROS 2 graph on each transport, map until
    `stop` is set.

    Returns:
        The process exit code.
    """
    if settings.world:
        logger.info("asking world %r for its robots", settings.world)
        robot_ids = world_robots(session, settings.world, settings.info_timeout_s, stop)
        if robot_ids is None:
            return 0
        per_robot = [robot_settings(settings, robot_id) for robot_id in robot_ids]
        logger.info("world %r: serving %s", settings.world, ", ".join(robot_ids))
    else:
        per_robot = [settings]
    dds = open_dds(settings)
    ids = itertools.count(0)
    faces: list[Face] = []
    try:
        for i, robot in enumerate(per_robot):
            transports = [t for t in (open_zenoh(session, robot, ids), dds) if t is not None]
            faces.append(Face(session, robot, transports, publish_clock=i == 0))  # one /clock: the world's
        for face in faces:
            logger.info("asking the sim on %s", face.keys.robot_info)
            if not face.start(session, stop):
                return 0
        period_s = 1.0 / settings.status_rate_hz
        while not stop.wait(period_s):
            if not all(face.tick(session, stop) for face in faces):
                break
    finally:
        for face in faces:
            face.close()
        if dds is not None:
            dds.close()
    return 0
