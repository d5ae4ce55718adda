"""`zensim ros1` as users run it: a private `roscore`, a real router, sim, bridge and gateway process,
and the test process as a rospy node (Debian's ROS 1) beside a plain zenoh session.

One stack serves the module's tests (starting it is the slow part); the official-G1 mesh test and
the restart test start their own.
"""

from __future__ import annotations

import gc
import math
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
import xmlrpc.client

import pytest

from ros_graph import Roscore, Stack, import_rospy, master_proxy
from support import TWO_JOINT_ARM, Latest, ctl, free_port, plain_client, wait_for
from zensim.robots.description import parse_urdf
from zensim.ros1.mapping import mesh_references
from zensim.schemas import JointState, JointTargets, Keys, Odometry, Ros1Status

rospy = import_rospy()
from nav_msgs.msg import Odometry as RosOdometry  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu as RosImu  # noqa: E402
from sensor_msgs.msg import JointState as RosJointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

# Debian's rospy (Noetic-era) calls threading's notifyAll() and leaves its xmlrpc sockets to the garbage
# collector: warnings about code that is not ours, raised on rospy's own threads, where an error would
# stall its registration with the master.
pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning"),
              pytest.mark.filterwarnings("ignore::ResourceWarning"),
              pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")]

KEYS = Keys("g1")  # the default robot id: the ROS names are the classic workspace's
NS = "/g1_description"
ELBOW = "left_elbow_joint"


class Received:
    """A rospy subscriber that keeps every message (with the wall time it came)."""

    def __init__(self, topic: str, message_type: type) -> None:
        self.messages: list = []
        self.times: list[float] = []
        self._lock = threading.Lock()
        self._sub = rospy.Subscriber(topic, message_type, self._on, queue_size=1000)

    def _on(self, message) -> None:
        with self._lock:
            self.messages.append(message)
            self.times.append(time.monotonic())

    def since(self, t0: float) -> list:
        with self._lock:
            return [m for m, t in zip(self.messages, self.times) if t >= t0]

    def latest(self):
        with self._lock:
            return self.messages[-1] if self.messages else None

    def close(self) -> None:
        self._sub.unregister()


@pytest.fixture(scope="module")
def roscore(tmp_path_factory):
    """A master of the module's own; the test process joins it as a rospy node."""
    core = Roscore(tmp_path_factory.mktemp("ros"))
    saved = {name: os.environ.get(name) for name in core.env}
    os.environ.update(core.env)
    rospy.init_node("zensim_test", anonymous=True, disable_signals=True)
    try:
        yield core
    finally:
        # rospy allows one node per process and never a second: shut it down here, and collect its
        # sockets now, under this module's warning filters, not in a later module's test.
        rospy.signal_shutdown("the ROS tests are done")
        gc.collect()
        core.stop()
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@pytest.fixture(scope="module")
def stack(roscore, tmp_path_factory):
    """The G1 standing in the floating mode (the classic Gazebo setup), with the bridge and the gateway."""
    stack = Stack(roscore, tmp_path_factory.mktemp("stack"))
    try:
        yield stack
    finally:
        stack.close()


def status_after(status: Latest, seq: int) -> Ros1Status:
    return status.wait(lambda s: s.seq > seq, 10, "a newer state/ros1")


def publisher(topic: str, message_type: type):
    pub = rospy.Publisher(topic, message_type, queue_size=1000)
    wait_for(lambda: pub.get_num_connections() > 0, 10, f"the gateway to subscribe to {topic}")
    return pub


def robot_joint_names(session) -> list[str]:
    """The sim's canonical joint order (info/robot)."""
    return list(ctl(session, KEYS.robot_info)["joint_names"])


def joint_position(state: JointState, joint: str, names: list[str]) -> float:
    return state.q[names.index(joint)]


def test_joint_states_odometry_imu_clock_and_description_reach_ros(stack) -> None:
    names = robot_joint_names(stack.session)
    joints = Latest(stack.session, KEYS.joints, JointState)
    odoms = Latest(stack.session, KEYS.odom, Odometry)
    joints.keep_history = odoms.keep_history = True
    ros_joints = Received(f"{NS}/joint_states", RosJointState)
    ros_odom = Received("/ground_truth_odom", RosOdometry)
    ros_imu = Received(f"{NS}/imu", RosImu)
    ros_clock = Received("/clock", Clock)
    wait_for(lambda: len(ros_joints.messages) > 10, 20, "JointState on ROS", 0.1)
    t0 = time.monotonic()
    zenoh_before = joints.count
    time.sleep(3.0)
    window = ros_joints.since(t0)
    zenoh_count = joints.count - zenoh_before
    for topic in (ros_joints, ros_odom, ros_imu, ros_clock):
        topic.close()

    # Rate: every sim state becomes a JointState, at 100 Hz of sim time.
    stamps = [m.header.stamp.to_sec() for m in window]
    sim_rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert sim_rate >= 90, f"{sim_rate:.1f} JointState per sim second"
    assert len(window) >= 0.9 * zenoh_count, f"{len(window)} JointState for {zenoh_count} state/joints samples"
    wall_rate = len(window) / 3.0
    print(f"[ros1] JointState {wall_rate:.1f} Hz wall, {sim_rate:.1f} Hz sim time ({zenoh_count / 3.0:.1f} Hz "
          "state/joints on zenoh in the same window; shared machine)")
    # The robot's own 29 names in its order, and the positions of state/joints at the same instant.
    assert all(list(m.name) == names for m in window) and len(names) == 29
    by_time = {round(s.sim_time_s, 6): s for s in joints.history}
    matched = [(m, by_time[round(m.header.stamp.to_sec(), 6)]) for m in window
               if round(m.header.stamp.to_sec(), 6) in by_time]
    assert len(matched) >= 0.9 * len(window)
    for message, state in matched:
        assert tuple(message.position) == tuple(state.q)
        assert tuple(message.velocity) == tuple(state.dq) and tuple(message.effort) == tuple(state.tau)

    # Odometry: frame world, child pelvis, the pose of state/odom at the same instant (x, y, z, w).
    odom_by_time = {round(o.sim_time_s, 6): o for o in odoms.history}
    odom_matched = [(m, odom_by_time[round(m.header.stamp.to_sec(), 6)]) for m in ros_odom.messages
                    if round(m.header.stamp.to_sec(), 6) in odom_by_time]
    assert len(odom_matched) >= 100
    for message, odom in odom_matched:
        assert (message.header.frame_id, message.child_frame_id) == ("world", "pelvis")
        p, q = message.pose.pose.position, message.pose.pose.orientation
        assert (p.x, p.y, p.z) == tuple(odom.pos)
        assert (q.w, q.x, q.y, q.z) == tuple(odom.quat_wxyz)
        assert (message.twist.twist.linear.x, message.twist.twist.linear.y) == tuple(odom.lin_vel_world[:2])
    assert 0.6 < odom_matched[-1][0].pose.pose.position.z < 0.9, "the G1 stands on the floor"

    # IMU: upright, gravity on z; /clock: sim time going forward.
    imu = ros_imu.latest()
    assert imu.header.frame_id == "imu_in_pelvis"
    assert 8.0 < imu.linear_acceleration.z < 11.0
    clocks = [c.clock.to_sec() for c in ros_clock.messages]
    assert len(clocks) > 100 and clocks == sorted(clocks)

    # robot_description: the sim's URDF, parsed; the gateway set use_sim_time as Gazebo's launch does.
    description = parse_urdf(rospy.get_param("/robot_description"))
    assert sorted(joint.name for joint in description.actuated_joints) == sorted(names)
    assert rospy.get_param("/use_sim_time") is True


def test_float64_and_gui_joint_states_move_the_sim_through_the_bridge(stack) -> None:
    joints = Latest(stack.session, KEYS.joints, JointState)
    targets = Latest(stack.session, KEYS.bridge_targets, JointTargets)  # the bridge's clamped, slew-limited targets
    names = list(targets.wait(timeout_s=10).names)

    elbow = publisher(f"{NS}/{ELBOW}_controller/command", Float64)
    elbow.publish(Float64(data=0.9))
    state = joints.wait(lambda s: abs(joint_position(s, ELBOW, names) - 0.9) < 0.05, 15, "the left elbow at 0.9")
    targets.wait(lambda t: abs(t.q[names.index(ELBOW)] - 0.9) < 1e-6, 5, "the bridge to hold the elbow at 0.9")

    gui = publisher("/gui_commands", RosJointState)
    gui.publish(RosJointState(name=["right_elbow_joint", "left_wrist_roll_joint"], position=[0.6, 0.4]))
    joints.wait(lambda s: abs(joint_position(s, "right_elbow_joint", names) - 0.6) < 0.05
                and abs(joint_position(s, "left_wrist_roll_joint", names) - 0.4) < 0.05, 15, "the GUI's two joints")
    assert abs(joint_position(joints.value, ELBOW, names) - 0.9) < 0.05, "a joint the GUI does not name stays"
    assert state.sim_time_s < joints.value.sim_time_s


def test_bad_input_on_every_ros_topic_is_counted_not_applied_and_outputs_keep_their_rate(stack) -> None:
    joints = Latest(stack.session, KEYS.joints, JointState)
    status = Latest(stack.session, KEYS.ros1_status, Ros1Status)
    forwarded: list[object] = []  # zenoh samples
    zenoh_commands = [stack.session.declare_subscriber(key, forwarded.append)  # what the gateway puts for the bridge
                      for key in (KEYS.joint_targets, KEYS.joint_target_any)]
    names = robot_joint_names(stack.session)
    before = status.wait(timeout_s=10)
    q_before = joints.wait(timeout_s=10).q
    elbow = publisher(f"{NS}/{ELBOW}_controller/command", Float64)
    gui = publisher("/gui_commands", RosJointState)

    bad_floats = [math.nan, math.inf, -math.inf, 50.0, -1e300]
    bad_gui = [
        RosJointState(name=[ELBOW], position=[math.nan]),
        RosJointState(name=[ELBOW, "tail_joint"], position=[0.1, 0.1]),
        RosJointState(name=[ELBOW, "right_elbow_joint"], position=[0.1]),
        RosJointState(name=[ELBOW, ELBOW], position=[0.1, 0.2]),
        RosJointState(name=[ELBOW], position=[40.0]),
        RosJointState(),
    ]
    for value in bad_floats:
        elbow.publish(Float64(data=value))
        time.sleep(0.02)
    for message in bad_gui:
        gui.publish(message)
        time.sleep(0.02)
    n_bad = len(bad_floats) + len(bad_gui)
    after = status.wait(lambda s: s.rejected >= before.rejected + n_bad, 10, "the refusals to be counted")
    assert after.rejected == before.rejected + n_bad
    assert after.commands_received == before.commands_received + n_bad
    assert after.commands_forwarded == before.commands_forwarded
    assert after.last_error == "a JointState with no names moves nothing"
    time.sleep(0.5)
    assert forwarded == [], "a refused ROS message reached zensim"
    assert max(abs(a - b) for a, b in zip(joints.value.q, q_before)) < 0.05, "the robot moved"

    # A flood of bad commands (2000 a second for 2 s) does not slow the joint states down.
    ros_joints = Received(f"{NS}/joint_states", RosJointState)
    wait_for(lambda: len(ros_joints.messages) > 5, 10, "JointState on ROS")
    stop = threading.Event()

    def flood() -> None:
        while not stop.is_set():
            for _ in range(20):
                elbow.publish(Float64(data=math.nan))
            time.sleep(0.01)

    flooder = threading.Thread(target=flood, daemon=True)
    t0 = time.monotonic()
    zenoh_before = joints.count
    flooder.start()
    time.sleep(2.0)
    stop.set()
    flooder.join(5)
    window = ros_joints.since(t0)
    zenoh_count = joints.count - zenoh_before
    ros_joints.close()
    stamps = [m.header.stamp.to_sec() for m in window]
    assert (len(stamps) - 1) / (stamps[-1] - stamps[0]) >= 90
    assert len(window) >= 0.9 * zenoh_count, f"{len(window)} JointState for {zenoh_count} states during the flood"
    flooded = status_after(status, status.value.seq)
    assert flooded.rejected > after.rejected + 100, "the flood was counted"
    assert forwarded == []
    print(f"[ros1] during a flood of bad Float64: {len(window) / 2.0:.1f} JointState/s for {zenoh_count / 2.0:.1f} "
          f"state/joints/s; {flooded.rejected - after.rejected} refused")
    # ...and the gateway still takes a good command at once.
    elbow.publish(Float64(data=0.3))
    names_order = names
    joints.wait(lambda s: abs(s.q[names_order.index(ELBOW)] - 0.3) < 0.05, 15, "the elbow at 0.3 after the flood")
    for subscriber in zenoh_commands:
        subscriber.undeclare()


def test_a_valid_flood_is_shed_in_the_gateway_counted_and_its_newest_value_arrives(stack) -> None:
    """Valid Float64 as fast as one rospy publisher goes (the issue's 9.7 kHz took the sim to RTF 0.31): the
    gateway passes each topic on at most command_rate_hz (100) times a second, counts the rest as shed,
    and the flood's last value still reaches the bridge."""
    status = Latest(stack.session, KEYS.ros1_status, Ros1Status)
    puts: list[float] = []
    subscriber = stack.session.declare_subscriber(KEYS.joint_target(ELBOW), lambda s: puts.append(time.monotonic()))
    targets = Latest(stack.session, KEYS.bridge_targets, JointTargets)
    names = list(targets.wait(timeout_s=10).names)
    before = status.wait(timeout_s=10)
    elbow = publisher(f"{NS}/{ELBOW}_controller/command", Float64)
    sent = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.0:
        for _ in range(50):
            elbow.publish(Float64(data=0.2 + 0.1 * (sent % 2)))
            sent += 1
    elbow.publish(Float64(data=0.55))
    sent += 1
    took = time.monotonic() - t0
    targets.wait(lambda t: abs(t.q[names.index(ELBOW)] - 0.55) < 1e-6, 10, "the flood's last value at the bridge")
    after = status.wait(lambda s: s.commands_received - before.commands_received > 0.5 * sent
                        and s.command_age_s is not None and s.command_age_s > 0.3, 15, "the flood to be counted")
    received = after.commands_received - before.commands_received
    forwarded = after.commands_forwarded - before.commands_forwarded
    shed = after.commands_shed - before.commands_shed
    subscriber.undeclare()
    assert received == forwarded + shed, (received, forwarded, shed)
    assert forwarded <= 100 * took * 1.2 + 5, f"{forwarded} forwarded in {took:.1f} s"
    assert shed >= received - forwarded and shed > 0
    assert after.rejected == before.rejected
    print(f"[ros1] valid flood: {sent / took:.0f} Float64/s sent, {received} read, {forwarded} forwarded, "
          f"{shed} shed ({len(puts)} cmd/joint puts seen)")


def test_robot_description_meshes_load_from_where_it_says(official_g1_dir, tmp_path) -> None:
    """Unitree's G1 with its 61 mesh references: each URL in robot_description serves the file's bytes."""
    core = Roscore(tmp_path / "ros")
    stack = Stack(core, tmp_path, sim_args=("--urdf", str(official_g1_dir / "g1_29dof.urdf")), bridge=False)
    try:
        original = (official_g1_dir / "g1_29dof.urdf").read_text()
        description = core.param("/robot_description")
        urls = mesh_references(description)
        assert len(urls) == len(mesh_references(original)) == 61
        fetched: dict[str, bytes] = {}
        for filename, url in zip(mesh_references(original), urls):
            assert url.startswith("http://127.0.0.1:"), url
            if url not in fetched:
                with urllib.request.urlopen(url, timeout=30) as response:
                    fetched[url] = response.read()
            assert fetched[url] == (official_g1_dir / filename).read_bytes(), filename
        # The server serves the robot's meshes and nothing else.
        root = urls[0].split("/meshes/")[0]
        for path in ("/etc/passwd", "/meshes/../g1_29dof.urdf", "/meshes/nothere.STL"):
            with pytest.raises(urllib.error.HTTPError, match="404") as refused:
                urllib.request.urlopen(root + path, timeout=10)
            refused.value.close()  # an HTTPError holds the response's socket until closed
        print(f"[ros1] {len(fetched)} meshes, {sum(map(len, fetched.values())) / 1e6:.1f} MB over http from the gateway")
    finally:
        stack.close()
        core.stop()


def test_follows_a_restarted_sim_and_a_restarted_master(tmp_path) -> None:
    """A sim restarted with another robot: new robot_description, joint names and command topics.
    A roscore restarted on the same port: the gateway registers again and its topics flow."""
    core = Roscore(tmp_path / "ros")
    stack = Stack(core, tmp_path, sim_args=("--mode", "fixed"))
    try:
        assert "left_elbow_joint" in core.echo_once(f"{NS}/joint_states")["name"]
        arm = tmp_path / "arm.urdf"
        arm.write_text(TWO_JOINT_ARM)
        stack.sim.stop()
        stack.sim = stack.start("sim", "--urdf", str(arm), "--mode", "fixed")
        wait_for(lambda: "two_joint_arm" in (core.param("/robot_description") or ""), 60,
                 "robot_description of the new robot", 0.2)
        assert core.echo_once(f"{NS}/joint_states")["name"] == ["shoulder", "elbow"]
        assert core.subscribers(f"{NS}/elbow_controller/command") == ["/zensim_ros1_g1"]
        assert core.subscribers(f"{NS}/left_elbow_joint_controller/command") == []

        core.stop()
        core = Roscore(tmp_path / "ros2", port=core.port)
        wait_for(lambda: "two_joint_arm" in (core.param("/robot_description") or ""), 30,
                 "robot_description on the new master", 0.2)
        assert core.publishers(f"{NS}/joint_states") == ["/zensim_ros1_g1"]
        assert core.echo_once(f"{NS}/joint_states")["name"] == ["shoulder", "elbow"]
        status = Latest(stack.session, KEYS.ros1_status, Ros1Status).wait(lambda s: s.master_restarts >= 1, 10,
                                                                             "the status to count the new master")
        assert status.master_up and status.description_updates >= 3
    finally:
        stack.close()
        core.stop()


def test_up_ros1_starts_roscore_and_the_gateway_and_ctrl_c_stops_them(tmp_path, robot_id) -> None:
    """`zensim up --ros1` with no master at ROS_MASTER_URI: it starts roscore beside the services."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    port = free_port()
    ros = {"ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1", "ROS_HOME": str(tmp_path / "ros")}
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, PYTHONUNBUFFERED="1", ZENSIM_SIM_MODE="fixed",
               ZENSIM_ROS1_MESH_HTTP_PORT="0", **ros)
    log = (tmp_path / "up.log").open("wb")
    up = subprocess.Popen([sys.executable, "-m", "zensim", "up", "--router-endpoint", endpoint, "--viz", "false",
                           "--ros1"], env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        with plain_client(endpoint, wait_for_router=True) as session:
            def alive() -> set[str]:
                replies = session.liveliness().get(f"zensim/{robot_id}/alive/*", timeout=1.0)
                return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

            wait_for(lambda: alive() >= {"router", "sim", "bridge", "ros1"}, 60, "the services and the gateway", 0.2)
        with master_proxy(ros["ROS_MASTER_URI"]) as master:
            code, _, urdf = master.getParam("/test", "/robot_description")
            assert code == 1 and "<robot" in urdf
            _, _, (publishers, _, _) = master.getSystemState("/test")
        assert f"/{robot_id}_description/joint_states" in dict(publishers)
        up.send_signal(signal.SIGINT)
        assert up.wait(20) == 0, (tmp_path / "up.log").read_text()
        text = (tmp_path / "up.log").read_text()
        assert "ros1 exited with 0" in text and "the ROS master exited with 0" in text, text
        with pytest.raises(OSError):
            with master_proxy(ros["ROS_MASTER_URI"]) as master:
                master.getPid("/test")
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        log.close()
