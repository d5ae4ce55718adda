"""`zensim record`, `zensim replay` and `zensim resim` as users run them, against real sims on loopback."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from browser import Browser, chromium_binary
from support import Latest, Service, ctl, free_port, wait_for
from test_lockstep_process import advance, scripted_command
from test_secure import role_conf, secrets_dir  # noqa: F401 - the module-scoped fixture
from test_sim_process import put_json, robot_info, wait_alive
from zensim.schemas import JointState, Keys

DISTAL_LINK = "left_wrist_yaw_link"


def zensim(*args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zensim", *args], capture_output=True, text=True, timeout=timeout_s)


def start_recorder(start_service, path: Path, zsession, keys: Keys) -> Service:
    recorder = start_service("record", "-o", str(path))
    wait_for(lambda: "saved the sim's description" in recorder.log() or not recorder.alive(), 30,
             "the recorder to save the description")
    assert recorder.alive(), recorder.log()
    return recorder


def stop_recorder(recorder: Service, signum: int = signal.SIGTERM) -> None:
    recorder.signal(signum)
    assert recorder.proc.wait(15) == 0, recorder.log()


def record_lockstep_run(start_service, zsession, robot_id: str, path: Path, n: int = 120, mode: str = "floating") -> None:
    """A lockstep sim driven by the scripted controller, half through cmd/motors, half through ctl/advance."""
    keys = Keys(robot_id)
    joints = Latest(zsession, keys.joints, JointState)
    start_service("sim", "--clock", "lockstep", "--mode", mode)
    wait_alive(zsession, keys)
    recorder = start_recorder(start_service, path, zsession, keys)
    info = robot_info(zsession, keys)
    q = list(joints.wait(what="the initial state").q)
    for k in range(n):
        command = scripted_command(k, info, q)
        if k % 2:
            q = advance(zsession, keys, command)["joints"]["q"]
        else:
            before = joints.count
            put_json(zsession, keys.motors, command)
            q = list(joints.wait(lambda m, b=before: joints.count > b, what=f"the state after command {k}").q)
    time.sleep(0.3)  # the last states reach the recorder
    stop_recorder(recorder)


class TestRecord:
    def test_lockstep_recording_is_a_valid_mcap_with_schemas_and_resims_to_zero(self, start_service, zsession, robot_id, tmp_path) -> None:
        path = tmp_path / "run.mcap"
        record_lockstep_run(start_service, zsession, robot_id, path)
        with path.open("rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            assert summary is not None and summary.chunk_indexes, "no index: the file was not finished"
            topics = {c.topic: c for c in summary.channels.values()}
            root = f"zensim/{robot_id}"
            for relative, schema in [("state/joints", "joint_state"), ("state/odom", "odometry"), ("state/imu", "imu"),
                                     ("state/contacts", "contacts"), ("state/sim", "sim_status"), ("state/applied", "applied_command"),
                                     ("cmd/motors", "motor_command")]:
                channel = topics[f"{root}/{relative}"]
                assert channel.message_encoding == "json"
                assert summary.schemas[channel.schema_id].name == schema
                assert summary.schemas[channel.schema_id].encoding == "jsonschema"
                assert json.loads(summary.schemas[channel.schema_id].data)["$defs"]
            counts = summary.statistics.channel_message_counts
            by_topic = {summary.channels[c].topic: n for c, n in counts.items()}
            assert by_topic[f"{root}/state/applied"] == 120
            assert by_topic[f"{root}/state/contacts"] >= 120  # one per advance (and the start's): resim compares them
            assert by_topic[f"{root}/cmd/motors"] == 60
            attachments = {a.name: a for a in reader.iter_attachments()}
            assert json.loads(attachments["info/robot"].data)["robot"] == robot_id
            assert attachments["info/urdf"].data.startswith(b"<") and b"<robot" in attachments["info/urdf"].data
            metadata = {m.name: m.metadata for m in reader.iter_metadata()}
            assert metadata["zensim"]["robot_id"] == robot_id
            # Publish time is the sim time; log time the (later, wall-clock) receive time.
            for _schema, channel, message in reader.iter_messages(topics=[f"{root}/state/joints"]):
                state = json.loads(message.data)
                assert message.publish_time == round(state["sim_time_s"] * 1e9)
                assert message.log_time > 1.6e18
        result = zensim("resim", str(path))
        assert result.returncode == 0, result.stderr
        assert "lockstep recording" in result.stdout and "120 commands" in result.stdout, result.stdout
        assert ("joint position 0 rad, base position 0 m, base orientation 0 rad, foot normal force 0 N"
                in result.stdout), result.stdout

    def test_realtime_recording_resims_and_says_what_the_divergence_means(self, start_service, zsession, robot_id, tmp_path) -> None:
        keys = Keys(robot_id)
        path = tmp_path / "rt.mcap"
        start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        recorder = start_recorder(start_service, path, zsession, keys)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            put_json(zsession, keys.motors, {"names": ["left_elbow_joint"], "q": [0.8]})
            time.sleep(0.02)
        # A mode switch: the recorder saves the new description too; resim re-simulates the longer segment.
        assert ctl(zsession, keys.ctl("mode"), {"mode": "floating"})["mode"] == "floating"
        wait_for(lambda: recorder.log().count("saved the sim's description") == 2, 20, "the second description saved")
        stop_recorder(recorder)
        with path.open("rb") as stream:
            modes = [json.loads(a.data)["mode"] for a in make_reader(stream).iter_attachments() if a.name == "info/robot"]
        assert modes == ["fixed", "floating"]
        result = zensim("resim", str(path))
        assert result.returncode == 0, result.stderr
        # The switch resets (time starts over), then the status says floating: two cuts, the fixed run is longest.
        assert re.search(r"has [23] segments", result.stdout) and "the longest, fixed mode" in result.stdout, result.stdout
        assert "real-time recording" in result.stdout and "measures how much the run depended" in result.stdout
        joint = float(result.stdout.split("joint position ")[1].split(" rad")[0])
        compared = int(result.stdout.split(" states compared")[0].rsplit(", ", 1)[1])
        assert compared > 100, result.stdout
        # The fixed-base arm follows the same command either way; a command applied up to 10 ms off its
        # real step shifts a fast elbow move by a few hundredths of a radian, never by the whole move.
        assert 0 <= joint < 0.4, result.stdout

    def test_recorder_skips_and_counts_bad_samples(self, start_service, zsession, robot_id, tmp_path) -> None:
        keys = Keys(robot_id)
        path = tmp_path / "bad.mcap"
        recorder = start_service("record", "-o", str(path))
        wait_for(lambda: "recording zensim/" in recorder.log(), 30, "the recorder to start")
        time.sleep(0.5)
        zsession.put(keys.motors, b"\xc1 not msgpack")
        zsession.put(keys.joint_target("left_knee_joint"), "0.5")
        zsession.put(keys.joint_target("left_knee_joint"), "nan")
        wait_for(lambda: "not recorded" in recorder.log(), 10, "the bad sample logged")
        time.sleep(0.3)
        stop_recorder(recorder, signal.SIGINT)  # Ctrl-C finishes the file as SIGTERM does
        assert "2 samples not recorded" in recorder.log()
        with path.open("rb") as stream:
            messages = [json.loads(m.data) for _s, _c, m in make_reader(stream).iter_messages()]
        assert messages == [{"value": 0.5}]

    def test_progress_line_on_a_terminal(self, service_env, robot_id, tmp_path) -> None:
        main_fd, terminal_fd = os.openpty()
        proc = subprocess.Popen([sys.executable, "-m", "zensim", "record", "-o", str(tmp_path / "p.mcap")],
                                env=service_env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=terminal_fd, start_new_session=True)
        os.close(terminal_fd)
        seen = b""
        try:
            deadline = time.monotonic() + 30
            while b"messages" not in seen or b" MB" not in seen:
                assert time.monotonic() < deadline, seen
                ready, _, _ = select.select([main_fd], [], [], 1.0)
                if ready:
                    seen += os.read(main_fd, 4096)
        finally:
            proc.send_signal(signal.SIGINT)
            assert proc.wait(15) == 0
            os.close(main_fd)
        assert re.search(rb"recording .*p\.mcap: +[0-9.]+ s +[0-9]+ messages +[0-9.]+ MB", seen), seen


@pytest.fixture
def browser():
    if chromium_binary() is None:
        pytest.fail("chromium is needed: apt-get install -y --no-install-recommends chromium")
    with Browser(width=1000, height=700) as b:
        yield b


class TestReplay:
    def test_replay_refuses_a_robot_id_a_live_sim_serves(self, start_service, zsession, robot_id, tmp_path, service_env) -> None:
        path = tmp_path / "run.mcap"
        record_lockstep_run(start_service, zsession, robot_id, path, n=10)
        replay = start_service("replay", str(path))
        assert replay.proc.wait(20) == 2
        assert "already served by a live sim" in replay.log()

    def test_replay_drives_the_viewer(self, start_service, zsession, robot_id, tmp_path, browser) -> None:
        path = tmp_path / "run.mcap"
        # Fixed base: the arms swing in place, the view stays on the robot.
        record_lockstep_run(start_service, zsession, robot_id, path, n=150, mode="fixed")
        replay_id = robot_id + "r"
        port = free_port()
        start_service("viz", "--port", str(port), env={"ZENSIM_ROBOT_ID": replay_id})
        replayed = Latest(zsession, Keys(replay_id).joints, JointState)
        replay = start_service("replay", str(path), "--robot-id", replay_id, "--rate", "0.1")
        browser.goto(f"http://127.0.0.1:{port}/")
        browser.wait("window.zensim && zensim.sceneReady", 60, "the replayed robot drawn")
        positions = []

        def moved() -> bool:
            positions.append(browser.eval(f"zensim.linkPosition('robot', '{DISTAL_LINK}')"))
            return np.ptp(np.array(positions), axis=0).max() > 0.05

        wait_for(moved, 40, "the replayed robot's hand moving on the page", interval_s=0.3)
        assert replayed.value is not None and replay.alive(), replay.log()
        assert "sim" in browser.eval("zensim.status.alive")


def test_bad_files_get_one_line_and_exit_code_2(tmp_path) -> None:
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("root:x:0:0\n")
    truncated = tmp_path / "cut.mcap"
    truncated.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    for args in (("resim", str(not_mcap)), ("replay", str(not_mcap)), ("resim", str(truncated)),
                 ("resim", str(tmp_path / "missing.mcap")), ("replay",), ("record", "-o", str(tmp_path / "no/such/dir.mcap"))):
        result = zensim(*args, timeout_s=30)
        assert result.returncode == 2, (args, result.stdout, result.stderr)
        assert "Traceback" not in result.stderr, (args, result.stderr)
        assert result.stderr.strip().splitlines()[-1].startswith(f"zensim {args[0]}: "), (args, result.stderr)


def test_secured_lockstep_run_is_recorded_whole_and_resims_to_zero(secrets_dir, tmp_path, robot_id) -> None:
    """Secured network (TLS, passwords, access roles): the sim's role may publish state/applied, the
    recorder reads everything as the operator, the operator drives ctl/advance."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(secrets_dir), ZENSIM_ROBOT_ID=robot_id, PYTHONUNBUFFERED="1")
    keys, path = Keys(robot_id), tmp_path / "secured.mcap"
    router = Service("router", ["--zenoh-listen", endpoint], env, tmp_path)
    started = [router]
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 20, "the secured router")
        started.append(Service("sim", ["--zenoh-connect", endpoint, "--clock", "lockstep"], env, tmp_path))
        recorder = Service("record", ["-o", str(path), "--zenoh-connect", endpoint], env, tmp_path)
        started.append(recorder)
        wait_for(lambda: "saved the sim's description" in recorder.log() or not recorder.alive(), 30,
                 "the recorder to save the description")
        with zenoh.open(role_conf(secrets_dir, "operator", endpoint)) as operator:
            info = robot_info(operator, keys)
            q = list(info["default_q"][info["mode"]])
            for k in range(20):
                q = advance(operator, keys, scripted_command(k, info, q))["joints"]["q"]
        time.sleep(0.3)
        stop_recorder(recorder)
    finally:
        for service in reversed(started):
            service.stop()
    result = zensim("resim", str(path))
    assert result.returncode == 0, result.stderr
    assert "20 commands, 20 states compared" in result.stdout, result.stdout
    assert "joint position 0 rad, base position 0 m, base orientation 0 rad" in result.stdout, result.stdout
