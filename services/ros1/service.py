"""The ROS 1 gateway's wiring: ROS topics and parameters on one side, zensim's Zenoh keys on the other.

Reads:
    {robot}/state/joints, state/odom, state/imu   -> JointState, Odometry + TF, Imu, Clock on ROS
    {robot}/state/sim          SimStatus: a new `run_id` is a restarted sim (perhaps another robot):
                               learn it again and set robot_description anew; a new `episode` is logged
    {robot}/info/robot, info/urdf, info/mesh/{path}   the robot, its URDF and meshes
    ROS: the per-joint Float64 command topics and the GUI's JointState topic; /cmd_vel (Twist)
Writes:
    {robot}/cmd/joint/{joint}  one per accepted Float64 (the bridge clamps and slew-limits it)
    {robot}/cmd/joints         JointTargets, one per accepted GUI message that moved a slider
    {robot}/cmd/velocity       VelocityCommand, one per accepted /cmd_vel Twist (for `zensim loco`)
    {robot}/state/ros1         Ros1Status at status_rate_hz
    {robot}/alive/ros1         liveliness token, once the robot is known
    ROS: JointState, Odometry, Imu, TF, Clock; params robot_description and use_sim_time

Outputs go out on zenoh's callback threads as each state arrives; inputs come in on rospy's
threads and go to zenoh at once. Nothing queues in the gateway: rospy's publishers and subscribers
keep a short queue each and drop the oldest, so a flood on one side never stalls the other.
The rules (names, checks, the odometry's frames, mesh URLs) live in mapping.py; the state's intake (size
cap, rate, joint count), shared with `zensim ros2`, in common/ros_state.py.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import xmlrpc.client
from typing import Any

import msgspec
import rospy
import zenoh
from geometry_msgs.msg import TransformStamped, Twist
from nav_msgs.msg import Odometry as RosOdometry
from rosgraph_msgs.msg import Clock
from rospy.impl.registration import Registration, get_registration_listeners, get_topic_manager
from sensor_msgs.msg import Imu as RosImu
from sensor_msgs.msg import JointState as RosJointState
from std_msgs.msg import Float64
from tf2_msgs.msg import TFMessage

from zensim.common.edges import check_edge, is_loopback
from zensim.common.logs import FORMAT, RateLimitedLog
from zensim.common.robot_info import description_bytes, fetch_robot
from zensim.common.ros_state import StateIntake
from zensim.common.session import StartupError
from zensim.common.wire import Refusals, TypedPublisher
from zensim.schemas import (Imu, JointState, JointTargets, Keys, Odometry, Ros1Status, SimStatus,
                            VelocityCommand, bounded, encoding_of, topics)

from .mapping import (CommandGate, GuiChanges, InputError, P3dOdometry, RobotJoints, RosNames, resolve,
                      velocity_command, with_mesh_urls, xyzw)
from .meshserver import MeshServer
from .settings import Ros1Settings

logger = logging.getLogger("zensim.ros1")

CMD_VEL_KEY = "/cmd_vel"
"""The command gate's key for /cmd_vel (joint topics are keyed by joint name)."""
GUI_KEY = "/gui"
"""The command gate's key for the GUI's topic (joint names never start with `/`)."""
ROS_QUEUE = 10
"""Depth of each rospy publisher's and subscriber's queue: the oldest message is dropped beyond it."""
MASTER_CHECK_S = 1.0
"""How often the gateway asks the master whether it is still the same one."""
MASTER_TIMEOUT_S = 2.0
"""Longest one question to the master may take."""
ROS_SHUTDOWN_S = 1.0
"""Longest rospy's own shutdown (it unregisters every topic from the master, with no timeout) may take:
a frozen master never answers, and SIGTERM must still end the process."""
STUCK_EXIT_S = 4.0
"""After SIGTERM, how long the gateway may stay inside a call to a master that does not answer (rospy's
init_node, set_param) before it leaves without finishing it."""


def names_of(settings: Ros1Settings) -> RosNames:
    s = settings
    return RosNames.of(s.robot_id, s.namespace, s.joint_states_topic, s.command_topic, s.gui_topic, s.odom_topic,
                       s.imu_topic, s.clock_topic, s.tf_topic)


class Counters:
    """What the status reports; updated under the gateway's lock."""

    def __init__(self) -> None:
        self.commands_received = 0
        self.commands_forwarded = 0
        self.commands_shed = 0
        self.last_command: float | None = None
        self.description_updates = 0
        self.master_restarts = 0
        self.master_up = False


class Gateway:
    """The running gateway (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, settings: Ros1Settings, names: RosNames,
                 mesh_server: MeshServer | None) -> None:
        self._session = session
        self._keys = keys
        self._settings = settings
        self.names = names
        self._mesh_server = mesh_server
        self._lock = threading.Lock()
        self.counters = Counters()
        self.refusals = Refusals(logger, "ROS message")
        self.intake = StateIntake(logger, settings.state_rate_hz, joints=self._on_joints, odom=self._on_odom,
                                  imu=self._on_imu, sim_status=self._on_sim_status)
        """state/*, and the robot: `intake.sim_run.restarted` is set when it must be learned again."""
        self._episode = ""
        self._gui_changes = GuiChanges()
        self._command_gate: CommandGate[str, float | JointTargets | VelocityCommand] = CommandGate(settings.command_rate_hz)
        """Per topic (a joint's name, or GUI_KEY): at most command_rate_hz forwards a second; guarded by _lock."""
        self._command_subscribers: list[rospy.Subscriber] = []
        self._base_frame = settings.base_frame
        # ROS side.
        self._joint_states = rospy.Publisher(names.joint_states, RosJointState, queue_size=ROS_QUEUE)
        self._odom = rospy.Publisher(names.odom, RosOdometry, queue_size=ROS_QUEUE)
        self._imu = rospy.Publisher(names.imu, RosImu, queue_size=ROS_QUEUE)
        self._clock = rospy.Publisher(names.clock, Clock, queue_size=ROS_QUEUE)
        self._tf = rospy.Publisher(names.tf, TFMessage, queue_size=ROS_QUEUE)
        self._gui = rospy.Subscriber(names.gui, RosJointState, self._on_gui, queue_size=ROS_QUEUE)
        self._cmd_vel_topic = resolve(names.namespace, settings.cmd_vel_topic)
        self._cmd_vel = rospy.Subscriber(self._cmd_vel_topic, Twist, self._on_cmd_vel, queue_size=ROS_QUEUE)
        # Zenoh side.
        self._targets = TypedPublisher.of(session, keys, topics.JOINT_TARGETS)
        self._velocity = TypedPublisher.of(session, keys, topics.VELOCITY)
        self._status = TypedPublisher.of(session, keys, topics.ROS1_STATUS)
        self._scalar_encoding = zenoh.Encoding(encoding_of("msgpack"))
        self._subscribers: list[zenoh.Subscriber] = []

    def start(self, robot: RobotJoints) -> None:
        """Take the robot, set robot_description, then start the flow of states."""
        self.adopt(robot)
        self._subscribers = self.intake.subscribe(self._session, self._keys)

    # --- the robot and its description ------------------------------------------------------

    def adopt(self, robot: RobotJoints) -> None:
        """Take `robot` (at start and after a sim restart): its command topics and robot_description."""
        previous = self.intake.robot
        self.intake.adopt(robot)
        if previous is None or previous.names != robot.names:
            for subscriber in self._command_subscribers:
                subscriber.unregister()
            self._command_subscribers = [
                rospy.Subscriber(self.names.command(joint), Float64, self._on_command, callback_args=joint,
                                 queue_size=ROS_QUEUE)
                for joint in robot.names
            ]
            with self._lock:
                self._gui_changes.forget()
                self._command_gate.forget()
        if self._mesh_server is not None:
            self._mesh_server.serve_robot(robot.mesh_paths)
        self.set_params()

    def set_params(self) -> None:
        """robot_description (the sim's URDF, meshes pointed at our http server) and use_sim_time."""
        urdf = description_bytes(self._session, self._keys.urdf, self._settings.info_timeout_s).decode("utf-8", errors="replace")
        if self._mesh_server is not None:
            urdf = with_mesh_urls(urdf, self.mesh_url())
        if self._settings.set_use_sim_time:
            rospy.set_param("/use_sim_time", True)
        rospy.set_param(self._settings.description_param, urdf)
        with self._lock:
            self.counters.description_updates += 1
        logger.info("%s set: %d characters", self._settings.description_param, len(urdf))

    def mesh_url(self) -> str:
        if self._mesh_server is None:
            return ""
        host = mesh_host(self._settings)
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self._mesh_server.port}"

    # --- zensim -> ROS (zenoh threads; the intake decodes, thins and checks) -----------------

    def _on_joints(self, state: JointState, robot: RobotJoints) -> None:
        stamp = rospy.Time.from_sec(state.sim_time_s)
        message = RosJointState(name=list(robot.names), position=state.q, velocity=state.dq, effort=state.tau)
        message.header.stamp = stamp
        self._clock.publish(Clock(clock=stamp))
        self._joint_states.publish(message)

    def _on_odom(self, odom: Odometry) -> None:
        p3d = P3dOdometry.of(odom)
        stamp = rospy.Time.from_sec(odom.sim_time_s)
        world = self._settings.world_frame
        message = RosOdometry()
        message.header.stamp, message.header.frame_id, message.child_frame_id = stamp, world, self._base_frame
        pose, twist = message.pose.pose, message.twist.twist
        pose.position.x, pose.position.y, pose.position.z = p3d.position
        o = pose.orientation
        o.x, o.y, o.z, o.w = p3d.orientation_xyzw
        twist.linear.x, twist.linear.y, twist.linear.z = p3d.linear
        twist.angular.x, twist.angular.y, twist.angular.z = p3d.angular
        self._odom.publish(message)
        transform = TransformStamped()
        transform.header.stamp, transform.header.frame_id, transform.child_frame_id = stamp, world, self._base_frame
        t = transform.transform
        t.translation.x, t.translation.y, t.translation.z = p3d.position
        t.rotation = o
        self._tf.publish(TFMessage(transforms=[transform]))

    def _on_imu(self, imu: Imu) -> None:
        message = RosImu()
        message.header.stamp = rospy.Time.from_sec(imu.sim_time_s)
        message.header.frame_id = self._settings.imu_frame
        o = message.orientation
        o.x, o.y, o.z, o.w = xyzw(imu.quat_wxyz)
        message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z = imu.gyro
        a = message.linear_acceleration
        a.x, a.y, a.z = imu.accel
        self._imu.publish(message)

    def _on_sim_status(self, status: SimStatus) -> None:
        if status.episode and status.episode != self._episode:
            if self._episode:
                # The GUI's sliders that did not move since are not sent again (GuiChanges), so the
                # sim's reset pose stands until someone moves a slider or sends a command.
                logger.info("new sim episode (mode %s): the robot is in its default pose", status.mode)
            self._episode = status.episode

    # --- ROS -> zensim (rospy threads) --------------------------------------------------------

    def _received(self) -> RobotJoints | None:
        with self._lock:
            self.counters.commands_received += 1
            return self.intake.robot

    def _on_command(self, message: Float64, joint: str) -> None:
        robot = self._received()
        topic = self.names.command(joint)
        try:
            if robot is None:
                raise InputError("the robot is not known yet")
            value = robot.check_position(joint, message.data)
        except (InputError, TypeError) as exc:
            self.refusals.refuse(topic, str(exc))
            return
        self._offer(joint, value)

    def _on_gui(self, message: RosJointState) -> None:
        robot = self._received()
        try:
            if robot is None:
                raise InputError("the robot is not known yet")
            targets = robot.joint_targets(list(message.name), list(message.position))
        except (InputError, TypeError) as exc:
            self.refusals.refuse(self.names.gui, str(exc))
            return
        self._offer(GUI_KEY, targets)

    def _offer(self, key: str, value: float | JointTargets | VelocityCommand) -> None:
        """A valid command through the gate: forwarded now, or held for its turn (a held one is shed)."""
        with self._lock:  # rospy calls back on one thread per publisher: two GUIs, two threads
            forward_now, shed = self._command_gate.offer(key, value, time.monotonic())
            self.counters.commands_shed += shed
        if forward_now:
            self._forward(key, value)

    def forward_held(self, stop: threading.Event) -> None:
        """Forward each held command when its turn comes (the newest of a burst always arrives)."""
        period_s = self._command_gate.period_s
        if period_s <= 0:
            return
        while not stop.wait(period_s / 2):
            with self._lock:
                ready = self._command_gate.due(time.monotonic())
            for key, value in ready:
                self._forward(key, value)

    def _forward(self, key: str, value: float | JointTargets | VelocityCommand) -> None:
        if isinstance(value, VelocityCommand):
            self._velocity.put(value)
        elif isinstance(value, JointTargets):
            # The sliders that moved since the last forward: computed at forward time, so a GUI message
            # shed while held loses no slider that the newer one still holds.
            with self._lock:
                changed = self._gui_changes.changed(value)
            if changed is None:
                return
            self._targets.put(changed)
        else:
            self._session.put(self._keys.joint_target(key), msgspec.msgpack.encode(value),
                              encoding=self._scalar_encoding)
        with self._lock:
            self.counters.commands_forwarded += 1
            self.counters.last_command = time.monotonic()

    def _on_cmd_vel(self, message: Twist) -> None:
        """The classic /cmd_vel: linear x, y and angular z to the walking controller (`zensim loco`)."""
        with self._lock:
            self.counters.commands_received += 1
        try:  # the rule `zensim ros2` applies too (common/ros_rules.py): NaN or absurd anywhere, refused whole
            linear, angular = message.linear, message.angular
            command = velocity_command((linear.x, linear.y, linear.z), (angular.x, angular.y, angular.z),
                                       self._settings.cmd_vel_timeout_s)
        except (InputError, TypeError) as exc:
            self.refusals.refuse(self._cmd_vel_topic, str(exc))
            return
        self._offer(CMD_VEL_KEY, command)  # shed like the joint commands: a Twist flood is one put per period

    # --- the master ------------------------------------------------------------------------------

    def watch_master(self, stop: threading.Event) -> None:
        """Ask the master's pid every MASTER_CHECK_S; a new pid is a restarted master: register again.

        rospy registers a node's topics once, at start; a restarted roscore knows nothing of them.
        """
        uri = rosmaster_uri()
        master = xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport())
        known_pid = None
        down_log = RateLimitedLog(logger, 10.0)
        while not stop.wait(MASTER_CHECK_S):
            try:
                answer: Any = master.getPid(rospy.get_name())  # xmlrpc: [code, message, pid]
                code, _, pid = answer
                up = code == 1
            except (OSError, xmlrpc.client.Error) as exc:
                up, pid = False, None
                down_log.warning("the ROS master at %s does not answer: %s", uri, exc)
            with self._lock:
                self.counters.master_up = up
            if not up:
                continue
            if known_pid is not None and pid != known_pid:
                logger.info("the ROS master restarted (pid %s): registering again", pid)
                try:
                    self.register_again()
                except (LookupError, OSError) as exc:
                    logger.warning("could not register with the new master yet: %s", exc)
                    continue
                with self._lock:
                    self.counters.master_restarts += 1
            known_pid = pid

    def register_again(self) -> None:
        """Tell the (new) master every topic of this node, and set the parameters again."""
        manager = get_topic_manager()
        listeners = get_registration_listeners()
        for name, data_type in manager.get_publications():
            listeners.notify_added(name, data_type, Registration.PUB)
        for name, data_type in manager.get_subscriptions():
            listeners.notify_added(name, data_type, Registration.SUB)
        self.set_params()

    # --- status ------------------------------------------------------------------------------------

    def publish_status(self, seq: int) -> None:
        rate_hz = self.intake.published_rate_hz()
        published, sim_time_s = self.intake.published()
        with self._lock:
            c = self.counters
            status = Ros1Status(
                seq=seq, master_uri=rosmaster_uri(), master_up=c.master_up, master_restarts=c.master_restarts,
                joint_states_published=published, joint_states_rate_hz=rate_hz,
                sim_time_s=sim_time_s, commands_received=c.commands_received,
                commands_forwarded=c.commands_forwarded, rejected=self.refusals.count,
                last_error=self.refusals.last_error,
                command_age_s=None if c.last_command is None else time.monotonic() - c.last_command,
                description_updates=c.description_updates, mesh_url=self.mesh_url(),
                commands_shed=c.commands_shed,
            )
        self._status.put(status)

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._targets.undeclare()
        self._velocity.undeclare()
        self._status.undeclare()


class _TimeoutTransport(xmlrpc.client.Transport):
    """xmlrpc over http that gives up after MASTER_TIMEOUT_S (a frozen master must not hang the watch)."""

    def make_connection(self, host):  # noqa: ANN001, ANN201 - the stdlib's signature
        connection = super().make_connection(host)
        connection.timeout = MASTER_TIMEOUT_S
        return connection


def mesh_host(settings: Ros1Settings) -> str:
    """The host name robot_description's mesh URLs name (and so the Host header RViz sends)."""
    host = settings.mesh_http_host or settings.mesh_http_bind
    return socket.gethostname() if host in ("0.0.0.0", "::", "") else host


def ros_bind_address() -> str:
    """The address rospy binds the node's XML-RPC and TCPROS servers to: loopback unless ROS_IP or
    ROS_HOSTNAME says otherwise (rospy alone would bind every interface when neither is set)."""
    import rosgraph.network

    if rosgraph.network.get_address_override() is None:
        os.environ["ROS_IP"] = "127.0.0.1"  # read by rospy's init_node: how a ROS node is told where to listen
    return rosgraph.network.get_bind_address()


def check_ros_edge(settings: Ros1Settings) -> None:
    """Loopback unless ROS_IP / ROS_HOSTNAME ask otherwise; beyond it, warn, or refuse under --secure-dir
    without --open-edge (services/common/edges.py).

    Raises:
        StartupError: beyond loopback under --secure-dir without --open-edge.
    """
    import rosgraph.network

    bind = ros_bind_address()
    where = f"{bind} (ROS_IP / ROS_HOSTNAME {rosgraph.network.get_address_override()})"
    check_edge("the ROS 1 gateway (its XML-RPC and TCPROS servers)", where, is_loopback(bind),
               settings.zenoh.secure_dir, settings.open_edge, logger)


def rosmaster_uri() -> str:
    import rosgraph

    return rosgraph.get_master_uri()


class RosShutdown:
    """Why rospy shut this node down, when something other than us did: `rosnode kill`, an XML-RPC
    `shutdown` call to the node (anyone who reaches its port may send one), or the master when another
    node registered the same name. rospy's side then stops for good while the process would run on."""

    def __init__(self) -> None:
        self.reason: str | None = None
        self.ours = False

    def note(self, reason: str) -> None:
        """rospy's pre-shutdown hook: called once, with rospy's reason, on the thread that shut it down."""
        if not self.ours:
            self.reason = bounded(str(reason), 300)

    def shut_down(self, why: str) -> None:
        """Shut rospy down ourselves, waiting at most ROS_SHUTDOWN_S for it to unregister from the master."""
        self.ours = True
        closer = threading.Thread(target=rospy.signal_shutdown, args=(why,), name="ros-shutdown", daemon=True)
        closer.start()
        closer.join(ROS_SHUTDOWN_S)
        if closer.is_alive():
            logger.warning("the ROS master did not answer within %.1f s: leaving without unregistering",
                           ROS_SHUTDOWN_S)


def _leave_if_stuck(stop: threading.Event) -> None:
    """Once `stop` is set, give the gateway STUCK_EXIT_S to return, then leave: a call to a frozen master
    (rospy's init_node, set_param) has no timeout and would hold SIGTERM off until a SIGKILL."""
    stop.wait()
    time.sleep(STUCK_EXIT_S)
    logger.warning("still inside a call to the ROS master %.0f s after the stop signal: leaving now", STUCK_EXIT_S)
    logging.shutdown()
    os._exit(0)


def run(session: zenoh.Session, settings: Ros1Settings, stop: threading.Event) -> int:
    """Learn the robot, join the ROS graph, map until `stop` is set or the ROS side is shut down.

    Returns:
        The process exit code: 1 when something on the ROS side shut the gateway's node down.
    """
    threading.Thread(target=_leave_if_stuck, args=(stop,), name="stuck-exit", daemon=True).start()
    keys = Keys(settings.robot_id)
    try:
        names = names_of(settings)
    except ValueError as exc:
        raise StartupError(str(exc)) from None
    mesh_server = None
    if settings.mesh_urls == "http":
        try:
            mesh_server = MeshServer(settings.mesh_http_bind, settings.mesh_http_port,
                                     lambda path: description_bytes(session, keys.mesh(path), settings.info_timeout_s),
                                     hosts=(mesh_host(settings),))
        except OSError as exc:
            raise StartupError(f"cannot serve meshes on {settings.mesh_http_bind}:{settings.mesh_http_port}: "
                               f"{exc.strerror or exc}") from None
    try:
        return _serve(session, keys, settings, names, mesh_server, stop)
    finally:
        if mesh_server is not None:
            mesh_server.close()


def _learn_robot(session: zenoh.Session, keys: Keys, settings: Ros1Settings, stop: threading.Event) -> RobotJoints | None:
    return fetch_robot(session, keys, settings.info_timeout_s, stop, RobotJoints.from_info, logger)


def _serve(session: zenoh.Session, keys: Keys, settings: Ros1Settings, names: RosNames,
           mesh_server: MeshServer | None, stop: threading.Event) -> int:
    logger.info("asking the sim on %s", keys.robot_info)
    robot = _learn_robot(session, keys, settings, stop)
    if robot is None:
        return 0
    node = settings.node_name or f"zensim_ros1_{settings.robot_id.replace('-', '_')}"
    logger.info("joining the ROS graph as /%s, master %s", node, rosmaster_uri())
    ros_shutdown = RosShutdown()
    rospy.core.add_preshutdown_hook(ros_shutdown.note)
    rospy.init_node(node, disable_signals=True)
    # init_node points the root logger at a file in ROS_HOME/log: ours go to stderr like every service's.
    logging.basicConfig(level=settings.log_level.upper(), format=FORMAT, force=True)
    if logger.getEffectiveLevel() > logging.DEBUG:
        logging.getLogger("rospy").setLevel(logging.WARNING)  # a line per connection otherwise
    if mesh_server is not None:
        mesh_server.start()
    gateway = Gateway(session, keys, settings, names, mesh_server)
    try:
        gateway.start(robot)
    except LookupError as exc:
        gateway.close()
        ros_shutdown.shut_down("no robot description")
        raise StartupError(f"cannot read the robot's URDF: {exc}") from None
    watcher = threading.Thread(target=gateway.watch_master, args=(stop,), name="ros-master", daemon=True)
    watcher.start()
    threading.Thread(target=gateway.forward_held, args=(stop,), name="held-commands", daemon=True).start()
    token = session.liveliness().declare_token(keys.alive("ros1"))
    logger.info("ros1 gateway up: %d joints; %s, %s, %s%s", len(robot.names), names.joint_states, names.gui,
                names.command("{joint}"), f"; meshes at {gateway.mesh_url()}" if mesh_server else "")
    period_s = 1.0 / settings.status_rate_hz
    seq = 0
    exit_code = 0
    try:
        while not stop.wait(period_s):
            if ros_shutdown.reason is not None:
                # Serving on would be a lie: no ROS output, commands ignored, and a live alive/ros1 token.
                logger.error("the gateway's ROS node was shut down from outside (%s): exiting (restart it; "
                             "`zensim up` stops with it)", ros_shutdown.reason)
                exit_code = 1
                break
            if gateway.intake.sim_run.restarted.is_set():
                robot = _learn_robot(session, keys, settings, stop)
                if robot is None:
                    break
                try:
                    gateway.adopt(robot)
                    logger.info("robot from the restarted sim: %d joints", len(robot.names))
                except LookupError as exc:
                    logger.warning("the restarted sim's URDF: %s; asking again", exc)
                    gateway.intake.sim_run.restarted.set()
            gateway.publish_status(seq)
            seq += 1
    finally:
        token.undeclare()
        gateway.close()
        ros_shutdown.shut_down("zensim ros1 stopping")
    c = gateway.counters
    logger.info("%d ROS commands read, %d forwarded, %d shed, %d rejected; %d joint states published",
                c.commands_received, c.commands_forwarded, c.commands_shed, gateway.refusals.count,
                gateway.intake.published()[0])
    return exit_code
