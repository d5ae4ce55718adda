"""The G1 walking controller's pure parts (zensim loco: the numpy policy, the FSM, the arm blend and its
checks) and the sport service's answers (zensim unitree), with the controller behind the sport service's
`Walker` interface as the adapter reaches it over Zenoh."""

import json
import math

import numpy as np
import pytest

from zensim.loco.arms import ArmRules, arm_blend
from zensim.loco.controller import ArmBlend, LocoController
from zensim.loco.walk_policy import NUM_OBS, WalkPolicy, double_support, gravity_in_body, load_weights, observation
from zensim.robots import BUNDLED_DIR
from zensim.robots.walking import load_walking
from zensim.schemas import ArmCommand, Contacts, LocoStatus
from zensim.unitree import sport
from zensim.unitree.highlevel import foot_force

UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])
WALKING = load_walking(BUNDLED_DIR / "unitree_g1" / "walking.toml")
NUM_JOINTS = len(WALKING.joints)
STAND_Q = WALKING.stand_q
DEFAULT_LEG_Q = WALKING.leg_default_q
UPPER_KP, UPPER_KD = WALKING.upper_kp, WALKING.upper_kd


def new_controller() -> LocoController:
    return LocoController(WALKING)


class ControllerWalker:
    """sport.Walker over a controller in this process (the adapter's reaches `zensim loco` over Zenoh)."""

    def __init__(self, controller: LocoController, now_s: float = 0.0) -> None:
        self.controller = controller
        self.now_s = now_s

    def status(self) -> LocoStatus:
        state, c = self.controller.state, self.controller
        return LocoStatus(active=state.active, fsm_id=state.fsm_id, walking=state.walking,
                          balance_mode=state.balance_mode, commanded=tuple(c.command_now(self.now_s).tolist()))

    def request(self, fsm_id=None, balance_mode=None):  # noqa: ANN001, ANN201
        try:
            if fsm_id is not None:
                self.controller.set_fsm(fsm_id)
        except ValueError as exc:
            return LocoStatus(ok=False, error=str(exc))
        if balance_mode is not None:
            self.controller.state.balance_mode = balance_mode
        return self.status()

    def velocity(self, vx, vy, wz, duration_s):  # noqa: ANN001, ANN201
        self.controller.set_velocity(vx, vy, wz, duration_s, self.now_s)


def test_policy_is_the_declared_lstm_and_keeps_state_until_reset():
    weights = load_weights(WALKING.weights)
    assert weights["lstm_weight_ih"].shape == (256, NUM_OBS) and weights["actor2_weight"].shape == (12, 32)
    policy = WalkPolicy(weights, DEFAULT_LEG_Q)
    obs = observation(np.zeros(3), UPRIGHT, np.zeros(3), DEFAULT_LEG_Q, np.zeros(12), np.zeros(12), 0.0, DEFAULT_LEG_Q)
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
                      np.ones(12), np.full(12, 0.5), 0.2, DEFAULT_LEG_Q)
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
    controller = new_controller()
    assert tick(controller, 0.0) is None
    controller.set_fsm(706)
    sent = [t for t in np.arange(0, 1.0, 0.002) if tick(controller, float(t)) is not None]
    assert len(sent) == 50 and np.allclose(np.diff(sent), 0.02)


def test_squat_to_stand_hands_over_to_the_policy_and_toggles_back():
    controller = new_controller()
    controller.set_fsm(706)
    for t in np.arange(0, 3.0, 0.02):
        targets = tick(controller, float(t))
    assert controller.state.walking and controller.policy_steps > 0
    assert np.all(targets.kp[12:] == UPPER_KP)
    controller.set_fsm(706)  # standing: stand-to-squat
    assert not controller.state.walking


def test_a_sim_reset_restarts_the_mode_from_the_spawn_pose():
    controller = new_controller()
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
    controller = new_controller()
    controller.set_fsm(500)
    for t in np.arange(0, 3.0, 0.02):
        base = tick(controller, float(t))
    ones = np.ones(17)
    controller.set_arm(ArmBlend(q=ones, dq=0 * ones, kp=60 * ones, kd=1.5 * ones, tau=0 * ones, weight=0.25))
    blended = tick(controller, 3.0)
    assert np.allclose(blended.q[15:], 0.25) and np.allclose(blended.kp[15:], 0.25 * 60 + 0.75 * UPPER_KP)
    assert np.allclose(blended.q[12:15], 0.25) and np.all(blended.kp[12:15] == UPPER_KP)
    assert np.array_equal(blended.kp[:12], base.kp[:12])


def test_sport_answers_codes_as_the_robot():
    controller = new_controller()
    walker = ControllerWalker(controller)
    assert sport.answer(1, "{}", walker) == (0, "1.0.0.0")
    assert sport.answer(7001, "{}", walker) == (0, json.dumps({"data": 0}))
    assert sport.answer(7101, json.dumps({"data": 706}), walker) == (0, "")
    assert json.loads(sport.answer(7001, "{}", walker)[1]) == {"data": 706}
    for bad in ("not json", "[1]", json.dumps({"data": 12345}), json.dumps({"data": 1.5}), json.dumps({"data": True})):
        assert sport.answer(7101, bad, walker)[0] == 3204, bad
    assert controller.state.fsm_id == 706  # nothing changed
    good = json.dumps({"velocity": [0.3, 0, 0], "duration": 2.0})
    walker.now_s = 1.0
    assert sport.answer(7105, good, walker) == (0, "")
    walker.now_s = 0.0
    assert list(controller.command_now(2.9)) == [0.3, 0, 0] and not any(controller.command_now(3.0))
    for bad in (json.dumps({"velocity": [0.3, 0], "duration": 1}), '{"velocity": [NaN, 0, 0], "duration": 1}',
                json.dumps({"velocity": [0, 0, 0], "duration": -1}), json.dumps({"velocity": ["a", 0, 0]})):
        assert sport.answer(7105, bad, walker)[0] == 3204, bad
    assert sport.answer(7105, json.dumps({"velocity": [9, -9, 9], "duration": 1}), walker)[0] == 0
    assert list(controller.command_now(0.0)) == [1.0, -0.5, 1.0]  # clipped to the policy's range
    for unsupported in (7004, 7005, 7006, 7103, 7104, 7106, 9999):
        assert sport.answer(unsupported, json.dumps({"data": 0}), walker) == (3203, "")


def test_sport_refuses_every_number_it_cannot_represent_and_never_raises():
    """Issue 27 item 1: `{"data": 1000...0}` (400 digits) raised OverflowError past a ValueError-only
    handler and killed the adapter's DDS thread. Every such parameter is a 3204 and changes nothing."""
    controller = new_controller()
    walker = ControllerWalker(controller)
    assert sport.answer(7101, json.dumps({"data": 706}), walker) == (0, "")
    assert sport.answer(7105, json.dumps({"velocity": [0.2, 0, 0], "duration": 5}), walker) == (0, "")
    huge = "1" + "0" * 400
    hostile = {
        7101: ['{"data": %s}' % huge, '{"data": -%s}' % huge, '{"data": 1e400}', '{"data": %d}' % 2**31,
               '{"data": %s.0}' % huge, '{"data": "1" }', '{"data": [706]}', '{"data": %s}' % ("9" * 5000)],
        7102: ['{"data": %s}' % huge, '{"data": 1e308}'],
        7105: ['{"velocity": [%s, 0, 0], "duration": 1}' % huge, '{"velocity": [0, 0, 0], "duration": %s}' % huge,
               '{"velocity": [1e300, 0, 0], "duration": 1}', '{"velocity": [0, -%s, 0]}' % huge,
               '{"velocity": [0, 0, 1e400], "duration": 1}', '{"velocity": [0, 0, 0], "duration": 1e10}',
               '{"velocity": [0, 0, 0], "duration": 1, "pad": "%s"}' % ("x" * 5000)],
    }
    for api_id, parameters in hostile.items():
        for parameter in parameters:
            assert sport.answer(api_id, parameter, walker) == (3204, ""), (api_id, parameter[:60])
    assert controller.state.fsm_id == 706 and list(controller.command_now(1.0)) == [0.2, 0, 0]  # nothing changed
    assert sport.answer(7101, json.dumps({"data": 706.0}), walker) == (0, "")  # an integral float is fine


def test_arm_commands_refuse_what_the_sim_would_refuse_and_take_what_it_would_take():
    """Issue 27 item 2: kp 1e6 (or q 1e30) at weight 1 was blended into every command of the walk, the sim
    refused them all and the G1 fell. Such a command is refused whole; a sane one passes."""
    n = 17
    q_min, q_max = -np.ones(29), np.ones(29)
    rules = ArmRules.of(WALKING, q_min, q_max, velocity_limit=np.full(29, 10.0), effort_limit=np.full(29, 25.0))
    names = rules.names
    assert names == WALKING.joints[12:]  # the G1's waist and arms: rt/arm_sdk's motors 12..28

    def error(**change):  # noqa: ANN003
        values = {"q": np.zeros(n), "dq": np.zeros(n), "kp": np.full(n, 60.0), "kd": np.full(n, 1.5),
                  "tau": np.zeros(n)}
        for name, (index, value) in change.items():
            values[name][index] = value
        try:
            arm_blend(ArmCommand(names=names, weight=1.0, **{k: tuple(v) for k, v in values.items()}), rules)
        except ValueError as exc:
            return str(exc)
        return None

    assert error() is None
    assert error(q=(6, 1.0 + 6.0)) is None  # within a full turn of its range: the sim clamps it
    assert error(kp=(3, UPPER_KP)) is None and error(kd=(3, UPPER_KD)) is None
    for bad in ({"kp": (6, 1e6)}, {"kd": (0, 1e4)}, {"q": (6, 1e30)}, {"q": (6, -1 - 7.0)}, {"dq": (2, 21.0)},
                {"tau": (16, -51.0)}, {"kp": (1, -1.0)}, {"q": (0, float("nan"))}, {"kp": (6, UPPER_KP + 1)}):
        assert error(**bad) is not None, bad
    with pytest.raises(ValueError):  # other joints, or the arm joints out of order
        arm_blend(ArmCommand(names=names[::-1], weight=1.0, q=(0.0,) * n, dq=(0.0,) * n, kp=(0.0,) * n,
                             kd=(0.0,) * n, tau=(0.0,) * n), rules)
    with pytest.raises(ValueError):  # the schema: weight in 0..1
        ArmCommand(names=names, weight=float("inf"), q=(0.0,) * n, dq=(0.0,) * n, kp=(0.0,) * n, kd=(0.0,) * n,
                   tau=(0.0,) * n)


def test_at_zero_velocity_the_policy_hands_over_to_the_planted_stance_at_double_support():
    """Issue 28: the policy alone steps in place at zero velocity (the robot crept 0.10-0.11 m in 2 s after
    StopMove); the controller stops stepping after `settle_s`, at an instant with both feet down."""
    controller = new_controller()
    controller.set_fsm(500)
    t = 0.0
    while t < 3.0:
        tick(controller, t)
        t += 0.02
    controller.set_velocity(0.4, 0, 0, 1.0, t)
    steps_walking = controller.policy_steps
    while not controller.state.planted:
        assert t < 10.0, "never planted"
        tick(controller, t)
        t += 0.02
    planted_at = t - 0.02
    assert controller.policy_steps > steps_walking and planted_at >= 4.0 + WALKING.settle_s
    assert double_support(planted_at) and not controller.stepping(planted_at)
    steps = controller.policy_steps
    for _ in range(100):
        held = tick(controller, t)
        t += 0.02
    assert controller.policy_steps == steps  # no stepping while planted
    assert np.allclose(held.q, STAND_Q) and np.array_equal(held.kp[WALKING.legs], WALKING.ramp_kp[WALKING.legs])
    assert np.all(held.kp[12:] == UPPER_KP)  # the upper body as while walking
    controller.set_velocity(0.4, 0, 0, 1.0, t)
    tick(controller, t)
    assert controller.policy_steps == steps + 1 and controller.stepping(t)  # the next command walks again


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


def test_foot_force_is_each_foots_normal_force_in_newtons_within_int16():
    def contacts(*normal: float) -> Contacts:
        n = len(normal)
        return Contacts(sim_time_s=1.0, seq=1, links=tuple(f"foot{i}" for i in range(n)), in_contact=(True,) * n,
                        normal_force_n=normal, force_world=((0.0, 0.0, 0.0),) * n, points=(1,) * n)

    assert foot_force(None) == [0, 0, 0, 0]  # no contacts seen yet
    assert foot_force(contacts()) == [0, 0, 0, 0]  # a robot without feet
    assert foot_force(contacts(172.4, 171.6)) == [172, 172, 0, 0]  # the G1: left, right; no hind feet
    # Anyone may publish a state: what is no force reads 0, what int16 cannot hold its largest; never raises.
    assert foot_force(contacts(math.nan, -5.0, math.inf, 1e9, 3.0)) == [0, 0, 0, 32767]
