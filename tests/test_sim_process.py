"""The sim service as users run it: `python -m zensim sim`, a router, plain zenoh clients on loopback."""

from __future__ import annotations

import json
import random
import signal
import struct
import time
from pathlib import Path

import msgspec
import pytest
import zenoh

from support import Latest, ctl, wait_for
from zensim.schemas import Imu, JointState, Keys, Odometry, RobotInfo, SimStatus

STARTUP_S = 30.0


def sim_keys(robot_id: str) -> Keys:
    return Keys(robot_id)


def wait_alive(session: zenoh.Session, keys: Keys, service: str = "sim", timeout_s: float = STARTUP_S) -> None:
    def seen() -> bool:
        return any(r.ok is not None for r in session.liveliness().get(keys.alive(service), timeout=1.0))

    wait_for(seen, timeout_s, f"alive/{service}", interval_s=0.1)


def robot_info(session: zenoh.Session, keys: Keys) -> dict:
    replies = list(session.get(keys.robot_info + "?format=json", timeout=5.0))
    return json.loads(replies[0].ok.payload.to_bytes())


def joint_index(info: dict, name: str) -> int:
    return info["joint_names"].index(name)


def put_json(session: zenoh.Session, key: str, message: dict) -> None:
    """What a client in any language does: JSON text, no zensim import, no encoding set."""
    session.put(key, json.dumps(message))


def command_until(session: zenoh.Session, key: str, message: dict, done, what: str, timeout_s: float = 10.0) -> None:
    """Send `message` every 20 ms, as a controller would, until `done()` holds.

    A single command would race the sim's watchdog (0.5 s of silence drops it to the default pose),
    and how fast a joint gets there depends on the machine's load; a stream does not.
    """

    def sent_and_done() -> bool:
        put_json(session, key, message)
        return bool(done())

    wait_for(sent_and_done, timeout_s, what)


class TestStreams:
    def test_state_rates_and_standing_for_30_sim_seconds(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        odom = Latest(zsession, keys.odom, Odometry)
        imu = Latest(zsession, keys.imu, Imu)
        status = Latest(zsession, keys.sim_status, SimStatus)
        odom.keep_history = True
        joints.keep_history = True
        start_service("sim", "--rtf", "0", "--state-rate-hz", "100")
        odom.wait(lambda m: m.sim_time_s >= 30.0, timeout_s=120, what="30 s of sim time")
        heights = [m.pos[2] for m in odom.history if m.sim_time_s > 0.5]
        times = [m.sim_time_s for m in odom.history]
        # 100 Hz in sim time: consecutive states 10 ms apart (a few may be dropped on a busy machine).
        gaps = sorted(b - a for a, b in zip(times, times[1:]))
        assert gaps[len(gaps) // 2] == pytest.approx(0.01, abs=1e-6)
        assert len(odom.history) > 0.8 * 30 * 100
        assert min(heights) > 0.65, f"the G1 sagged or fell: min pelvis z {min(heights):.3f}"
        assert max(heights) < 0.80
        # The streams are in step: a joint state and an odometry with the same seq describe the same
        # instant. (Comparing the newest of each races the two subscriber threads at rtf 0.)
        joint_times = {m.seq: m.sim_time_s for m in list(joints.history)}
        odom_times = {m.seq: m.sim_time_s for m in list(odom.history)}
        both = joint_times.keys() & odom_times.keys()
        assert len(both) > 0.8 * 30 * 100
        assert all(joint_times[seq] == odom_times[seq] for seq in both)
        assert len(joints.value.q) == 29
        assert imu.value.accel[2] == pytest.approx(9.81, abs=1.0)
        assert status.value.fallen is False
        assert status.value.rtf > 1.0  # as fast as possible runs faster than real time

    def test_real_time_pacing(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--rtf", "1", "--state-rate-hz", "50")
        first = joints.wait(what="a first joint state")
        count0, t0 = joints.count, time.monotonic()
        time.sleep(2.0)
        rate = (joints.count - count0) / (time.monotonic() - t0)
        assert 35 < rate < 65, f"state/joints at {rate:.1f} Hz, configured 50"
        assert joints.value.sim_time_s > first.sim_time_s + 1.5
        assert 0.8 < status.value.rtf < 1.2


    def test_wall_clock_state_rate_while_running_as_fast_as_possible(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        start_service("sim", "--rtf", "0", "--state-rate-hz", "50", "--state-clock", "wall")
        first = joints.wait(what="a first joint state")
        count0, t0 = joints.count, time.monotonic()
        time.sleep(2.0)
        rate = (joints.count - count0) / (time.monotonic() - t0)
        assert 35 < rate < 65, f"state/joints at {rate:.1f} Hz of wall time, configured 50"
        # ...while the physics runs many times faster than real time.
        assert joints.value.sim_time_s - first.sim_time_s > 4 * 2.0


class TestCommands:
    def test_json_motor_command_moves_a_joint_and_partial_leaves_others(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        elbow = joint_index(info, "left_elbow_joint")
        knee = joint_index(info, "right_knee_joint")
        joints.wait(what="a first state")
        # Full command: every joint at its default, the left elbow at 0.8.
        q = list(info["default_q"]["fixed"])
        q[elbow] = 0.8
        command_until(zsession, keys.motors, {"q": q}, lambda: abs(joints.value.q[elbow] - 0.8) < 0.03, "the elbow at 0.8")
        # Partial command: only the right knee changes; the elbow keeps its target.
        partial = {"names": ["right_knee_joint"], "q": [0.5]}
        command_until(zsession, keys.motors, partial, lambda: abs(joints.value.q[knee] - 0.5) < 0.03, "the knee at 0.5")
        assert joints.value.q[elbow] == pytest.approx(0.8, abs=0.03)

    def test_1000_malformed_commands_are_counted_and_the_last_good_one_holds(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--mode", "fixed", "--watchdog-timeout-s", "30")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        n = len(info["joint_names"])
        elbow = joint_index(info, "left_elbow_joint")
        good = {"names": ["left_elbow_joint"], "q": [0.6]}
        put_json(zsession, keys.motors, good)
        joints.wait(lambda m: abs(m.q[elbow] - 0.6) < 0.03, what="the good command tracked")

        rng = random.Random(7)
        bad_payloads = [
            lambda: bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 64))),  # random bytes
            lambda: json.dumps({"q": [0.1] * (n - 1)}).encode(),  # wrong length
            lambda: msgspec.msgpack.encode({"q": [float("nan")] * n}),  # NaN
            lambda: json.dumps({"names": ["no_such_joint"], "q": [0.1]}).encode(),  # unknown joint
            lambda: json.dumps({"names": ["left_elbow_joint"], "q": [0.1], "kp": [-5]}).encode(),  # negative gain
            lambda: json.dumps({"names": ["left_elbow_joint", "left_knee_joint"], "q": [-0.5]}).encode(),  # mismatch
        ]
        publisher = zsession.declare_publisher(keys.motors, congestion_control=zenoh.CongestionControl.BLOCK)
        for i in range(1000):
            publisher.put(bad_payloads[i % len(bad_payloads)]())
        # Each is counted: rejected when decoded, or shed unread when a newer one from the same
        # source (this session, which sets no source info) was already waiting behind it.
        last = status.wait(lambda m: m.rejected_commands + m.shed_commands >= 1000, timeout_s=20,
                           what="1000 bad commands counted")
        time.sleep(0.5)
        settled = status.value
        assert settled.rejected_commands + settled.shed_commands == 1000
        assert settled.rejected_commands >= 1
        assert settled.sim_time_s > last.sim_time_s  # still stepping
        assert settled.last_error
        assert joints.value.q[elbow] == pytest.approx(0.6, abs=0.03)

    def test_out_of_range_targets_are_clamped_and_counted(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        elbow = joint_index(info, "left_elbow_joint")
        upper = info["q_max"][elbow]
        joints.wait(what="a first state")
        beyond = {"names": ["left_elbow_joint"], "q": [upper + 5.0]}
        command_until(zsession, keys.motors, beyond, lambda: abs(joints.value.q[elbow] - upper) < 0.05, "the elbow at its limit")
        status.wait(lambda m: m.clamped_commands >= 1, what="a clamped command counted")
        assert joints.value.q[elbow] <= upper + 0.05, "the elbow went past its limit"

    def test_watchdog_engages_and_lets_go(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--mode", "fixed", "--watchdog-timeout-s", "0.3")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        elbow = joint_index(info, "left_elbow_joint")
        default = info["default_q"]["fixed"][elbow]
        status.wait(lambda m: m.watchdog, what="the watchdog holding the default pose before any command")
        joints.wait(what="a first state")

        bend = {"names": ["left_elbow_joint"], "q": [1.0]}

        def tracking() -> bool:
            return not status.value.watchdog and abs(joints.value.q[elbow] - 1.0) < 0.05

        command_until(zsession, keys.motors, bend, tracking, "the watchdog letting go and the command tracked")
        status.wait(lambda m: m.watchdog, timeout_s=5, what="the watchdog engaging after silence")
        joints.wait(lambda m: abs(m.q[elbow] - default) < 0.05, what="the default pose held")
        command_until(zsession, keys.motors, bend, tracking, "the next command taking over")


class TestFalls:
    def test_a_limp_robot_falls_is_reported_and_auto_reset(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        status.keep_history = True
        start_service("sim", "--auto-reset-on-fall", "true", "--fall-reset-delay-s", "0.5")
        wait_alive(zsession, keys)
        n = len(robot_info(zsession, keys)["joint_names"])
        limp = {"q": [0.0] * n, "kp": [0.0] * n, "kd": [0.0] * n}  # motors off: nothing holds it up
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not any(m.resets >= 1 for m in status.history):
            put_json(zsession, keys.motors, limp)
            time.sleep(0.05)
        assert any(m.fallen for m in status.history), "the limp robot was never reported fallen"
        assert status.value.resets >= 1, "no automatic reset after the fall"


class TestControl:
    def test_pause_step_resume_reset_and_mode(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        odom = Latest(zsession, keys.odom, Odometry)
        start_service("sim")
        wait_alive(zsession, keys)
        paused = ctl(zsession, keys.ctl("pause"))
        assert paused["ok"] and paused["paused"]
        time.sleep(0.3)
        t_paused = joints.value.sim_time_s
        time.sleep(0.3)
        assert joints.value.sim_time_s == t_paused, "time moved while paused"

        stepped = ctl(zsession, keys.ctl("step"), {"n": 50})
        assert stepped["ok"]
        assert stepped["steps"] == paused["steps"] + 50
        assert stepped["episode"] == paused["episode"] != "", "stepping is not a new episode"
        joints.wait(lambda m: m.sim_time_s == pytest.approx(t_paused + 50 * 0.002, abs=1e-9), what="the stepped state")

        # Reset to a pose and height of our own, while still paused so that the pose is seen exactly
        # as requested (running, the motors start pulling the knee back to the default pose at once).
        info = robot_info(zsession, keys)
        knee = joint_index(info, "left_knee_joint")
        reset = ctl(zsession, keys.ctl("reset"), {"names": ["left_knee_joint"], "q": [1.2], "base_height_m": 1.5})
        assert reset["ok"] and reset["steps"] == 0 and reset["paused"], "a reset must not resume a paused sim"
        assert reset["episode"] != paused["episode"], "a reset starts a new episode"
        assert robot_info(zsession, keys)["episode"] == reset["episode"]
        state = joints.wait(lambda m: m.sim_time_s == 0.0, what="the state of the reset instant")
        assert state.q[knee] == pytest.approx(1.2, abs=1e-6)
        assert odom.wait(lambda m: m.sim_time_s == 0.0).pos[2] == pytest.approx(1.5, abs=1e-6)

        resumed = ctl(zsession, keys.ctl("resume"))
        assert resumed["ok"] and not resumed["paused"]
        joints.wait(lambda m: m.sim_time_s > 0.05, what="time running again after resume")
        refused = ctl(zsession, keys.ctl("step"), {"n": 1})
        assert not refused["ok"] and "paused" in refused["error"]

        bad = ctl(zsession, keys.ctl("reset"), {"names": ["nope"], "q": [0.0]})
        assert not bad["ok"] and "nope" in bad["error"]
        bad_json = ctl(zsession, keys.ctl("step"), {"n": -3})
        assert not bad_json["ok"] and "`n`" in bad_json["error"]

        # Mode switch: fixed base at 0.79 m with gravity off, and info/robot follows.
        switched = ctl(zsession, keys.ctl("mode"), {"mode": "fixed"})
        assert switched["ok"] and switched["mode"] == "fixed"
        assert switched["episode"] not in (paused["episode"], reset["episode"]), "a mode switch starts a new episode"
        assert robot_info(zsession, keys)["mode"] == "fixed"
        time.sleep(0.5)
        assert odom.value.pos[2] == pytest.approx(info["base_height_m"]["fixed"], abs=1e-6)
        back = ctl(zsession, keys.ctl("reset"), {"mode": "floating"})
        assert back["ok"] and back["mode"] == "floating"
        status = Latest(zsession, keys.sim_status, SimStatus)
        assert status.wait(lambda m: m.episode == back["episode"], what="the status of the new episode")

    def test_info_urdf_and_mesh(self, start_service, zsession, robot_id, tmp_path: Path) -> None:
        urdf = write_mesh_arm(tmp_path)
        keys = sim_keys(robot_id)
        start_service("sim", "--urdf", str(urdf), "--mode", "fixed")
        wait_alive(zsession, keys)
        info = msgspec.msgpack.decode(next(iter(zsession.get(keys.robot_info))).ok.payload.to_bytes(), type=RobotInfo)
        assert info.joint_names == ("shoulder", "elbow")
        assert info.mesh_paths == ("meshes/link.stl",)
        text = next(iter(zsession.get(keys.urdf))).ok.payload.to_string()
        assert text == urdf.read_text()
        mesh = next(iter(zsession.get(keys.mesh("meshes/link.stl")))).ok.payload.to_bytes()
        assert mesh == (tmp_path / "meshes" / "link.stl").read_bytes()
        missing = next(iter(zsession.get(keys.mesh("meshes/nothing.stl"))))
        assert missing.err is not None

    def test_official_g1_serves_its_meshes(self, start_service, zsession, robot_id, official_g1_dir: Path) -> None:
        keys = sim_keys(robot_id)
        start_service("sim", "--urdf", str(official_g1_dir / "g1_29dof.urdf"), "--rtf", "0")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        assert len(info["joint_names"]) == 29
        assert "meshes/pelvis.STL" in info["mesh_paths"]
        mesh = next(iter(zsession.get(keys.mesh("meshes/pelvis.STL"), timeout=10))).ok.payload.to_bytes()
        assert mesh == (official_g1_dir / "meshes" / "pelvis.STL").read_bytes()


class TestProcess:
    def test_sigterm_exits_cleanly_and_the_token_goes(self, start_service, zsession, robot_id) -> None:
        keys = sim_keys(robot_id)
        sim = start_service("sim")
        wait_alive(zsession, keys)
        tokens = []
        zsession.liveliness().declare_subscriber(keys.alive("sim"), lambda s: tokens.append(s.kind))
        start = time.monotonic()
        sim.signal(signal.SIGTERM)
        code = sim.proc.wait(5)
        assert code == 0, sim.log()
        assert time.monotonic() - start < 2.0
        wait_for(lambda: zenoh.SampleKind.DELETE in tokens, 5, "the alive/sim token to go")

    def test_two_sims_with_different_ids_do_not_disturb_each_other(self, start_service, zsession, robot_id) -> None:
        keys_a, keys_b = Keys(robot_id + "a"), Keys(robot_id + "b")
        joints_a = Latest(zsession, keys_a.joints, JointState)
        joints_b = Latest(zsession, keys_b.joints, JointState)
        start_service("sim", "--mode", "fixed", env={"ZENSIM_ROBOT_ID": keys_a.robot})
        start_service("sim", "--mode", "fixed", env={"ZENSIM_ROBOT_ID": keys_b.robot})
        wait_alive(zsession, keys_a)
        wait_alive(zsession, keys_b)
        info = robot_info(zsession, keys_a)
        elbow = joint_index(info, "left_elbow_joint")
        joints_a.wait(what="a first state of sim a")
        bend = {"names": ["left_elbow_joint"], "q": [1.0]}
        command_until(zsession, keys_a.motors, bend, lambda: abs(joints_a.value.q[elbow] - 1.0) < 0.05, "sim a tracking")
        assert joints_b.value.q[elbow] == pytest.approx(info["default_q"]["fixed"][elbow], abs=0.02)
        # Pausing b must leave a running: a's time goes on while b's stands still.
        assert ctl(zsession, keys_b.ctl("pause"))["paused"] is True
        t_a = joints_a.wait(what="a state of sim a").sim_time_s
        joints_a.wait(lambda m: m.sim_time_s > t_a + 0.2, what="sim a stepping while sim b is paused")
        t_b = joints_b.value.sim_time_s
        time.sleep(0.3)
        assert joints_b.value.sim_time_s == t_b, "sim b stepped while paused"


def write_mesh_arm(folder: Path) -> Path:
    """A two-joint arm whose link is an STL mesh (a box), so mesh serving can be checked."""
    (folder / "meshes").mkdir()
    write_box_stl(folder / "meshes" / "link.stl", 0.04, 0.04, 0.3)
    urdf = folder / "arm.urdf"
    inertial = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
    link = f'<visual><geometry><mesh filename="meshes/link.stl"/></geometry></visual>{inertial}'
    urdf.write_text(
        f"""<robot name="arm">
  <link name="base">{inertial}</link>
  <link name="upper">{link}</link>
  <link name="lower">{link}</link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
</robot>
"""
    )
    return urdf


def write_box_stl(path: Path, sx: float, sy: float, sz: float) -> None:
    """A binary STL of a box spanning z in [0, sz]."""
    x, y = sx / 2, sy / 2
    v = [(-x, -y, 0), (x, -y, 0), (x, y, 0), (-x, y, 0), (-x, -y, sz), (x, -y, sz), (x, y, sz), (-x, y, sz)]
    faces = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4),
             (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    data = bytearray(b"\0" * 80 + struct.pack("<I", len(faces)))
    for a, b, c in faces:
        data += struct.pack("<3f", 0, 0, 0) + struct.pack("<9f", *v[a], *v[b], *v[c]) + b"\0\0"
    path.write_bytes(bytes(data))


