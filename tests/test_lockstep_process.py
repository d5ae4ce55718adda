"""The lockstep clock as users run it: `python -m zensim sim --clock lockstep`, plain zenoh clients on loopback."""

from __future__ import annotations

import json
import math
import time

import msgspec
import pytest
import zenoh

from support import Latest, ctl
from test_sim_process import robot_info, wait_alive
from zensim.schemas import AppliedCommand, JointState, Keys, Odometry, SimStatus

DT = 0.002  # the G1's physics step


def advance(session: zenoh.Session, keys: Keys, command: dict) -> dict:
    """One lockstep step the way any client does it: a JSON MotorCommand in, the JSON reply out."""
    replies = list(session.get(keys.ctl("advance"), payload=json.dumps(command), timeout=10.0))
    assert replies and replies[0].ok is not None, "no (good) reply from ctl/advance"
    return json.loads(replies[0].ok.payload.to_bytes())


def scripted_command(k: int, info: dict, q: list[float]) -> dict:
    """A closed-loop scripted controller: swings arms and legs, and reads the state it gets back.

    The feedback term makes every command depend on the previous state, so any difference between
    two runs would feed on itself instead of hiding.
    """
    default = info["default_q"][info["mode"]]
    target = [d + 0.25 * math.sin(0.15 * k + 0.3 * i) for i, d in enumerate(default)]
    target = [t + 0.05 * (t - qi) for t, qi in zip(target, q)]
    return {"q": target}


class TestLockstep:
    def test_each_command_advances_lockstep_steps_and_publishes_one_state(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        odom = Latest(zsession, keys.odom, Odometry)
        applied = Latest(zsession, keys.applied, AppliedCommand)
        status = Latest(zsession, keys.sim_status, SimStatus)
        joints.keep_history = applied.keep_history = True
        # state_rate_hz 25 would mean one state per 40 ms in real time; lockstep publishes one per command.
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "7", "--state-rate-hz", "25")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        assert info["clock"] == "lockstep" and info["lockstep_steps"] == 7
        first = joints.wait(what="the initial state")
        assert first.sim_time_s == 0.0
        n_commands = 30
        for k in range(n_commands):
            before = joints.count
            zsession.put(keys.motors, json.dumps(scripted_command(k, info, list(joints.value.q))))
            joints.wait(lambda m, b=before: joints.count > b, what=f"the state after command {k}")
        time.sleep(0.5)  # time stands still: nothing more may come
        times = [m.sim_time_s for m in joints.history]
        assert len(times) == n_commands + 1, "one state per command (plus the initial one)"
        assert times == pytest.approx([k * 7 * DT for k in range(n_commands + 1)], abs=1e-9)
        assert [m.seq for m in joints.history] == list(range(joints.history[0].seq, joints.history[0].seq + n_commands + 1))
        assert odom.value.sim_time_s == times[-1]
        assert [a.sim_time_s for a in applied.history] == pytest.approx(times[:-1], abs=1e-9)
        assert all(a.steps == 7 for a in applied.history)
        sim = status.wait(lambda s: s.seq > 0 and s.waiting, what="a status that says the sim waits")
        assert sim.clock == "lockstep" and sim.steps == n_commands * 7 and sim.watchdog is False
        assert sim.sim_time_s == pytest.approx(times[-1], abs=1e-12)

    def test_advance_answers_a_plain_zenoh_client_with_all_three_states(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        joints = Latest(zsession, keys.joints, JointState)
        start_service("sim", "--clock", "lockstep")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        reply = advance(zsession, keys, {"names": ["left_elbow_joint"], "q": [0.9]})
        assert reply["ok"] is True and reply["type"] == "advance_reply"
        assert reply["steps"] == 10 and reply["sim_time_s"] == pytest.approx(10 * DT)
        for part in ("joints", "odom", "imu"):
            assert reply[part]["sim_time_s"] == reply["sim_time_s"], part
        assert len(reply["joints"]["q"]) == len(info["joint_names"])
        assert len(reply["odom"]["quat_wxyz"]) == 4 and len(reply["imu"]["accel"]) == 3
        # The same instant went out on state/joints for everyone else.
        published = joints.wait(lambda m: m.sim_time_s == reply["sim_time_s"], what="the published state")
        assert list(published.q) == reply["joints"]["q"]
        # The elbow goes towards 0.9 over a few advances.
        elbow = info["joint_names"].index("left_elbow_joint")
        for _ in range(40):
            reply = advance(zsession, keys, {"names": ["left_elbow_joint"], "q": [0.9]})
        assert reply["joints"]["q"][elbow] == pytest.approx(0.9, abs=0.1)
        steps = reply["steps"]

        # Bad input: rejected whole, nothing advances, counted.
        bad = advance(zsession, keys, {"names": ["no_such_joint"], "q": [0.1]})
        assert bad["ok"] is False and "no_such_joint" in bad["error"] and bad["steps"] == steps
        bad = advance(zsession, keys, {"q": "nope"})
        assert bad["ok"] is False and bad["joints"] is None
        bad = advance(zsession, keys, {"q": [0.0] * 6000})  # over the sim's cap (20 kB), under the router's (64 kB)
        assert bad["ok"] is False and "bytes" in bad["error"] and bad["steps"] == steps
        # A wildcard query reaches the queryable but must not step the sim.
        list(zsession.get(f"{keys.root}/*/advance", payload=json.dumps({"q": [0.0] * 29}), timeout=3.0))
        status = Latest(zsession, keys.sim_status, SimStatus)
        sim = status.wait(lambda s: s.rejected_commands >= 3, what="the rejections counted")
        assert sim.steps == steps
        # msgpack in, msgpack out, as a typed client does it.
        request = msgspec.msgpack.encode({"q": [0.0] * len(info["joint_names"])})
        replies = list(zsession.get(keys.ctl("advance"), payload=request, encoding=zenoh.Encoding("application/msgpack"), timeout=10.0))
        assert msgspec.msgpack.decode(replies[0].ok.payload.to_bytes())["steps"] == steps + 10

    def test_pause_step_and_reset_keep_working(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "5")
        wait_alive(zsession, keys)
        assert advance(zsession, keys, {"q": [0.0] * 29})["steps"] == 5
        assert ctl(zsession, keys.ctl("pause"))["paused"] is True
        refused = advance(zsession, keys, {"q": [0.0] * 29})
        assert refused["ok"] is False and "paused" in refused["error"] and refused["steps"] == 5
        assert ctl(zsession, keys.ctl("step"), {"n": 3})["steps"] == 8
        assert ctl(zsession, keys.ctl("resume"))["paused"] is False
        assert advance(zsession, keys, {"q": [0.0] * 29})["steps"] == 13
        reset = ctl(zsession, keys.ctl("reset"))
        assert reset["ok"] is True and reset["steps"] == 0 and reset["sim_time_s"] == 0.0
        assert advance(zsession, keys, {"q": [0.0] * 29})["sim_time_s"] == pytest.approx(5 * DT)


def test_two_sims_fed_the_same_commands_produce_bit_identical_states(start_service, zsession, robot_id) -> None:
    """Determinism: the same scripted controller against two sim processes, every state compared bit for bit."""
    ids = [robot_id + "a", robot_id + "b"]
    for rid in ids:
        start_service("sim", "--clock", "lockstep", env={"ZENSIM_ROBOT_ID": rid})
    runs = []
    for rid in ids:
        keys = Keys(rid)
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        q = list(info["default_q"][info["mode"]])
        states = []
        for k in range(150):  # 3 s of sim time: the G1 swings and shifts its weight
            reply = advance(zsession, keys, scripted_command(k, info, q))
            assert reply["ok"], reply
            q = reply["joints"]["q"]
            # JSON floats round-trip exactly: equal text means equal bits.
            states.append(json.dumps([reply["joints"], reply["odom"], reply["imu"]]))
        runs.append(states)
    assert len(runs[0]) == len(runs[1]) == 150
    differing = [k for k, (a, b) in enumerate(zip(*runs)) if a != b]
    assert not differing, f"states differ from step {differing[0]} on"
    # ... and the run did something: the robot moved.
    first, last = json.loads(runs[0][0]), json.loads(runs[0][-1])
    assert first[0]["q"] != last[0]["q"]


def test_a_lockstep_sim_stopped_mid_stream_exits_cleanly(start_service, zsession, robot_id) -> None:
    """Under lockstep the command thread advances and publishes: stopping the sim while a client streams
    commands must end that thread before the publishers go (it exited 1 with "Already borrowed" and
    logged "taking a command failed: session closed", seen under `zensim up --unitree` at Ctrl-C)."""
    import threading

    keys = Keys(robot_id)
    joints = Latest(zsession, keys.joints, JointState)
    for attempt in range(5):
        sim = start_service("sim", "--clock", "lockstep", "--lockstep-steps", "1")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        command = json.dumps({"q": info["default_q"][info["mode"]]})
        streaming = threading.Event()
        streaming.set()

        def stream() -> None:
            while streaming.is_set():
                zsession.put(keys.motors, command)

        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        try:
            before = joints.count
            joints.wait(lambda m, b=before: joints.count > b + 200, 30, "states from the streamed commands")
            code = sim.stop(10.0)
        finally:
            streaming.clear()
            streamer.join(5)
        log = sim.log()
        assert code == 0 and "Traceback" not in log and "failed" not in log, f"stop {attempt}: exit {code}\n{log[-3000:]}"
