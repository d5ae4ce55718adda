"""The G1 locomotion controller's pure parts: the numpy policy, the FSM, the arm_sdk blend, the sport answers."""

import json
import math

import numpy as np
import pytest

from zensim.robots import robot_files
from zensim.robots.builder import build
from zensim.unitree import sport
from zensim.unitree.loco import NUM_JOINTS, STAND_Q, UPPER_KP, LocoController, Squat
from zensim.unitree.walk_policy import DEFAULT_LEG_Q, NUM_OBS, WalkPolicy, gravity_in_body, load_weights, observation

_G1 = build(robot_files("g1"), "floating")
G1_SQUAT = Squat(_G1.default_q, _G1.kp, _G1.kd)
"""The G1's squat and floating gains, from its control file, as the sim serves them on info/robot."""

UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])


def test_policy_is_the_declared_lstm_and_keeps_state_until_reset():
    weights = load_weights()
    assert weights["lstm_weight_ih"].shape == (256, NUM_OBS) and weights["actor2_weight"].shape == (12, 32)
    policy = WalkPolicy(weights)
    obs = observation(np.zeros(3), UPRIGHT, np.zeros(3), DEFAULT_LEG_Q, np.zeros(12), np.zeros(12), 0.0)
    first = policy.act(obs)
    second = policy.act(obs)
    assert first.shape == (12,) and np.all(np.isfinite(first)) and np.all(np.abs(first) < 10)
    assert not np.allclose(first, second)  # the LSTM's memory changed the answer
    policy.reset()
    assert np.array_equal(policy.act(obs), first)
    with pytest.raises(ValueError):
        policy.act(np.zeros(12, np.float32))


def test_observation_layout_follows_unitrees_reference_loop():
    obs = observation(np.array([1.0, 2.0, 4.0]), UPRIGHT, np.array([0.3, 0.0, 0.5]), DEFAULT_LEG_Q + 0.1,
                      np.ones(12), np.full(12, 0.5), 0.2)
    assert np.allclose(obs[0:3], [0.25, 0.5, 1.0])
    assert np.allclose(obs[3:6], [0, 0, -1])  # gravity points down in an upright body
    assert np.allclose(obs[6:9], [0.6, 0.0, 0.125])
    assert np.allclose(obs[9:21], 0.1) and np.allclose(obs[21:33], 0.05) and np.allclose(obs[33:45], 0.5)
    assert np.allclose(obs[45:47], [math.sin(2 * math.pi * 0.25), math.cos(2 * math.pi * 0.25)])
    tilted = gravity_in_body(np.array([math.cos(0.25), math.sin(0.25), 0, 0]))  # rolled 0.5 rad
    assert tilted[2] == pytest.approx(-math.cos(0.5)) and abs(tilted[1]) == pytest.approx(math.sin(0.5))


def tick(controller, t, q=None, force=False):
    q = STAND_Q if q is None else q
    return controller.tick(t, q.copy(), np.zeros(NUM_JOINTS), UPRIGHT, np.zeros(3), force=force)


def test_passive_until_asked_then_one_command_per_20_ms_of_sim_time():
    controller = LocoController(G1_SQUAT)
    assert tick(controller, 0.0) is None
    controller.set_fsm(706)
    sent = [t for t in np.arange(0, 1.0, 0.002) if tick(controller, float(t)) is not None]
    assert len(sent) == 50 and np.allclose(np.diff(sent), 0.02)


def test_squat_to_stand_hands_over_to_the_policy_and_toggles_back():
    controller = LocoController(G1_SQUAT)
    controller.set_fsm(706)
    for t in np.arange(0, 3.0, 0.02):
        targets = tick(controller, float(t))
    assert controller.state.walking and controller.policy_steps > 0
    assert np.all(targets.kp[12:] == UPPER_KP)
    controller.set_fsm(706)  # standing: stand-to-squat
    assert not controller.state.walking


def test_a_sim_reset_restarts_the_mode_from_the_spawn_pose():
    controller = LocoController(G1_SQUAT)
    controller.set_fsm(500)
    for t in np.arange(0, 3.0, 0.02):
        tick(controller, float(t))
    assert controller.state.walking
    controller.set_velocity(0.3, 0, 0, 100.0, 3.0)
    squat = tick(controller, 0.0, q=np.zeros(NUM_JOINTS))  # a reset: sim time 0 again
    assert not controller.state.walking and controller.state.fsm_id == 500  # standing up again first
    assert np.allclose(squat.q, 0.0)  # the ramp starts from the present pose
    assert not any(controller.command_now(0.5))  # the velocity command lapsed
    for t in np.arange(0.02, 3.0, 0.02):
        tick(controller, float(t))
    assert controller.state.walking


def test_arm_sdk_blends_arms_by_weight_keeps_the_waist_stiff_and_leaves_the_legs():
    controller = LocoController(G1_SQUAT)
    controller.set_fsm(500)
    for t in np.arange(0, 3.0, 0.02):
        base = tick(controller, float(t))
    ones = np.ones(17)
    controller.set_arm_sdk(q=ones, dq=0 * ones, kp=60 * ones, kd=1.5 * ones, tau=0 * ones, weight=0.25)
    blended = tick(controller, 3.0)
    assert np.allclose(blended.q[15:], 0.25) and np.allclose(blended.kp[15:], 0.25 * 60 + 0.75 * UPPER_KP)
    assert np.allclose(blended.q[12:15], 0.25) and np.all(blended.kp[12:15] == UPPER_KP)
    assert np.array_equal(blended.kp[:12], base.kp[:12])
    controller.set_arm_sdk(q=ones, dq=0 * ones, kp=60 * ones, kd=1.5 * ones, tau=0 * ones, weight=7.0)
    assert controller.arm_sdk.weight == 1.0


def test_sitting_holds_the_robots_own_squat_with_its_floating_gains():
    """The squat and its gains are the robot's control file's (through info/robot), not a copy in the controller."""
    assert G1_SQUAT.q[3] == 0.9 and G1_SQUAT.kp[0] == 1000.0  # control.toml: knee 0.9 rad, legs kp 1000
    with pytest.raises(ValueError, match="no robot yet"):
        LocoController().set_fsm(3)
    softer = Squat(G1_SQUAT.q * 0.5, G1_SQUAT.kp * 0.5, G1_SQUAT.kd * 0.5)
    for squat in (G1_SQUAT, softer):
        controller = LocoController(squat)
        controller.set_fsm(3)
        for t in np.arange(0, 2.0, 0.02):
            targets = tick(controller, float(t))
        assert np.allclose(targets.q, squat.q) and np.allclose(targets.kp, squat.kp) and np.allclose(targets.kd, squat.kd)


def test_sport_answers_codes_as_the_robot():
    controller = LocoController(G1_SQUAT)
    assert sport.answer(1, "{}", controller, 0.0) == (0, "1.0.0.0")
    assert sport.answer(7001, "{}", controller, 0.0) == (0, json.dumps({"data": 0}))
    assert sport.answer(7101, json.dumps({"data": 706}), controller, 0.0) == (0, "")
    assert json.loads(sport.answer(7001, "{}", controller, 0.0)[1]) == {"data": 706}
    for bad in ("not json", "[1]", json.dumps({"data": 12345}), json.dumps({"data": 1.5}), json.dumps({"data": True})):
        assert sport.answer(7101, bad, controller, 0.0)[0] == 3204, bad
    assert controller.state.fsm_id == 706  # nothing changed
    good = json.dumps({"velocity": [0.3, 0, 0], "duration": 2.0})
    assert sport.answer(7105, good, controller, 1.0) == (0, "")
    assert list(controller.command_now(2.9)) == [0.3, 0, 0] and not any(controller.command_now(3.0))
    for bad in (json.dumps({"velocity": [0.3, 0], "duration": 1}), '{"velocity": [NaN, 0, 0], "duration": 1}',
                json.dumps({"velocity": [0, 0, 0], "duration": -1}), json.dumps({"velocity": ["a", 0, 0]})):
        assert sport.answer(7105, bad, controller, 0.0)[0] == 3204, bad
    assert sport.answer(7105, json.dumps({"velocity": [9, -9, 9], "duration": 1}), controller, 0.0)[0] == 0
    assert list(controller.command_now(0.0)) == [1.0, -0.5, 1.0]  # clipped to the policy's range
    for unsupported in (7004, 7005, 7006, 7103, 7104, 7106, 9999):
        assert sport.answer(unsupported, json.dumps({"data": 0}), controller, 0.0) == (3203, "")


def test_sport_mode_state_bytes_are_what_the_binding_serializes():
    from zensim.unitree.highlevel_dds import encode_sport_mode_state
    from zensim.unitree.idl import GoIMUState_, PathPoint_, SportModeState_, TimeSpec_

    rng = np.random.default_rng(1)

    def floats(n):
        return [float(v) for v in rng.normal(size=n).astype(np.float32)]

    state = SportModeState_(
        stamp=TimeSpec_(sec=12, nanosec=345_000_000), error_code=7,
        imu_state=GoIMUState_(quaternion=floats(4), gyroscope=floats(3), accelerometer=floats(3), rpy=floats(3),
                              temperature=41),
        mode=3, progress=0.5, gait_type=1, foot_raise_height=0.125, position=floats(3), body_height=0.75,
        velocity=floats(3), yaw_speed=0.25, range_obstacle=floats(4), foot_force=[1, -2, 300, -400],
        foot_position_body=floats(12), foot_speed_body=floats(12),
        path_point=[PathPoint_(*floats(7)) for _ in range(10)])
    assert encode_sport_mode_state(state) == state.serialize()
    assert SportModeState_.deserialize(encode_sport_mode_state(state)) == state


def _torchscript_zip(path, data_pkl: bytes, storages: dict[str, bytes]) -> None:
    import zipfile

    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("policy/data.pkl", data_pkl)
        for key, raw in storages.items():
            archive.writestr(f"policy/data/{key}", raw)


def test_policy_converter_rebuilds_tensors_and_refuses_any_other_global(tmp_path):
    import pickle

    from zensim.robots.unitree_g1.policy.convert import load_torchscript

    # A tensor as TorchScript pickles it: _rebuild_tensor_v2((storage pid), offset, size, stride, ...),
    # here a 2x3 float32 matrix stored transposed (stride 1, 2) to check strides are honoured.
    raw = np.arange(6, dtype="<f4").tobytes()
    data = (b"\x80\x02c__torch__.legged_gym.utils.helpers\nPolicyExporterLSTM\n)\x81}X\x01\x00\x00\x00w"
            b"ctorch._utils\n_rebuild_tensor_v2\n((X\x07\x00\x00\x00storagectorch\nFloatStorage\n"
            b"X\x01\x00\x00\x000X\x03\x00\x00\x00cpuK\x06tQK\x00K\x02K\x03\x86K\x01K\x02\x86\x89"
            b"ccollections\nOrderedDict\n)RtRsb.")
    _torchscript_zip(tmp_path / "ok.pt", data, {"0": raw})
    module = load_torchscript(tmp_path / "ok.pt")
    assert module.class_name == "__torch__.legged_gym.utils.helpers.PolicyExporterLSTM"
    assert np.array_equal(module.attrs["w"], np.arange(6, dtype=np.float32).reshape(3, 2).T)
    # Anything else a pickle could call is refused before it runs.
    evil = b"\x80\x02cos\nsystem\nX\x04\x00\x00\x00trueq\x00\x85R."
    _torchscript_zip(tmp_path / "evil.pt", evil, {})
    with pytest.raises(pickle.UnpicklingError, match="refusing to load os.system"):
        load_torchscript(tmp_path / "evil.pt")
