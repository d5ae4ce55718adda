"""Faults on demand as users inject them: `python -m zensim sim --clock lockstep`, plain zenoh clients on loopback
sending JSON to ctl/faults and driving the robot through ctl/advance.

Lockstep makes the checks exact: the states are the instants each advance replies with, so a run without
sensor faults is the truth a run with them is compared to, figure by figure, and two runs with one seed are
compared bit for bit.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from support import Latest, ctl
from test_lockstep_process import advance, scripted_command
from test_sim_process import robot_info, wait_alive
from zensim.schemas import AppliedCommand, Imu, JointState, Keys, Odometry, SimStatus

SHOULDER, ELBOW, WRIST = "left_shoulder_pitch_joint", "left_elbow_joint", "right_elbow_joint"


def command(info: dict, tau: dict[str, float] | None = None) -> dict:
    """Hold the default pose, with feed-forward torques on some joints."""
    names = info["joint_names"]
    torques = [0.0] * len(names)
    for name, value in (tau or {}).items():
        torques[names.index(name)] = value
    return {"q": info["default_q"][info["mode"]], "tau": torques}


class TestMotorFaults:
    def test_a_locked_joint_holds_under_load_a_limp_one_carries_no_torque_and_both_end_when_cleared(
            self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--clock", "lockstep")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        names = info["joint_names"]
        shoulder, elbow = names.index(SHOULDER), names.index(ELBOW)
        for _ in range(50):  # 1 s: the G1 lands and stands on its gains
            state = advance(zsession, keys, command(info))
        assert abs(state["joints"]["tau"][elbow]) > 0.05, "a healthy elbow carries its forearm"

        reply = ctl(zsession, keys.ctl("faults"), {"verb": "set", "joints": [
            {"joint": SHOULDER, "locked": True}, {"joint": ELBOW, "limp": True}]})
        assert reply["ok"] is True, reply
        locked_q = reply["faults"]["locked_q"][0]
        assert locked_q == pytest.approx(state["joints"]["q"][shoulder], abs=1e-9), "held where it was"
        # The shoulder's own motor pushes 20 N m (the load) for 1 s: the lock holds it.
        pushed = command(info, {SHOULDER: 20.0})
        for _ in range(50):
            state = advance(zsession, keys, pushed)
            assert abs(state["joints"]["dq"][shoulder]) < 1e-3, state["joints"]["dq"][shoulder]
            assert state["joints"]["q"][shoulder] == pytest.approx(locked_q, abs=1e-3)
            assert state["joints"]["tau"][elbow] == 0.0, "a limp joint's motor gives nothing at all"
        seen = status.wait(lambda s: s.faults is not None, what="the faults in state/sim")
        assert seen.faults_set == 1 and {f.joint for f in seen.faults.joints} == {SHOULDER, ELBOW}
        assert seen.faults.locked_q == (pytest.approx(locked_q),)

        cleared = ctl(zsession, keys.ctl("faults"), {"verb": "clear"})
        assert cleared["ok"] is True and cleared["faults"] is None
        speeds = []
        for _ in range(10):
            state = advance(zsession, keys, pushed)
            speeds.append(abs(state["joints"]["dq"][shoulder]))
        assert max(speeds) > 0.1, "without the lock the same torque swings the shoulder: the check can fail"
        assert abs(state["joints"]["tau"][elbow]) > 0.05, "the elbow's motor works again"
        status.wait(lambda s: s.faults is None and s.faults_set == 2, what="the faults gone from state/sim")

    def test_a_weak_motor_gives_its_share_of_the_torque(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        start_service("sim", "--clock", "lockstep", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        elbow = info["joint_names"].index(ELBOW)
        # Zero gains and a pure feed-forward torque: the motor's torque is the command's, times its factor.
        n = len(info["joint_names"])
        torque = {**command(info, {ELBOW: 2.0}), "kp": [0.0] * n, "kd": [0.0] * n}
        assert advance(zsession, keys, torque)["joints"]["tau"][elbow] == pytest.approx(2.0)
        assert ctl(zsession, keys.ctl("faults"), {"verb": "set", "joints": [{"joint": ELBOW, "torque_scale": 0.6}]})["ok"]
        assert advance(zsession, keys, torque)["joints"]["tau"][elbow] == pytest.approx(1.2)


class TestSensorFaults:
    def test_an_encoder_offset_and_an_imu_bias_show_as_exactly_that_against_a_run_without_them(
            self, start_service, zsession, robot_id) -> None:
        ids = [robot_id + "true", robot_id + "faulty"]
        for rid in ids:
            start_service("sim", "--clock", "lockstep", env={"ZENSIM_ROBOT_ID": rid})
        truth, faulty = Keys(ids[0]), Keys(ids[1])
        for keys in (truth, faulty):
            wait_alive(zsession, keys)
        info = robot_info(zsession, truth)
        wrist = info["joint_names"].index(WRIST)
        gyro_bias, accel_bias = [0.02, -0.01, 0.005], [0.3, 0.0, -0.2]
        reply = ctl(zsession, faulty.ctl("faults"), {"verb": "set", "joints": [
            {"joint": WRIST, "encoder_offset_rad": 0.1}], "sensors": {"gyro_bias_rad_s": gyro_bias,
                                                                     "accel_bias_m_s2": accel_bias}})
        assert reply["ok"] is True, reply
        for k in range(30):  # the same open-loop commands to both: the physics is the same
            cmd = scripted_command(k, info, info["default_q"][info["mode"]])
            real, seen = advance(zsession, truth, cmd), advance(zsession, faulty, cmd)
            assert seen["odom"] == real["odom"], "a sensor fault leaves the physics alone"
            offsets = np.subtract(seen["joints"]["q"], real["joints"]["q"])
            assert offsets[wrist] == pytest.approx(0.1, abs=1e-12)
            assert np.delete(offsets, wrist).tolist() == [0.0] * (len(offsets) - 1)
            assert seen["joints"]["dq"] == real["joints"]["dq"]
            assert np.subtract(seen["imu"]["gyro"], real["imu"]["gyro"]) == pytest.approx(gyro_bias, abs=1e-12)
            assert np.subtract(seen["imu"]["accel"], real["imu"]["accel"]) == pytest.approx(accel_bias, abs=1e-12)
            assert seen["imu"]["quat_wxyz"] == real["imu"]["quat_wxyz"]

    def test_noise_is_seeded_one_seed_gives_the_same_run_another_a_different_one(
            self, start_service, zsession, robot_id) -> None:
        ids = [robot_id + "a", robot_id + "b", robot_id + "c"]
        seeds = [7, 7, 8]
        for rid in ids:
            start_service("sim", "--clock", "lockstep", env={"ZENSIM_ROBOT_ID": rid})
        noise = {"gyro_noise_std_rad_s": 0.01, "accel_noise_std_m_s2": 0.1, "q_noise_std_rad": 0.002,
                 "dq_noise_std_rad_s": 0.05}
        runs = []
        for rid, seed in zip(ids, seeds):
            keys = Keys(rid)
            wait_alive(zsession, keys)
            info = robot_info(zsession, keys)
            assert ctl(zsession, keys.ctl("faults"), {"verb": "set", "sensors": noise, "seed": seed})["ok"]
            q = list(info["default_q"][info["mode"]])
            states = []
            for k in range(60):  # closed loop: the noise the controller reads feeds back into the physics
                reply = advance(zsession, keys, scripted_command(k, info, q))
                assert reply["ok"], reply
                q = reply["joints"]["q"]
                states.append(json.dumps([reply["joints"], reply["odom"], reply["imu"]]))  # equal text: equal bits
            runs.append(states)
        differing = [k for k, (a, b) in enumerate(zip(runs[0], runs[1])) if a != b]
        assert not differing, f"one seed, two runs: the states differ from step {differing[0]} on"
        assert runs[0][0] != runs[2][0], "another seed, other noise from the first state on"
        assert runs[0][-1] != runs[2][-1]


class TestRefusals:
    def test_bad_fault_requests_are_refused_whole_and_counted(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--paused", "true")
        wait_alive(zsession, keys)
        good = {"joint": ELBOW, "limp": True}
        bad: list[tuple[dict, str]] = [
            ({"verb": "set", "joints": [good, {"joint": "tail_joint", "locked": True}]}, "tail_joint"),
            ({"verb": "set", "joints": [{"joint": ELBOW, "torque_scale": 1e9}]}, "torque_scale"),
            ({"verb": "set", "joints": [{"joint": ELBOW, "torque_scale": -0.5}]}, "torque_scale"),
            ({"verb": "set", "joints": [{"joint": ELBOW, "encoder_offset_rad": 7.0}]}, "encoder_offset_rad"),
            ({"verb": "set", "joints": [{"joint": ELBOW, "locked": True, "limp": True}]}, "not both"),
            ({"verb": "set", "joints": [good, good]}, "more than one"),
            ({"verb": "set", "joints": [good], "sensors": {"gyro_noise_std_rad_s": 1e6}}, "gyro_noise_std_rad_s"),
            ({"verb": "set", "sensors": {"accel_bias_m_s2": [0, 0, float("nan")]}}, ""),  # JSON has no NaN
            ({"verb": "set", "sensors": {"q_noise_std_rad": -1}}, "q_noise_std_rad"),
            ({"verb": "set", "seed": -3}, "seed"),
            ({"verb": "break"}, "verb"),
            ({"verb": "clear", "joints": [good]}, "verb: set"),
            ({"verb": "set", "joints": [{**good, "melted": True}]}, "melted"),
            ({"verb": "set", "link": {"command_delay_steps": 501}}, "command_delay_steps"),
            ({"verb": "set", "link": {"command_delay_steps": -1}}, "command_delay_steps"),
            ({"verb": "set", "link": {"command_delay_steps": 2.5}}, "command_delay_steps"),
            ({"verb": "set", "link": {"command_delay_steps": float("nan")}}, ""),  # JSON has no NaN
            ({"verb": "set", "link": {"drop_probability": 1.5}}, "drop_probability"),
            ({"verb": "set", "joints": [good], "link": {"drop_probability": -0.1}}, "drop_probability"),
            ({"verb": "clear", "link": {"command_delay_steps": 3}}, "verb: set"),
            ({"verb": "set", "sensors": {"orientation_drift_rad_s": 0.2}}, "orientation_drift_rad_s"),
            ({"verb": "set", "sensors": {"orientation_drift_rad_s": -0.11}}, "orientation_drift_rad_s"),
            ({"verb": "set", "sensors": {"orientation_drift_rad_s": float("inf")}}, ""),  # JSON has no Infinity
            ({"verb": "set", "sensors": {"orientation_drift_rad_s": 0.01, "orientation_drift_axis": [0, 0, 0]}},
             "orientation_drift_axis"),
            ({"verb": "set", "sensors": {"orientation_drift_axis": [0, 0, 2]}}, "orientation_drift_axis"),
            ({"verb": "set", "sensors": {"orientation_drift_axis": [0, 1]}}, "orientation_drift_axis"),
            ({"verb": "set", "sensors": {"dropout_probability": 1.01}}, "dropout_probability"),
            ({"verb": "set", "joints": [good], "sensors": {"dropout_probability": 0.1, "dropout_s": -0.5}},
             "dropout_s"),
            ({"verb": "set", "sensors": {"dropout_s": 11}}, "dropout_s"),
            ({"verb": "set", "link": {"state_delay_steps": 501}}, "state_delay_steps"),
            ({"verb": "set", "link": {"state_delay_steps": -1}}, "state_delay_steps"),
            ({"verb": "set", "link": {"state_delay_steps": 1.5}}, "state_delay_steps"),
            ({"verb": "clear", "link": {"state_delay_steps": 3}}, "verb: set"),
        ]
        for payload, why in bad:
            reply = ctl(zsession, keys.ctl("faults"), payload)
            assert reply["ok"] is False and why in reply["error"], (payload, reply)
            assert reply["faults"] is None
        seen = status.wait(lambda s: s.rejected_requests >= len(bad), what="the refusals counted")
        assert seen.rejected_requests == len(bad) and seen.faults is None and seen.faults_set == 0
        # A wildcard query reaches every ctl verb: it sets nothing.
        list(zsession.get(f"{keys.root}/ctl/*", payload=json.dumps({"verb": "set", "joints": [good]}), timeout=3.0))
        # The same request, sane, is carried out: the refusals were about what was wrong.
        reply = ctl(zsession, keys.ctl("faults"), {"verb": "set", "joints": [good]})
        assert reply["ok"] is True and reply["faults"]["joints"][0]["limp"] is True
        assert ctl(zsession, keys.ctl("faults"))["faults"]["joints"][0]["joint"] == ELBOW, "no verb: the state"
        status.wait(lambda s: s.faults is not None and s.faults_set == 1, what="the good request")



def elbow_torques(session, keys: Keys, info: dict, taus: list[float]) -> list[float]:
    """Advance once per torque in `taus` (zero gains, the torque fed forward on the elbow alone); the elbow's
    torque in each state replied: exactly the commanded torque the motor had during that step."""
    elbow = info["joint_names"].index(ELBOW)
    n = len(info["joint_names"])
    seen = []
    for tau in taus:
        reply = advance(session, keys, {**command(info, {ELBOW: tau}), "kp": [0.0] * n, "kd": [0.0] * n})
        assert reply["ok"], reply
        seen.append(reply["joints"]["tau"][elbow])
    return seen


class TestLinkFaults:
    """One physics step per advance (--lockstep-steps 1): each state replied is one step after the last."""

    def test_a_command_delay_of_k_steps_shows_exactly_k_states_later_and_loses_no_command(
            self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        applied = Latest(zsession, keys.applied, AppliedCommand)
        applied.keep_history = True
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "1", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        pulse = [0.0] * 4 + [2.0, 1.0] + [0.0] * 8  # two one-step pulses: each must land, at its own step
        assert elbow_torques(zsession, keys, info, pulse) == pytest.approx(pulse, abs=1e-9), "k = 0: at once"
        for k in (1, 5):
            reply = ctl(zsession, keys.ctl("faults"), {"verb": "set", "link": {"command_delay_steps": k}})
            assert reply["ok"] is True and reply["faults"]["link"]["command_delay_steps"] == k, reply
            seen = elbow_torques(zsession, keys, info, pulse)
            assert seen == pytest.approx([0.0] * k + pulse[:-k], abs=1e-9), f"delay {k}: the pulses {k} states later"
        # state/applied records each command as sent, at the sim time it was sent (a recording holds what the
        # controller did; the delay is the sim's fault, not the record's).
        applied.wait(lambda a: a.seq == 3 * len(pulse), what="every command on state/applied")
        elbow = info["joint_names"].index(ELBOW)
        last = applied.history[-len(pulse):]
        assert [a.command.tau[elbow] for a in last] == pulse
        assert np.diff([a.sim_time_s for a in last]) == pytest.approx([0.002] * (len(pulse) - 1), abs=1e-9)
        assert ctl(zsession, keys.ctl("faults"), {"verb": "clear"})["faults"] is None
        # The 5 commands still in flight land first (the link keeps order), then each at once again.
        assert elbow_torques(zsession, keys, info, [0.0] * 5) == [0.0] * 5
        assert elbow_torques(zsession, keys, info, pulse) == pytest.approx(pulse, abs=1e-9), "cleared: at once again"

    def test_dropped_commands_never_apply_are_counted_and_the_seed_picks_which(
            self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "1", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        assert ctl(zsession, keys.ctl("faults"), {"verb": "set", "link": {"drop_probability": 1}})["ok"]
        assert elbow_torques(zsession, keys, info, [2.0] * 20) == [0.0] * 20, "a dead link: nothing applies"
        status.wait(lambda s: s.dropped_commands == 20 and s.rejected_commands == 0, what="20 drops counted")

        # Every command's torque differs: a state shows the command's own torque when it applied, the last one's
        # when it was dropped.
        taus = [0.01 * (i + 1) for i in range(60)]

        def delivered(seed: int) -> list[int]:
            assert ctl(zsession, keys.ctl("faults"), {"verb": "set", "link": {"drop_probability": 0.5},
                                                      "seed": seed})["ok"]
            seen = elbow_torques(zsession, keys, info, taus)
            return [i for i, (tau, got) in enumerate(zip(taus, seen)) if got == pytest.approx(tau, abs=1e-9)]

        first, again, other = delivered(7), delivered(7), delivered(8)
        assert first == again, "one seed, the same commands dropped"
        assert first != other, "another seed, other drops"
        assert 10 < len(first) < 50, len(first)
        dropped = 20 + sum(len(taus) - len(run) for run in (first, again, other))
        status.wait(lambda s: s.dropped_commands == dropped, what=f"{dropped} drops counted")


def turn_between(seen: list[float], real: list[float]) -> np.ndarray:
    """The rotation q_seen * conj(q_real), wxyz, w >= 0: what turned the true orientation into the reported one
    (world frame)."""
    w1, x1, y1, z1 = seen
    w2, x2, y2, z2 = real[0], -real[1], -real[2], -real[3]
    turn = np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])
    return turn if turn[0] >= 0 else -turn


def yaw(quat_wxyz: list[float]) -> float:
    w, x, y, z = quat_wxyz
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


class TestOrientationDrift:
    def test_the_imu_turns_away_from_the_truth_at_the_rate_from_the_set_and_each_reset_and_clear_ends_it(
            self, start_service, zsession, robot_id) -> None:
        ids = [robot_id + "true", robot_id + "drifting"]
        for rid in ids:
            start_service("sim", "--clock", "lockstep", env={"ZENSIM_ROBOT_ID": rid})
        truth, faulty = Keys(ids[0]), Keys(ids[1])
        for keys in (truth, faulty):
            wait_alive(zsession, keys)
        info = robot_info(zsession, truth)
        rate = -0.08
        reply = ctl(zsession, faulty.ctl("faults"), {"verb": "set", "sensors": {"orientation_drift_rad_s": rate}})
        assert reply["ok"] is True and reply["faults"]["sensors"]["orientation_drift_rad_s"] == rate, reply
        since = reply["faults"]["set_at_s"]
        q = info["default_q"][info["mode"]]
        for k in range(60):  # the same commands to both (the truth's feedback): the same physics
            cmd = scripted_command(k, info, q)
            real, seen = advance(zsession, truth, cmd), advance(zsession, faulty, cmd)
            q = real["joints"]["q"]
            assert seen["odom"] == real["odom"] and seen["joints"] == real["joints"], "the physics is untouched"
            assert seen["imu"]["gyro"] == real["imu"]["gyro"], "only the orientation drifts"
            angle = rate * (seen["imu"]["sim_time_s"] - since)
            turn = turn_between(seen["imu"]["quat_wxyz"], real["imu"]["quat_wxyz"])
            assert turn == pytest.approx([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)], abs=1e-9), k
            drift = yaw(seen["imu"]["quat_wxyz"]) - yaw(real["imu"]["quat_wxyz"])
            assert (drift - angle + np.pi) % (2 * np.pi) - np.pi == pytest.approx(0.0, abs=1e-6)
        assert abs(angle) > 0.05, "enough drift that a check without it fails"
        # A reset is a new episode: the drift counts from it.
        reset = ctl(zsession, faulty.ctl("reset"), {})
        ctl(zsession, truth.ctl("reset"), {})
        real, seen = advance(zsession, truth, command(info)), advance(zsession, faulty, command(info))
        angle = rate * (seen["imu"]["sim_time_s"] - reset["sim_time_s"])
        assert 0 < abs(angle) < 0.01
        assert turn_between(seen["imu"]["quat_wxyz"], real["imu"]["quat_wxyz"]) == pytest.approx(
            [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)], abs=1e-9)
        # A tilt about world x instead.
        assert ctl(zsession, faulty.ctl("faults"), {"verb": "set", "sensors": {
            "orientation_drift_rad_s": 0.1, "orientation_drift_axis": [2e-1, 0, 0]}})["ok"]
        for _ in range(5):
            real, seen = advance(zsession, truth, command(info)), advance(zsession, faulty, command(info))
        turn = turn_between(seen["imu"]["quat_wxyz"], real["imu"]["quat_wxyz"])
        assert turn[2:] == pytest.approx([0.0, 0.0], abs=1e-12) and turn[1] > 0
        assert ctl(zsession, faulty.ctl("faults"), {"verb": "clear"})["faults"] is None
        real, seen = advance(zsession, truth, command(info)), advance(zsession, faulty, command(info))
        assert seen["imu"] == real["imu"], "cleared: the truth again, to the bit"


def withheld_runs(replies: list[dict]) -> list[int]:
    """The lengths of the runs of consecutive replies without joints (withheld)."""
    runs, length = [], 0
    for reply in replies:
        if reply["joints"] is None:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    return runs + ([length] if length else [])


class TestDropouts:
    """One physics step per advance (--lockstep-steps 1): a dropout of 10 ms withholds 5 states."""

    def test_states_are_withheld_for_the_dropout_s_counted_and_the_seed_picks_when(
            self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        joints, imu, odom = (Latest(zsession, key, message) for key, message in
                             ((keys.joints, JointState), (keys.imu, Imu), (keys.odom, Odometry)))
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "1", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        odom.wait(what="the first state")
        before = (joints.count, imu.count, odom.count)

        def run(seed: int, n: int = 150) -> list[dict]:
            reply = ctl(zsession, keys.ctl("faults"), {"verb": "set", "seed": seed, "sensors": {
                "dropout_probability": 0.05, "dropout_s": 0.01}})
            assert reply["ok"] is True and reply["faults"]["sensors"]["dropout_s"] == 0.01, reply
            replies = [advance(zsession, keys, command(info)) for _ in range(n)]
            assert all(r["ok"] and r["odom"] is not None for r in replies), "the advance and the truth go on"
            assert all((r["joints"] is None) == (r["imu"] is None) for r in replies), "joints and imu together"
            return replies

        first, again, other = run(3), run(3), run(4)
        pattern = [[r["joints"] is None for r in replies] for replies in (first, again, other)]
        assert pattern[0] == pattern[1], "one seed: the same states withheld"
        assert pattern[0] != pattern[2], "another seed, other dropouts"
        runs = withheld_runs(first)
        assert runs and all(length % 5 == 0 for length in runs), runs  # 10 ms of 2 ms steps, back to back maybe
        withheld = sum(sum(p) for p in pattern)
        assert 0 < withheld < 3 * 150 / 2
        seqs = [r["odom"]["seq"] for r in first if r["joints"] is not None]
        assert [r["joints"]["seq"] for r in first if r["joints"] is not None] == seqs, "a gap in seq shows a dropout"
        status.wait(lambda s: s.withheld_states == withheld, what=f"{withheld} withheld states counted")
        odom.wait(lambda _: odom.count == before[2] + 450, what="every odometry (ground truth: never withheld)")
        joints.wait(lambda _: joints.count == before[0] + 450 - withheld, what="the joints not withheld")
        assert imu.count == before[1] + 450 - withheld
        # Cleared: every state again.
        assert ctl(zsession, keys.ctl("faults"), {"verb": "clear"})["faults"] is None
        assert all(advance(zsession, keys, command(info))["joints"] is not None for _ in range(20))
        status.wait(lambda s: s.faults is None and s.withheld_states == withheld, what="no more withheld")


class TestStateDelay:
    """One physics step per advance (--lockstep-steps 1): a state delay of k steps is k advances."""

    def test_a_state_delay_of_k_steps_gives_the_state_of_k_advances_ago_and_clear_ends_it(
            self, start_service, zsession, robot_id) -> None:
        ids = [robot_id + "true", robot_id + "late"]
        for rid in ids:
            start_service("sim", "--clock", "lockstep", "--lockstep-steps", "1", env={"ZENSIM_ROBOT_ID": rid})
        truth, faulty = Keys(ids[0]), Keys(ids[1])
        for keys in (truth, faulty):
            wait_alive(zsession, keys)
        info = robot_info(zsession, truth)
        k = 4
        reply = ctl(zsession, faulty.ctl("faults"), {"verb": "set", "link": {"state_delay_steps": k}})
        assert reply["ok"] is True and reply["faults"]["link"]["state_delay_steps"] == k, reply
        q = info["default_q"][info["mode"]]
        reals, seens = [], []
        for n in range(40):
            cmd = scripted_command(n, info, q)
            real, seen = advance(zsession, truth, cmd), advance(zsession, faulty, cmd)
            q = real["joints"]["q"]
            reals.append(real)
            seens.append(seen)
            assert seen["odom"] == real["odom"], "the ground truth is not delayed"
            old = reals[max(0, n - k)]  # the first reading since the set until one is k steps old
            for name in ("joints", "imu"):
                assert seen[name]["seq"] == real[name]["seq"], "numbered as published"
                assert {**seen[name], "seq": 0} == {**old[name], "seq": 0}, (n, name)
        assert seens[-1]["joints"]["sim_time_s"] == pytest.approx(reals[-1]["sim_time_s"] - k * 0.002, abs=1e-9)
        assert reals[-1]["joints"]["q"] != reals[-1 - k]["joints"]["q"], "the robot moved: the check can fail"
        assert ctl(zsession, faulty.ctl("faults"), {"verb": "clear"})["faults"] is None
        cmd = command(info)
        real, seen = advance(zsession, truth, cmd), advance(zsession, faulty, cmd)
        assert seen["joints"] == real["joints"] and seen["imu"] == real["imu"], "cleared: this instant's again"

    def test_with_several_steps_per_advance_the_delay_is_whole_advances_rounded_up(
            self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        start_service("sim", "--clock", "lockstep", "--lockstep-steps", "5", "--mode", "fixed")
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        assert ctl(zsession, keys.ctl("faults"), {"verb": "set", "link": {"state_delay_steps": 7}})["ok"]
        for _ in range(6):
            reply = advance(zsession, keys, command(info))
        # 7 steps back from the newest instant lies between two advances: the reading at or before, 2 advances.
        assert reply["joints"]["sim_time_s"] == pytest.approx(reply["sim_time_s"] - 10 * 0.002, abs=1e-9)
        assert reply["odom"]["sim_time_s"] == pytest.approx(reply["sim_time_s"], abs=1e-12)
        # A reset is a new episode: no reading of the last one comes after it (the reset's own is repeated).
        reset = ctl(zsession, keys.ctl("reset"), {})
        for _ in range(2):
            assert advance(zsession, keys, command(info))["joints"]["sim_time_s"] == reset["sim_time_s"]
        assert advance(zsession, keys, command(info))["joints"]["sim_time_s"] > reset["sim_time_s"]


def test_a_world_advance_leaves_a_withheld_robot_out_and_delays_another_and_the_rest_are_untouched(
        start_service, zsession, robot_id, tmp_path) -> None:
    """A world of three G1s under lockstep (its states put from a thread of their own): robot 0 in a dropout that
    never ends, robot 1 with a state delay, robot 2 without a fault."""
    import zenoh

    from support import wait_for
    from zensim.schemas import Codec, WorldAdvanceReply, WorldAdvanceRequest

    ids = [f"{robot_id}-{k}" for k in range(3)]
    path = tmp_path / "three.toml"
    path.write_text(f'id = "{robot_id}-w"\n' + "".join(
        f'[[robots]]\nid = "{rid}"\nxy = [{1.2 * k}, 0.0]\n' for k, rid in enumerate(ids)))
    joints = Latest(zsession, Keys(ids[0]).joints, JointState)
    odom = Latest(zsession, Keys(ids[0]).odom, Odometry)
    status = Latest(zsession, Keys(ids[0]).sim_status, SimStatus)
    start_service("sim", "--world", str(path), "--clock", "lockstep")
    wait_for(lambda: list(zsession.liveliness().get(Keys(ids[-1]).alive("sim"), timeout=1)), 60, "the world up")
    assert ctl(zsession, Keys(ids[0]).ctl("faults"), {"verb": "set", "sensors": {
        "dropout_probability": 1.0, "dropout_s": 10.0}})["ok"]
    assert ctl(zsession, Keys(ids[1]).ctl("faults"), {"verb": "set", "link": {"state_delay_steps": 20}})["ok"]
    odom.wait(what="a first odometry")
    joints_before, odom_before = joints.count, odom.count
    key, request_codec, reply_codec = Keys(f"{robot_id}-w").world_advance, Codec(WorldAdvanceRequest), Codec(WorldAdvanceReply)
    replies = []
    for _ in range(5):
        got = list(zsession.get(key, payload=request_codec.encode(WorldAdvanceRequest()),
                                encoding=zenoh.Encoding("application/msgpack"), timeout=10))
        reply = reply_codec.decode(got[0].ok.payload.to_bytes(), "application/msgpack")
        assert reply.ok, reply.error
        assert reply.withheld == (ids[0],) and sorted(reply.states) == sorted(ids[1:]), reply.withheld
        replies.append(reply)
    late, on_time = replies[-1].states[ids[1]], replies[-1].states[ids[2]]
    assert on_time.joints.sim_time_s == on_time.odom.sim_time_s == replies[-1].sim_time_s
    lockstep_steps = round((replies[-1].sim_time_s - replies[-2].sim_time_s) / 0.002)
    back = -(-20 // lockstep_steps) * lockstep_steps * 0.002  # whole advances, rounded up
    assert late.joints.sim_time_s == pytest.approx(replies[-1].sim_time_s - back, abs=1e-9)
    assert late.imu.sim_time_s == late.joints.sim_time_s and late.odom.sim_time_s == replies[-1].sim_time_s
    odom.wait(lambda _: odom.count >= odom_before + 5, what="robot 0's odometry (never withheld)")
    status.wait(lambda s: s.withheld_states >= 5, what="robot 0's withheld states counted")
    assert joints.count == joints_before, "robot 0's joints withheld"


def test_at_real_time_a_state_delay_hands_out_the_newest_reading_at_or_before_k_steps_back(
        start_service, zsession, robot_id) -> None:
    """The real-time clock, states every 10 ms of sim time (5 steps): a delay of 7 steps (14 ms) gives the
    reading 2 state periods back (the newest at or before), a delay of 10 exactly 2; odometry is never late."""
    keys = Keys(robot_id)
    joints, odom = Latest(zsession, keys.joints, JointState), Latest(zsession, keys.odom, Odometry)
    joints.keep_history = odom.keep_history = True
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, keys)
    for k, back_s in ((7, 0.02), (10, 0.02)):
        reply = ctl(zsession, keys.ctl("faults"), {"verb": "set", "link": {"state_delay_steps": k}})
        assert reply["ok"], reply
        since = reply["sim_time_s"]
        odom.wait(lambda o: o.sim_time_s > since + 0.2, what="0.2 s of states")  # noqa: B023
        truth = {o.seq: o.sim_time_s for o in odom.history}
        late = [(truth[j.seq], j.sim_time_s) for j in joints.history
                if j.seq in truth and j.sim_time_s > since + back_s + 0.005]
        assert len(late) > 10
        for now, then in late:
            assert now - then == pytest.approx(back_s, abs=1e-9), (k, now, then)
