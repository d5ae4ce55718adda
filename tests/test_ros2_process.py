"""`zensim ros2` as users run it: a real router, sim (fixed mode), bridge and `zensim ros2` process, seen by
real ROS 2 code: rclpy from the Kilted wheels on Fast DDS (tests/ros2_node.py, a process of its own) over
DDS, and, on Zenoh, a plain zenoh session that checks every key, token and attachment against rmw_zenoh's
design document and decodes every payload with rclpy's own `deserialize_message`.

One stack serves the module (starting it is the slow part), in a DDS domain of its own.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
import zenoh.ext

from support import TWO_JOINT_ARM, Latest, Service, ctl, free_port, plain_client, wait_for
from zensim.schemas import JointState, Keys, Odometry, Ros2Status

import ros2_client  # noqa: E402 - real rclpy (tests/ros2_node.py), in its own process and venv

KEYS = Keys("g1")
ELBOW = "left_elbow_joint"
DOMAIN = 20 + os.getpid() % 200
"""A DDS domain and ROS domain of this test run's own (other test runs on the machine use DDS too)."""
HEX64 = "[0-9a-f]{64}"
# rmw_zenoh's templates (ros2/rmw_zenoh docs/design.md), written out here independently of the product.
DATA_KEY = re.compile(rf"^{DOMAIN}/(?P<topic>[a-z0-9_/]+)/(?P<type>[a-z0-9_]+::msg::dds_::[A-Za-z0-9]+_)/RIHS01_{HEX64}$")
NODE_TOKEN = re.compile(rf"^@ros2_lv/{DOMAIN}/(?P<zid>[0-9a-f]+)/(?P<nid>\d+)/(?P=nid)/NN/%/%/zensim_g1$")
ENDPOINT_TOKEN = re.compile(
    rf"^@ros2_lv/{DOMAIN}/(?P<zid>[0-9a-f]+)/0/(?P<eid>\d+)/(?P<kind>MP|MS)/%/%/zensim_g1/"
    rf"(?P<topic>%[a-z0-9_%]+)/(?P<type>[a-z0-9_]+::msg::dds_::[A-Za-z0-9]+_)/(?P<hash>RIHS01_{HEX64})/(?P<qos>[^/]+)$")
# The type hashes the Kilted wheels ship (share/<pkg>/msg/<Type>.json), read in test_ros2.py too.


class Ros2Stack:
    """router, sim, bridge and `zensim ros2` for robot id g1, and a plain zenoh client."""

    def __init__(self, log_dir: Path) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        base = dict(os.environ, ZENSIM_ROBOT_ID="g1", ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
        self.env = dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=self.endpoint)
        self.log_dir = log_dir
        self.services: list[Service] = []
        router = self.start("router", env=dict(base, ZENSIM_ZENOH_LISTEN=self.endpoint))
        self.session = plain_client(self.endpoint, wait_for_router=True)
        try:
            wait_for(lambda: "router up" in router.log() or not router.alive(), 15, "the router to start")
            self.start("sim", "--mode", "fixed")
            self.start("bridge")
            self.gateway = self.start("ros2", "--domain-id", str(DOMAIN), "--status-rate-hz", "10")
            wait_for(lambda: "ros2 face up" in self.gateway.log() or not self.gateway.alive(), 60,
                     "zensim ros2 to start")
            assert self.gateway.alive(), self.logs()
        except BaseException:
            self.close()
            raise

    def start(self, command: str, *args: str, env: dict[str, str] | None = None) -> Service:
        service = Service(command, list(args), env or self.env, self.log_dir)
        self.services.append(service)
        return service

    def logs(self) -> str:
        return "\n".join(f"----- {s.command} -----\n{s.log()[-3000:]}" for s in self.services)

    def close(self) -> None:
        self.session.close()
        for service in reversed(self.services):
            service.stop()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    stack = Ros2Stack(tmp_path_factory.mktemp("ros2"))
    try:
        yield stack
    finally:
        stack.close()


def rclpy_node(*args: str, timeout_s: float) -> list[dict]:
    """Run tests/ros2_node.py (real rclpy on Fast DDS) in this module's domain to the end; its JSON lines."""
    return ros2_client.run_json(*args, domain=DOMAIN, timeout_s=timeout_s)


def stamp_of(message: dict) -> float:
    stamp = message["header"]["stamp"] if "header" in message else message["clock"]
    return stamp["sec"] + stamp["nanosec"] * 1e-9


def status_after(session, seq: int) -> Ros2Status:
    status = Latest(session, KEYS.ros2_status, Ros2Status)
    return status.wait(lambda s: s.seq > seq, 10, "a newer state/ros2")


def newest_status(session) -> Ros2Status:
    return status_after(session, -1)


def pose_with(session, joint: str, value: float) -> list[float]:
    """Every joint where it stands now (inside its limits), `joint` at `value`: a forward command."""
    info = ctl(session, KEYS.robot_info)
    state = Latest(session, KEYS.joints, JointState).wait(timeout_s=10, what="state/joints")
    names = list(info["joint_names"])
    q = [min(max(v, lo), hi) for v, lo, hi in zip(state.q, info["q_min"], info["q_max"])]
    q[names.index(joint)] = value
    return q


def elbow_reaches(session, value: float, timeout_s: float = 20) -> None:
    names = list(ctl(session, KEYS.robot_info)["joint_names"])
    state = Latest(session, KEYS.joints, JointState)
    state.wait(lambda s: abs(s.q[names.index(ELBOW)] - value) < 0.05, timeout_s, f"the elbow to reach {value}")


# --- DDS: real rclpy on Fast DDS ------------------------------------------------------------------------


def test_rclpy_on_fast_dds_sees_the_robot_with_zensims_values(stack):
    """An rclpy node that starts after `zensim ros2` gets the latched /robot_description, and /joint_states,
    /odom, /imu, /clock carry the values of zensim's own state/joints and state/odom at the same sim time."""
    names = list(ctl(stack.session, KEYS.robot_info)["joint_names"])
    urdf = next(iter(stack.session.get(KEYS.urdf, timeout=10))).ok.payload.to_bytes().decode()
    joints = Latest(stack.session, KEYS.joints, JointState)
    odom = Latest(stack.session, KEYS.odom, Odometry)
    joints.keep_history = odom.keep_history = True
    lines = rclpy_node("echo", "10", timeout_s=90)
    by_topic: dict[str, list[dict]] = {}
    for line in lines:
        by_topic.setdefault(line.get("topic", ""), []).append(line)
    for topic in ("/joint_states", "/odom", "/imu", "/clock", "/robot_description"):
        assert by_topic.get(topic), f"no {topic} reached rclpy over DDS; got {sorted(by_topic)}\n{stack.logs()}"
    assert by_topic["/robot_description"][0]["data"] == urdf
    assert len(by_topic["/joint_states"]) > 50, "the 100 Hz stream for seconds (loosely: discovery takes some)"
    zensim_q = {round(s.sim_time_s, 6): s.q for s in joints.history}
    matched = 0
    for js in by_topic["/joint_states"]:
        assert js["name"] == names
        q = zensim_q.get(round(stamp_of(js), 6))
        if q is not None:
            assert js["position"] == pytest.approx(list(q), abs=1e-12)
            matched += 1
    assert matched > 50, f"only {matched} JointStates matched zensim's state/joints by sim time"
    zensim_pos = {round(s.sim_time_s, 6): s.pos for s in odom.history}
    odoms = [o for o in by_topic["/odom"] if round(stamp_of(o), 6) in zensim_pos]
    assert odoms, "no /odom at a sim time of state/odom"
    for o in odoms:
        assert o["header"]["frame_id"] == "world" and o["child_frame_id"] == "pelvis"
        p = o["pose"]["pose"]["position"]
        assert [p["x"], p["y"], p["z"]] == pytest.approx(list(zensim_pos[round(stamp_of(o), 6)]), abs=1e-12)
    assert by_topic["/imu"][-1]["header"]["frame_id"] == "imu_in_pelvis"
    clock = [stamp_of(c) for c in by_topic["/clock"]]
    assert clock == sorted(clock) and clock[-1] > clock[0], "/clock counts sim time up"
    # The DDS side listens on loopback only (as the Unitree adapter): every UDP socket of the process is
    # bound to 127.0.0.1 or tied to lo (`0.0.0.0%lo` in ss).
    sockets = [line.split()[3] for line in subprocess.run(["ss", "-H", "-uanp"], capture_output=True, text=True,
                                                          timeout=10).stdout.splitlines()
               if f"pid={stack.gateway.proc.pid}," in line]
    assert sockets, "zensim ros2 has its DDS sockets"
    assert all(a.startswith("127.0.0.1:") or "%lo:" in a for a in sockets), sockets


def test_a_forward_command_from_rclpy_moves_the_elbow_and_cmd_vel_is_refused_and_counted(stack):
    before = newest_status(stack.session)
    target = pose_with(stack.session, ELBOW, 0.9)
    sent = rclpy_node("forward", "4", ",".join(repr(v) for v in target), timeout_s=60)
    assert sent[-1]["matched"] >= 1, "zensim ros2 subscribes the forward command topic over DDS"
    elbow_reaches(stack.session, 0.9)
    after = status_after(stack.session, before.seq)
    assert after.commands_forwarded > before.commands_forwarded
    # /cmd_vel: no walking service in this zensim: every Twist refused, counted, nothing moves.
    before = newest_status(stack.session)
    twisted = rclpy_node("twist", "3", "0.3", "0.1", timeout_s=60)[-1]
    assert twisted["matched"] >= 1, "zensim ros2 subscribes /cmd_vel over DDS"
    # Those sent before DDS discovery matched the two are lost (a loaded machine took over a second): at
    # least some arrived, and every one that did was refused.
    after = wait_for(lambda: (s := newest_status(stack.session)).rejected >= before.rejected + 10 and s, 10,
                     f"the Twists to be counted as refused ({twisted['sent']} sent)")
    assert "walking" in (after.last_error or "")
    assert after.commands_forwarded == before.commands_forwarded


# --- Zenoh: rmw_zenoh's format, golden against the design document --------------------------------------


def test_zenoh_keys_tokens_attachments_follow_rmw_zenoh_and_payloads_decode_with_rclpy(stack):
    samples: list[zenoh.Sample] = []
    lock = threading.Lock()

    def keep(sample: zenoh.Sample) -> None:
        with lock:
            samples.append(sample)

    sub = stack.session.declare_subscriber(f"{DOMAIN}/**", keep)
    try:
        wait_for(lambda: len({str(s.key_expr) for s in samples}) >= 5 and len(samples) > 300, 20,
                 "samples of every zensim ros2 topic on Zenoh")
    finally:
        sub.undeclare()
    with lock:
        got = list(samples)
    per_key: dict[str, list[int]] = {}
    to_decode: list[tuple[str, bytes]] = []
    for sample in got:
        key = str(sample.key_expr)
        match = DATA_KEY.match(key)
        assert match, f"{key} is not rmw_zenoh's <domain>/<topic>/<type>/<hash>"
        if str(sample.key_expr) not in per_key or len(per_key[str(sample.key_expr)]) < 20:
            to_decode.append((match["type"], sample.payload.to_bytes()))
        raw = sample.attachment.to_bytes()
        assert len(raw) == 33 and raw[16] == 16, "the attachment: int64 seq, int64 time, 16-byte GID"
        seq, ts = struct.unpack_from("<qq", raw)
        assert abs(ts - time.time_ns()) < 60e9
        assert zenoh.ext.z_deserialize(tuple[zenoh.ext.Int64, zenoh.ext.Int64, bytes], sample.attachment)[0] == seq
        per_key.setdefault(key, []).append(seq)
    for key, seqs in per_key.items():
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{key}: sequence numbers count up by one"
    # rclpy's own decoder (rosbags' for tf2_msgs, which has no wheel) reads every payload, 20 per topic.
    decoded = ros2_client.deserialize(*to_decode)
    assert len(decoded) == len(to_decode)
    assert {d["child_frame_id"] for d in decoded if "child_frame_id" in d} == {"pelvis"}
    tokens = [str(r.ok.key_expr) for r in stack.session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=5)
              if r.ok is not None]
    nodes = [t for t in tokens if NODE_TOKEN.match(t)]
    assert len(nodes) == 1, tokens
    zid = NODE_TOKEN.match(nodes[0])["zid"]
    endpoints = {(m["kind"], m["topic"]): m for t in tokens if (m := ENDPOINT_TOKEN.match(t))}
    assert len(endpoints) == len(tokens) - 1, f"every other token is an endpoint of the node: {tokens}"
    assert all(m["zid"] == zid for m in endpoints.values())
    expected = {("MP", "%joint_states"): "::,10:,:,:,,", ("MP", "%robot_description"): ":1:,1:,:,:,,",
                ("MP", "%odom"): "::,10:,:,:,,", ("MP", "%imu"): "::,10:,:,:,,", ("MP", "%clock"): "::,10:,:,:,,",
                ("MP", "%tf"): "::,100:,:,:,,", ("MS", "%forward_position_controller%commands"): "::,10:,:,:,,",
                ("MS", "%joint_trajectory_controller%joint_trajectory"): "::,10:,:,:,,", ("MS", "%cmd_vel"): "::,10:,:,:,,"}
    assert {k: m["qos"] for k, m in endpoints.items()} == expected
    for (kind, topic), m in endpoints.items():
        if kind == "MP" and topic != "%robot_description":  # latched: published once, at start
            data_keys = [k for k in per_key if k.startswith(f"{DOMAIN}/{topic[1:].replace('%', '/')}/")]
            assert data_keys == [f"{DOMAIN}/{topic[1:].replace('%', '/')}/{m['type']}/{m['hash']}"], (topic, data_keys)


def test_a_late_zenoh_subscriber_gets_the_latched_robot_description(stack):
    """Through the advanced publisher's cache, as an rmw_zenoh transient-local subscription asks for it."""
    urdf = next(iter(stack.session.get(KEYS.urdf, timeout=10))).ok.payload.to_bytes().decode()
    got: list[bytes] = []
    sub = zenoh.ext.declare_advanced_subscriber(
        stack.session, f"{DOMAIN}/robot_description/std_msgs::msg::dds_::String_/*",
        handler=lambda s: got.append(s.payload.to_bytes()),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
    try:
        wait_for(lambda: got, 10, "robot_description from the cache")
    finally:
        sub.undeclare()
    assert ros2_client.deserialize(("std_msgs/msg/String", got[0]))[0]["data"] == urdf


def zenoh_command(session, topic: str, ros_type: str, payload: bytes, attachment: bytes | None = None,
                  seq: int = 1, block: bool = True) -> None:
    type_hash = {"std_msgs::msg::dds_::Float64MultiArray_": "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
                 "trajectory_msgs::msg::dds_::JointTrajectory_": "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
                 "geometry_msgs::msg::dds_::Twist_": "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"}[ros_type]
    if attachment is None:
        attachment = struct.pack("<qqB", seq, time.time_ns(), 16) + bytes(range(16))
    # Blocking, not dropped when the loaded machine backs the link up: every message sent must be counted.
    # A flood is sent as rmw_zenoh's keep-last publishers send (congestion control DROP).
    session.put(f"{DOMAIN}/{topic}/{ros_type}/{type_hash}", payload, attachment=attachment,
                congestion_control=zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP)


FORWARD = ("forward_position_controller/commands", "std_msgs::msg::dds_::Float64MultiArray_")
TRAJECTORY = ("joint_trajectory_controller/joint_trajectory", "trajectory_msgs::msg::dds_::JointTrajectory_")


def trajectory(names: list[str], positions: list[float]) -> bytes:
    return ros2_client.serialize({"type": "trajectory_msgs/msg/JointTrajectory", "joint_names": names,
                                  "points": [{"positions": positions}]})[0]



def test_a_trajectory_over_zenoh_moves_the_elbow(stack):
    goal = trajectory([ELBOW], [0.4])
    for seq in range(1, 11):
        zenoh_command(stack.session, *TRAJECTORY, goal, seq=seq)
        time.sleep(0.05)
    elbow_reaches(stack.session, 0.4)


def test_bad_ros2_input_is_refused_whole_counted_and_outputs_keep_their_rate(stack):
    names = list(ctl(stack.session, KEYS.robot_info)["joint_names"])
    good = pose_with(stack.session, ELBOW, 0.2)
    f64, traj = "std_msgs/msg/Float64MultiArray", "trajectory_msgs/msg/JointTrajectory"
    short, nan, inf, far, whole, unknown, twice = ros2_client.serialize(
        *({"type": f64, "data": data} for data in (good[:-1], [math.nan] + good[1:], [math.inf] + good[1:],
                                                   [*good[:-1], 1e6], good)),
        {"type": traj, "joint_names": ["no_such_joint"], "points": [{"positions": [0.1]}]},
        {"type": traj, "joint_names": [ELBOW, ELBOW], "points": [{"positions": [0.1, 0.2]}]})
    bad: list[tuple[tuple[str, str], bytes, bytes | None]] = [
        (FORWARD, short, None),  # one position short
        (FORWARD, nan, None),  # NaN
        (FORWARD, inf, None),  # infinity
        (FORWARD, far, None),  # beyond the joint's limit
        (TRAJECTORY, unknown, None),  # unknown joint
        (TRAJECTORY, twice, None),  # a joint named twice
        (FORWARD, whole[:40], None),  # truncated CDR
        (FORWARD, b"\x00\x01\x00\x00" + b"\xff" * 64, None),  # garbage CDR (a count of 4 billion)
        (FORWARD, b"garbage", None),  # not CDR at all
        (FORWARD, whole, b""),  # an attachment that is not rmw_zenoh's
        (FORWARD, b"\x00\x01\x00\x00" + bytes(100_000), None),  # oversize
    ]
    before = newest_status(stack.session)
    state = Latest(stack.session, KEYS.joints, JointState)
    elbow_before = state.wait(timeout_s=10, what="state/joints").q[names.index(ELBOW)]
    for n, ((topic, ros_type), payload, attachment) in enumerate(bad):
        zenoh_command(stack.session, topic, ros_type, payload, attachment, seq=n + 1)
    # A sample with no attachment at all (rmw_zenoh drops those too).
    stack.session.put(f"{DOMAIN}/{FORWARD[0]}/{FORWARD[1]}/RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
                      whole, congestion_control=zenoh.CongestionControl.BLOCK)
    after = wait_for(lambda: (s := newest_status(stack.session)).rejected >= before.rejected + len(bad) + 1 and s, 20,
                     "every bad message to be counted")
    assert after.rejected == before.rejected + len(bad) + 1
    assert after.commands_forwarded == before.commands_forwarded, "nothing of a refused message is applied"
    time.sleep(0.5)
    assert state.value.q[names.index(ELBOW)] == pytest.approx(elbow_before, abs=0.02)
    # A flood of garbage: shed and counted; the joint states keep coming at about their rate.
    flood_start = newest_status(stack.session)
    end = time.monotonic() + 3
    n = 0
    while time.monotonic() < end:
        zenoh_command(stack.session, *FORWARD, b"\x00\x01\x00\x00" + b"\xff" * 64, seq=n, block=False)
        n += 1
        if n % 10 == 0:
            time.sleep(0.005)  # about 2000 a second: ten times what the gateway passes on
    during = status_after(stack.session, flood_start.seq)
    assert during.joint_states_rate_hz > 50, f"joint states at {during.joint_states_rate_hz:.0f} Hz during a flood"
    assert stack.gateway.alive()
    # Sent with DROP, some may be lost on the way on a loaded machine: most are counted, none applied.
    final = wait_for(lambda: (s := newest_status(stack.session)).rejected >= flood_start.rejected + n * 0.5 and s, 20,
                     f"the {n} flooded messages to be counted")
    assert final.commands_forwarded == before.commands_forwarded
    assert "Traceback" not in stack.gateway.log()
    log_lines = [line for line in stack.gateway.log().splitlines() if "rejected ROS 2 message" in line]
    assert len(log_lines) < 20, f"{len(log_lines)} log lines for {n} refused messages: the log is rate-limited"


def test_sigterm_stops_zensim_ros2_within_two_seconds_and_its_tokens_go(tmp_path):
    stack = Ros2Stack(tmp_path)
    try:
        wait_for(lambda: [r for r in stack.session.liveliness().get(KEYS.alive("ros2"), timeout=2) if r.ok], 10,
                 "alive/ros2")
        t0 = time.monotonic()
        assert stack.gateway.stop(timeout_s=5) == 0, stack.gateway.log()[-3000:]
        assert time.monotonic() - t0 < 2.5
        wait_for(lambda: not [r for r in stack.session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=2)
                              if r.ok is not None], 10, "zensim ros2's ROS 2 tokens to go")
    finally:
        stack.close()


def test_zensim_up_ros2_runs_the_face_beside_the_others(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_UP_ROUTER_ENDPOINT=endpoint, ZENSIM_ROS2_DOMAIN_ID=str(DOMAIN),
               ZENSIM_ROS2_TRANSPORTS="zenoh", ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    up = Service("up", ["--ros2", "--viz", "false"], env, tmp_path)
    session = plain_client(endpoint, wait_for_router=True)
    try:
        wait_for(lambda: [r for r in session.liveliness().get(KEYS.alive("ros2"), timeout=2) if r.ok], 90,
                 "alive/ros2 from `zensim up --ros2`")
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=5) if r.ok]
        assert any(NODE_TOKEN.match(t) for t in tokens), tokens
    finally:
        session.close()
        assert up.stop(timeout_s=15) == 0, up.log()[-3000:]


def test_secured_ros2_face_serves_an_operators_ros2_node_and_a_viewer_cannot_drive(tmp_path):
    """Under `--secure-dir`, `zensim ros2` runs with its own role; a ROS 2 node with the operator's
    credentials reads rmw_zenoh's keys and drives the robot, one with the viewer's reads but its commands
    never reach the face."""
    secrets = tmp_path / "secrets"
    made = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(secrets), "--ros-domain",
                           str(DOMAIN)], capture_output=True, text=True, timeout=60)
    assert made.returncode == 0, made.stderr
    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(secrets), ZENSIM_ROBOT_ID="g1", PYTHONUNBUFFERED="1",
               ZENSIM_ZENOH_CONNECT=endpoint)
    services = [Service("router", ["--zenoh-listen", endpoint], dict(env, ZENSIM_ZENOH_CONNECT=""), tmp_path)]
    sessions = []
    try:
        wait_for(lambda: "router up" in services[0].log() or not services[0].alive(), 20, "the secured router")
        services += [Service("sim", ["--mode", "fixed"], env, tmp_path), Service("bridge", [], env, tmp_path),
                     Service("ros2", ["--domain-id", str(DOMAIN), "--transports", "zenoh", "--status-rate-hz", "10"],
                             env, tmp_path)]
        wait_for(lambda: "ros2 face up" in services[-1].log() or not services[-1].alive(), 60, "zensim ros2")

        def client(role: str) -> zenoh.Session:
            conf = zenoh.Config.from_file(str(secrets / f"{role}.json5"))
            conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
            sessions.append(zenoh.open(conf))
            return sessions[-1]

        operator, viewer = client("operator"), client("viewer")
        for session in (operator, viewer):
            got: list[bytes] = []
            sub = session.declare_subscriber(f"{DOMAIN}/joint_states/**", lambda s, got=got: got.append(s.payload.to_bytes()))
            wait_for(lambda got=got: len(got) > 10, 20, "joint states on rmw_zenoh's key through the secured router")
            sub.undeclare()
            assert ros2_client.deserialize(("sensor_msgs/msg/JointState", got[-1]))[0]["name"]
        status = Latest(operator, KEYS.ros2_status, Ros2Status)
        before = status.wait(timeout_s=10, what="state/ros2")
        goal = trajectory([ELBOW], [0.7])
        for seq in range(1, 6):
            zenoh_command(viewer, *TRAJECTORY, goal, seq=seq)
        time.sleep(1.0)
        assert status.wait(lambda s: s.seq > before.seq + 5, 10).commands_received == before.commands_received, \
            "the router dropped the viewer's commands"
        for seq in range(1, 11):
            zenoh_command(operator, *TRAJECTORY, goal, seq=seq)
            time.sleep(0.05)
        elbow_reaches(operator, 0.7)
    finally:
        for session in sessions:
            session.close()
        for service in reversed(services):
            service.stop()


def test_a_sim_restarted_with_another_robot_is_learned_again(tmp_path):
    """The face maps the sim's joints to ROS names: after a restart with another robot, /robot_description and
    /joint_states are the new robot's (a new run_id on state/sim: the robot is fetched again)."""
    stack = Ros2Stack(tmp_path)
    descriptions: list[str] = []
    sub = stack.session.declare_subscriber(
        f"{DOMAIN}/robot_description/std_msgs::msg::dds_::String_/*",
        lambda s: descriptions.append(ros2_client.deserialize(("std_msgs/msg/String", s.payload.to_bytes()))[0]["data"]))
    try:
        sim = next(s for s in stack.services if s.command == "sim")
        assert sim.stop() == 0
        urdf = tmp_path / "arm.urdf"
        urdf.write_text(TWO_JOINT_ARM)
        stack.start("sim", "--urdf", str(urdf), "--mode", "fixed")
        wait_for(lambda: any("shoulder" in d and "left_hip" not in d for d in descriptions), 60,
                 "the two-joint arm's robot_description")
        assert "learning the robot again" in stack.gateway.log() and stack.gateway.alive(), stack.logs()
    finally:
        sub.undeclare()
        stack.close()
