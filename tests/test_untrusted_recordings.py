"""Recordings as untrusted input, and the recorder under hostile samples (issue 18, finding 4).

Any client may publish on the keys a recorder records, and anyone may hand a user an MCAP file.
So: the recorder never writes what a strict JSON reader refuses, and stops at a size bound; resim
and replay read a forged or damaged file with one-line notes and errors, never a traceback or a
hang; a sim and a replay never serve the same robot id at once.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import msgspec
import pytest
from mcap.reader import make_reader

from support import Latest, free_port, wait_for, wait_subscribed
from test_record_process import stop_recorder, zensim
from zensim.mcapfile import ROBOT_INFO_ATTACHMENT, URDF_ATTACHMENT, RecordingWriter
from zensim.robots import robot_files
from zensim.schemas import AppliedCommand, Codec, JointState, Keys, MotorCommand, SimStatus
from zensim.robots.builder import ModeFigures
from zensim.sim.physics import Limits
from zensim.sim.world import World


def strict_loads(data: bytes) -> object:
    """JSON as Foxglove and other strict readers take it: NaN and Infinity are errors."""
    def refuse(name: str) -> object:
        raise ValueError(f"{name} in a JSON document")
    return json.loads(data, parse_constant=refuse)


def recorded(path: Path) -> list[tuple[str, object]]:
    with path.open("rb") as stream:
        return [(channel.topic, strict_loads(message.data))
                for _schema, channel, message in make_reader(stream).iter_messages()]


# --------------------------------------------------------------------------------------- the recorder
class TestRecorderUnderHostileSamples:
    def test_non_finite_numbers_are_not_recorded_and_strict_readers_read_the_file(
            self, start_service, zsession, robot_id, tmp_path) -> None:
        keys, path = Keys(robot_id), tmp_path / "nan.mcap"
        recorder = start_service("record", "-o", str(path))
        wait_for(lambda: "recording zensim/" in recorder.log(), 30, "the recorder to start")
        wait_subscribed(zsession, keys.joints, 10, "the recorder's subscription")
        codec = Codec(JointState)
        good = JointState(sim_time_s=1.0, seq=1, q=(0.1, 0.2), dq=(0.0, 0.0), tau=(0.0, 0.0))
        for q in ((float("nan"), 0.2), (float("inf"), 0.2)):
            zsession.put(keys.joints, codec.encode(msgspec.structs.replace(good, q=q), "msgpack"))
        zsession.put(f"{keys.root}/custom/note", b'{"x": NaN}')
        zsession.put(f"{keys.root}/custom/note", b'{"x": 1e999}')
        zsession.put(f"{keys.root}/custom/{'k' * 300}", b'{"x": 1}')
        zsession.put(keys.joints, codec.encode(good, "msgpack"))
        zsession.put(f"{keys.root}/custom/note", b'{"x": 2}')
        wait_for(lambda: "not recorded" in recorder.log(), 10, "the refused samples logged")
        time.sleep(1.0)
        stop_recorder(recorder)
        assert "5 samples not recorded" in recorder.log(), recorder.log()
        messages = recorded(path)  # raises on NaN/Infinity
        assert [m for k, m in messages if k == keys.joints] == [json.loads(codec.encode(good, "json"))]
        assert [m for k, m in messages if k.endswith("/custom/note")] == [{"x": 2}]
        assert not any("kkkk" in k for k, _ in messages)

    def test_max_bytes_ends_the_recording_with_a_complete_file(self, start_service, zsession, robot_id, tmp_path) -> None:
        keys, path = Keys(robot_id), tmp_path / "bounded.mcap"
        recorder = start_service("record", "-o", str(path), "--max-bytes", "200000")
        wait_for(lambda: "recording zensim/" in recorder.log(), 30, "the recorder to start")
        wait_subscribed(zsession, keys.joints, 10, "the recorder's subscription")
        codec = Codec(JointState)
        q = tuple(0.001 * i for i in range(29))
        deadline = time.monotonic() + 30
        seq = 0
        while recorder.alive() and time.monotonic() < deadline:
            for _ in range(200):
                seq += 1
                zsession.put(keys.joints, codec.encode(JointState(sim_time_s=seq * 0.01, seq=seq, q=q, dq=q, tau=q),
                                                       "msgpack"))
            time.sleep(0.02)
        assert recorder.proc.wait(15) == 0, recorder.log()
        assert "stopped at --max-bytes 200000" in recorder.log()
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
        assert summary is not None and summary.chunk_indexes, "the file was not finished"
        assert path.stat().st_size < 400_000, path.stat().st_size


# ------------------------------------------------------------------------------------ forged files
def write_recording(path: Path, robot_id: str, items: list[tuple[str, object]], *, metadata_robot: str | None = "g1",
                    info: bool = True) -> None:
    """An MCAP file laid out as `zensim record` writes it, holding exactly `items` (relative key, message)."""
    (sim,) = World.alone("g1", robot_files("g1"), "fixed", Limits(max_kp=5000, max_kd=500), watchdog_timeout_s=0.5).robots
    keys = Keys(robot_id)
    with path.open("wb") as stream:
        writer = RecordingWriter(stream, metadata_robot or "g1")
        if metadata_robot is None:  # a file whose metadata lost its robot id
            writer._writer.add_metadata("zensim", {"format_version": "1"})  # noqa: SLF001 - forging on purpose
        if info:
            robot = sim.robot
            robot_info = sim.robot_info(keys, 100.0, 10.0, {"fixed": ModeFigures(robot.default_q, robot.kp, robot.kd,
                                                                                 robot.base_height_m)})
            writer.attach(ROBOT_INFO_ATTACHMENT, "application/json", msgspec.json.encode(robot_info), 1)
            writer.attach(URDF_ATTACHMENT, "application/xml", b"<robot name='g1'/>", 1)
        for n, (relative, message) in enumerate(items):
            if isinstance(message, (bytes, str)):
                data = message.encode() if isinstance(message, str) else message
                message_type = None
            else:
                data = msgspec.json.encode(message)
                message_type = type(message)
            log_time_ns = 1_000_000_000 + n * 10_000_000  # 100 messages a second
            writer.write(f"{keys.root}/{relative}", message_type, data, log_time_ns, log_time_ns)
        writer.finish()


def lockstep_states(steps: int = 10, commands: int = 5) -> list[tuple[str, Any]]:
    """A short genuine lockstep run of the fixed-base G1: states, each command applied, the states after it."""
    world = World.alone("g1", robot_files("g1"), "fixed", Limits(max_kp=5000, max_kd=500), watchdog_timeout_s=0.5)
    (sim,) = world.robots
    sim.watchdog_enabled = False

    def states(seq: int) -> list[tuple[str, object]]:
        joints, odom, _imu, _contacts = world.reader.read(world.data, [seq])[0]
        return [("state/joints", joints), ("state/odom", odom)]

    items = states(0)
    q = sim.robot.default_q.tolist()
    for k in range(commands):
        q[0] += 0.05
        command = MotorCommand(q=tuple(q))
        applied = AppliedCommand(sim_time_s=sim.sim_time_s, seq=k + 1, steps=steps, command=command)
        sim.accept_command(command)
        world.step(steps, held=True)  # as the sim advances a lockstep command
        items += [*states(k + 1), ("state/applied", applied)]
    return items


def one_line_error_or_notes(result) -> None:
    assert "Traceback" not in result.stderr + result.stdout, result.stderr


class TestForgedRecordings:
    def test_a_genuine_file_resims_to_zero(self, tmp_path) -> None:
        """The forgery tests below start from this file: it must be a valid lockstep recording."""
        path = tmp_path / "genuine.mcap"
        write_recording(path, "g1", lockstep_states())
        result = zensim("resim", str(path), "--budget-s", "60", timeout_s=60)
        assert result.returncode == 0, result.stderr
        assert "joint position 0 rad" in result.stdout, result.stdout

    def test_forged_steps_and_far_times_finish_within_the_budget(self, tmp_path) -> None:
        items = lockstep_states()
        forged_command = AppliedCommand(sim_time_s=0.1, seq=99, steps=10**12, command=MotorCommand(q=(0.0,) * 29))
        far_state = msgspec.structs.replace(items[0][1], sim_time_s=1e9, seq=98)
        far_odom = msgspec.structs.replace(items[1][1], sim_time_s=1e9, seq=98)
        lockstep = tmp_path / "forged-steps.mcap"
        write_recording(lockstep, "g1", items + [("state/applied", forged_command)])
        realtime = tmp_path / "forged-time.mcap"
        genuine_states = [item for item in items if item[0] != "state/applied"]
        write_recording(realtime, "g1", genuine_states + [("cmd/motors", MotorCommand(q=(0.0,) * 29)),
                                                          ("state/joints", far_state), ("state/odom", far_odom)])
        for path, what in ((lockstep, "not something a sim runs"), (realtime, "was not stepped through")):
            started = time.monotonic()
            result = zensim("resim", str(path), "--budget-s", "20", timeout_s=60)
            assert time.monotonic() - started < 40, "resim did not keep to its budget"
            one_line_error_or_notes(result)
            assert result.returncode in (0, 1), result.stderr
            assert what in result.stdout, result.stdout

    def test_damaged_files_get_notes_or_one_line_errors(self, tmp_path) -> None:
        genuine = lockstep_states()
        short_q = msgspec.structs.replace(genuine[2][1], q=(0.1, 0.2))
        damaged = tmp_path / "damaged.mcap"
        write_recording(damaged, "g1", genuine[:2] + [("cmd/joint/left_knee_joint", b"[]"), ("state/joints", short_q)]
                        + genuine[2:])
        result = zensim("resim", str(damaged), timeout_s=60)
        one_line_error_or_notes(result)
        assert result.returncode == 0, result.stderr
        assert "1 messages of the file did not decode" in result.stdout, result.stdout
        no_robot = tmp_path / "no-robot.mcap"
        write_recording(no_robot, "g1", genuine, metadata_robot=None)
        for command in ("resim", "replay"):
            result = zensim(command, str(no_robot), timeout_s=60)
            one_line_error_or_notes(result)
            assert result.returncode == 2, result.stderr
            assert result.stderr.strip().splitlines()[-1].startswith(f"zensim {command}: "), result.stderr


# ------------------------------------------------------------------------------- one id, one source
class TestOneSourcePerRobotId:
    def test_a_sim_refuses_an_id_a_replay_serves_and_says_who(self, start_service, zsession, robot_id, tmp_path) -> None:
        path = tmp_path / "run.mcap"
        write_recording(path, robot_id, lockstep_states(commands=50))
        replay = start_service("replay", str(path), "--rate", "0.05")
        Latest(zsession, Keys(robot_id).joints, JointState).wait(what="the replay's first state", timeout_s=30)
        sim = start_service("sim", "--mode", "fixed")
        assert sim.proc.wait(30) == 2, sim.log()
        assert "already served by a `zensim replay`" in sim.log(), sim.log()
        assert replay.alive(), replay.log()

    def test_a_replay_refuses_an_id_a_sim_serves(self, start_service, zsession, robot_id, tmp_path) -> None:
        path = tmp_path / "run.mcap"
        write_recording(path, robot_id, lockstep_states())
        start_service("sim", "--mode", "fixed")
        Latest(zsession, Keys(robot_id).sim_status, SimStatus).wait(what="the sim's status", timeout_s=30)
        replay = start_service("replay", str(path))
        assert replay.proc.wait(20) == 2, replay.log()
        assert "already served by a live sim" in replay.log(), replay.log()


def test_junk_keys_put_before_a_controller_starts_never_crowd_its_channels_out(start_service, zsession, robot_id,
                                                                              tmp_path) -> None:
    """Issue 27 item 6: 1100 junk keys put before a controller started used up the recorder's 1000 channels,
    and 0 of its 300 `cmd/motors` were recorded (resim then found 0 commands). The protocol's keys now
    always get their channel; invented keys share a budget of their own."""
    keys, path = Keys(robot_id), tmp_path / "junk.mcap"
    recorder = start_service("record", "-o", str(path))
    wait_for(lambda: "recording zensim/" in recorder.log(), 30, "the recorder to start")
    time.sleep(0.5)
    for i in range(1100):
        zsession.put(f"{keys.root}/junk/k{i}", json.dumps({"junk": i}))
    time.sleep(1.0)  # the junk is in before the controller starts
    codec = Codec(MotorCommand)
    for i in range(300):
        zsession.put(keys.motors, codec.encode(MotorCommand(names=("left_elbow_joint",), q=(0.001 * i,)), "msgpack"))
        time.sleep(0.001)
    time.sleep(1.0)
    stop_recorder(recorder)
    topics = [topic for topic, _ in recorded(path)]
    motors = topics.count(keys.motors)
    junk_channels = len({topic for topic in topics if "/junk/" in topic})
    assert motors == 300, (motors, len(topics), recorder.log()[-2000:])
    assert junk_channels <= 200, junk_channels  # still bounded
