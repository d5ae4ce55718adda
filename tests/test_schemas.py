"""The wire contract: every message round-trips in msgpack and JSON, bad input fails loudly."""

from __future__ import annotations

import json
import math
from typing import cast, Any

import msgspec
import pytest

from zensim.schemas import (
    WIRE_TYPES,
    ArmCommand,
    CtlReply,
    PushRequest,
    SimStatus,
    LocoRequest,
    VelocityCommand,
    Codec,
    DecodeError,
    JointState,
    JointTargets,
    Keys,
    MotorCommand,
    ResetRequest,
    RobotInfo,
    StepRequest,
    WorldInfo,
    check_robot_id,
    decode_scalar,
    is_json,
)
from zensim.robots import robot_files
from zensim.robots.builder import mode_figures
from zensim.schemas import generate
from zensim.sim.physics import Limits
from zensim.sim.world import World
from zensim.schemas.topics import TOPICS

SAMPLES = {
    "joint_state": dict(sim_time_s=1.5, seq=7, q=[0.1, 0.2], dq=[0.0, -1.0], tau=[3.0, 4.0]),
    "odometry": dict(sim_time_s=1.5, seq=7, pos=[0, 0, 0.79], quat_wxyz=[1, 0, 0, 0], lin_vel_world=[0, 0, 0], ang_vel_body=[0, 0, 0]),
    "imu": dict(sim_time_s=1.5, seq=7, quat_wxyz=[1, 0, 0, 0], gyro=[0, 0, 0], accel=[0, 0, 9.81]),
    "sim_status": dict(sim_time_s=1.0, rtf=0.99, paused=False, mode="floating", fallen=False, rejected_commands=3, command_age_s=0.01),
    "motor_command": dict(names=["a", "b"], q=[0.1, 0.2], kp=[100, 100], kd=[1, 1], dq=[0, 0], tau=[0, 0]),
    "joint_targets": dict(names=["a"], q=[0.5]),
    "bridge_report": dict(key="zensim/g1/cmd/joints", accepted=False, error="unknown joint(s): x"),
    "reset_request": dict(names=["a"], q=[0.3], base_height_m=0.8, mode="fixed"),
    "pause_request": {},
    "resume_request": {},
    "step_request": dict(n=5),
    "mode_request": dict(mode="fixed"),
    "ctl_reply": dict(ok=False, error="nope", sim_time_s=2.0, paused=True, mode="fixed", steps=3),
    "robot_info": dict(
        robot="g1", model="g1_29dof", schema_version=1, joint_names=["a"], q_min=[-1], q_max=[1], effort_limit=[10],
        velocity_limit=[5], default_q={"floating": [0.0], "fixed": [0.0]},
        gains={"floating": {"kp": [100], "kd": [1]}, "fixed": {"kp": [50], "kd": [0.5]}},
        base_height_m={"floating": 0.85, "fixed": 0.79}, mode="floating", timestep_s=0.002, state_rate_hz=100,
        status_rate_hz=10, watchdog_timeout_s=0.5, mesh_paths=["meshes/a.STL"], keys=[msgspec.to_builtins(TOPICS[0].info("zensim/g1"))],
    ),    "unitree_status": dict(seq=3, dds_domain_id=1, dds_interface="lo", lowcmd_received=10, lowcmd_forwarded=8,
                           crc_errors=1, rejected=1, lowstate_rate_hz=500.0, command_age_s=0.002, last_error="crc mismatch"),
}
# Lockstep (issue 12): the command a lockstep advance applied, and ctl/advance's answer.
SAMPLES.update({
    "applied_command": dict(sim_time_s=0.02, seq=2, steps=10, command=SAMPLES["motor_command"]),
    "advance_reply": dict(ok=True, sim_time_s=0.04, steps=20, joints=SAMPLES["joint_state"], odom=SAMPLES["odometry"],
                          imu=SAMPLES["imu"]),
})
# Foot contacts (issue 29 item 5): two feet, one in the air; a reply of the new instant may carry them.
SAMPLES["contacts"] = dict(sim_time_s=1.5, seq=7, links=["left_ankle_roll_link", "right_ankle_roll_link"],
                           in_contact=[False, True], normal_force_n=[0.0, 344.5],
                           force_world=[[0.0, 0.0, 0.0], [1.5, -0.2, 344.4]], points=[0, 4])
SAMPLES["advance_reply"] = {**cast(dict, SAMPLES["advance_reply"]), "contacts": SAMPLES["contacts"]}
# A world's lockstep (issue 21).
SAMPLES["world_advance_request"] = dict(commands={"g1a": SAMPLES["motor_command"]})
SAMPLES["world_advance_reply"] = dict(ok=True, sim_time_s=0.02, steps=10, states={"g1a": dict(
    joints=SAMPLES["joint_state"], odom=SAMPLES["odometry"], imu=SAMPLES["imu"], contacts=SAMPLES["contacts"])})
# A world's robots, for the viewer (issue 21).
SAMPLES["world_info"] = dict(world="lab", robots=[dict(robot="g1a", model="g1_29dof", mode="floating", xy=[0.0, 0.0]),
                                                  dict(robot="arm", model="arm", mode="fixed", xy=[0.0, 3.0], yaw_deg=90.0)])
# The ROS 1 gateway's status (issue 20).
SAMPLES["ros1_status"] = dict(seq=4, master_uri="http://127.0.0.1:11311", master_up=True, joint_states_published=400,
                              joint_states_rate_hz=100.0, commands_received=5, commands_forwarded=3, rejected=2,
                              last_error="unknown joint 'tail'", mesh_url="http://127.0.0.1:7011")
# The ROS 2 face's status (issue 30).
SAMPLES["ros2_status"] = dict(seq=2, transports=["zenoh", "dds"], domain_id=0, joint_states_published=200,
                              joint_states_rate_hz=100.0, sim_time_s=2.0, commands_received=4, commands_forwarded=3,
                              rejected=1, last_error="NaN in data", command_age_s=0.01)

# Walking (issue 28).
SAMPLES["velocity_command"] = dict(vx=0.4, vy=-0.1, wz=0.2, timeout_s=0.5)
SAMPLES["arm_command"] = dict(names=["a", "b"], weight=0.5, q=[0.1, 0.2], dq=[0, 0], kp=[60, 60], kd=[1.5, 1.5],
                              tau=[0, 0])
SAMPLES["loco_request"] = dict(verb="walk")
SAMPLES["remote_state"] = dict(buttons=["A", "Up"], lx=0.5, ly=-0.25, rx=0.0, ry=1.0)
SAMPLES["loco_status"] = dict(seq=3, sim_time_s=4.2, active=True, fsm_id=500, walking=True, stepping=True,
                              commanded=[0.4, 0.0, 0.0], achieved=[0.38, 0.01, 0.0], velocity_received=9)

# Disturbances (issue 29 item 2).
SAMPLES["push_request"] = dict(direction=[1.0, 0.0, 0.0], magnitude_n=80.0, duration_s=0.2, body="pelvis")
SAMPLES["band_request"] = dict(verb="on", length_m=0.5)
SAMPLES["faults_request"] = dict(verb="set", joints=[dict(joint="left_knee_joint", torque_scale=0.6, encoder_offset_rad=0.02)],
                                 sensors=dict(gyro_noise_std_rad_s=0.01, accel_bias_m_s2=[0.1, 0.0, 0.0]), seed=7)
PUSH_STATE = dict(body="pelvis", force_n=[80.0, 0.0, 0.0], start_s=2.0, duration_s=0.2, remaining_s=0.1,
                  impulse_n_s=[16.0, 0.0, 0.0])
BAND_STATE = dict(on=True, anchor=[0.0, 0.0, 3.05], length_m=0.0, stiffness_n_m=200.0, damping_n_s_m=100.0,
                  force_n=[0.0, 0.0, 340.0])


def test_disturbances_travel_in_the_status_and_the_reply_and_bad_ones_are_refused_on_decode() -> None:
    status = msgspec.convert({**cast(dict, SAMPLES["sim_status"]), "pushes": [PUSH_STATE], "pushes_applied": 1,
                              "last_push": PUSH_STATE, "band": BAND_STATE}, SimStatus)
    for codec_type, message in ((SimStatus, status),
                                (CtlReply, msgspec.convert(dict(ok=True, push=PUSH_STATE, band=BAND_STATE), CtlReply))):
        codec: Codec[Any] = Codec(codec_type)
        for fmt in ("json", "msgpack"):
            assert codec.decode(codec.encode(message, fmt)) == message
    # An old status (none of the new fields) reads as no disturbance at all.
    old = Codec(SimStatus).decode(json.dumps(SAMPLES["sim_status"]).encode(), "application/json")
    assert old.pushes == () and old.band is None and old.last_push is None and old.pushes_applied == 0
    push = Codec(PushRequest)
    with pytest.raises(DecodeError, match="magnitude_n"):
        push.decode(msgspec.msgpack.encode({**cast(dict, SAMPLES["push_request"]), "magnitude_n": float("inf")}),
                    "application/msgpack")
    with pytest.raises(DecodeError, match="direction"):
        push.decode(b'{"direction": [0, 0, 0], "magnitude_n": 1, "duration_s": 1}', "application/json")


def test_walking_messages_refuse_what_no_robot_could_do() -> None:
    """NaN, absurd speeds, impossible timeouts, verb and id together, weights beyond 0..1: refused on decode."""
    velocity, request, arm = Codec(VelocityCommand), Codec(LocoRequest), Codec(ArmCommand)
    for bad in ({"vx": 1e9}, {"wz": -11}, {"vx": 0.1, "timeout_s": -1}, {"timeout_s": 1e7}, {"v_x": 0.3}, {"vx": "1"}):
        with pytest.raises(DecodeError):
            velocity.decode(json.dumps(bad).encode(), "application/json")
    with pytest.raises(DecodeError):
        velocity.decode(msgspec.msgpack.encode({"vx": float("nan")}), "application/msgpack")
    for bad_request in ({"verb": "fly"}, {"verb": "walk", "fsm_id": 500}, {"fsm_id": 2**40}, {"balance_mode": 2}, {"x": 1}):
        with pytest.raises(DecodeError):
            request.decode(json.dumps(bad_request).encode(), "application/json")
    changes: list[dict[str, object]] = [{"weight": 1.5}, {"kp": [-1, 0]}, {"q": [0.1]}, {"names": ["a", "a"]}]
    for change in changes:
        with pytest.raises(DecodeError):
            arm.decode(json.dumps({**cast(dict, SAMPLES["arm_command"]), **change}).encode(), "application/json")
    assert velocity.decode(b"{}", "application/json").timeout_s == 0.5  # a bare stop, lapsing by itself


def tag(message_type: type) -> str:
    return generate.tag_of(message_type)


def test_every_wire_type_has_a_sample() -> None:
    assert {tag(t) for t in WIRE_TYPES} == set(SAMPLES)


@pytest.mark.parametrize("message_type", WIRE_TYPES, ids=tag)
@pytest.mark.parametrize("fmt", ["msgpack", "json"])
def test_round_trip(message_type: type, fmt: str) -> None:
    codec: Codec[Any] = Codec(message_type)
    message: Any = msgspec.convert(SAMPLES[tag(message_type)], message_type)
    assert codec.decode(codec.encode(message, fmt)) == message  # type: ignore[arg-type]


@pytest.mark.parametrize("message_type", WIRE_TYPES, ids=tag)
def test_json_needs_no_type_tag(message_type: type) -> None:
    """A client typing JSON by hand leaves the tag out: the key says the type."""
    payload = json.dumps(SAMPLES[tag(message_type)]).encode()
    assert Codec(message_type).decode(payload, encoding=None) == msgspec.convert(SAMPLES[tag(message_type)], message_type)


def test_writers_tag_their_messages() -> None:
    encoded = json.loads(Codec(JointTargets).encode(JointTargets(names=("a",), q=(1.0,)), "json"))
    assert encoded["type"] == "joint_targets"


def test_wrong_tag_is_rejected() -> None:
    with pytest.raises(DecodeError, match="type"):
        Codec(JointTargets).decode(b'{"type": "motor_command", "names": ["a"], "q": [1]}')


@pytest.mark.parametrize(
    "payload, field",
    [
        (b'{"q": [0.1, "x"]}', "q[1]"),
        (b'{"q": [0.1], "names": ["a", "b"]}', "q"),
        (b'{"q": [0.1, 0.2], "kp": [1.0]}', "kp"),
        (b'{"q": [0.1], "kd": [-1.0]}', "kd[0]"),
        (b'{"q": [1e999]}', "q[0]"),
        (b'{"names": ["a", "a"], "q": [1, 2]}', "names"),
        (b'{"dq": [1]}', "q"),
        (b'{"q": 3}', "q"),
    ],
)
def test_bad_motor_command_names_the_field(payload: bytes, field: str) -> None:
    with pytest.raises(DecodeError) as info:
        Codec(MotorCommand).decode(payload)
    assert field in str(info.value)


@pytest.mark.parametrize("field", ["q", "dq", "kp", "kd", "tau"])
def test_nan_in_msgpack_command_is_rejected(field: str) -> None:
    fields = {"q": [0.0, 0.0], field: [0.0, math.nan]}
    with pytest.raises(DecodeError, match=rf"`{field}\[1\]` must be a finite number"):
        Codec(MotorCommand).decode(msgspec.msgpack.encode(fields))


@pytest.mark.parametrize("payload", [b"\xff\x00\x13", b"{not json", b"\x93\x01\x02\x03", b"[1, 2]", b"null"])
def test_malformed_bytes_raise_decode_error(payload: bytes) -> None:
    with pytest.raises(DecodeError, match="invalid MotorCommand"):
        Codec(MotorCommand).decode(payload)


def test_joint_targets_lengths_must_match() -> None:
    with pytest.raises(DecodeError, match="`q` has 1 values but `names` has 2"):
        Codec(JointTargets).decode(b'{"names": ["a", "b"], "q": [1]}')


def test_step_request_is_bounded() -> None:
    assert Codec(StepRequest).decode(b"").n == 1
    with pytest.raises(DecodeError, match="`n` must be in"):
        Codec(StepRequest).decode(b'{"n": 0}')


def _robot(robot: str = "g1a", xy: list[float] = [0.0, 0.0]) -> dict:
    return dict(robot=robot, model="g1_29dof", mode="floating", xy=xy)


@pytest.mark.parametrize("world, robots, why", [
    ("lab", [_robot("G1")], r"robots\[0\]\.robot"),                            # not a robot id
    ("lab", [_robot("a/b")], r"robots\[0\]\.robot"),                           # a key chunk cannot hold `/`
    ("lab/**", [_robot()], r"\$\.world"),
    ("lab", [_robot(xy=[math.nan, 0.0])], "xy"),
    ("lab", [_robot(f"r{i}") for i in range(257)], "robots"),                  # past a world file's 256
])
def test_world_info_is_bounded(world: str, robots: list[dict], why: str) -> None:
    assert Codec(WorldInfo).decode(msgspec.msgpack.encode({"world": "lab", "robots": [_robot()]})).robots[0].robot == "g1a"
    with pytest.raises(DecodeError, match=why):
        Codec(WorldInfo).decode(msgspec.msgpack.encode({"world": world, "robots": robots}))


def test_empty_payload_means_defaults() -> None:
    assert Codec(ResetRequest).decode(b"") == ResetRequest()


def test_json_is_recognised_by_encoding_or_content() -> None:
    assert is_json(b'{"q": [1]}', None)
    assert is_json(b' {"q": [1]}', "zenoh/bytes")
    assert is_json(b"anything", "application/json")
    assert not is_json(msgspec.msgpack.encode({"q": [1.0]}), None)
    assert not is_json(b'{"q": [1]}', "application/msgpack")


@pytest.mark.parametrize(
    "payload, encoding, value",
    [(b"0.9", None, 0.9), (b" -1.25\n", "text/plain", -1.25), (b"2", "application/json", 2.0),
     (msgspec.msgpack.encode(0.5), "application/msgpack", 0.5), (msgspec.msgpack.encode(-0.75), None, -0.75)],
)
def test_bare_numbers(payload: bytes, encoding: str | None, value: float) -> None:
    assert decode_scalar(payload, encoding) == value


@pytest.mark.parametrize("payload", [b"", b"abc", b"NaN", b"1e999", b'"0.5"', b"[1]"])
def test_bad_bare_numbers(payload: bytes) -> None:
    with pytest.raises(DecodeError):
        decode_scalar(payload)


def test_state_messages_carry_the_contract_field_names() -> None:
    encoded = json.loads(Codec(JointState).encode(JointState(sim_time_s=0, seq=1, q=(), dq=(), tau=()), "json"))
    assert {"sim_time_s", "seq", "q", "dq", "tau"} <= set(encoded)


def test_json_schemas_are_up_to_date() -> None:
    """Run `python -m zensim.schemas.generate` when this fails."""
    rendered = generate.render()
    on_disk = {p.name: p.read_text() for p in generate.SCHEMA_DIR.glob("*.json")}
    assert on_disk == rendered


class TestKeys:
    def test_layout(self) -> None:
        keys = Keys("g1")
        assert keys.joints == "zensim/g1/state/joints"
        assert keys.motors == "zensim/g1/cmd/motors"
        assert keys.joint_target("left_knee_joint") == "zensim/g1/cmd/joint/left_knee_joint"
        assert keys.joint_from_target_key("zensim/g1/cmd/joint/left_knee_joint") == "left_knee_joint"
        assert keys.ctl("reset") == "zensim/g1/ctl/reset"
        assert keys.alive("sim") == "zensim/g1/alive/sim"

    def test_mesh_keys_hold_no_empty_chunks(self) -> None:
        keys = Keys("g1")
        assert keys.mesh("meshes/pelvis.STL") == "zensim/g1/info/mesh/meshes/pelvis.STL"
        assert keys.mesh("package://g1_description/meshes/a.STL") == "zensim/g1/info/mesh/g1_description/meshes/a.STL"
        assert keys.mesh_path(keys.mesh("meshes/a.STL")) == "meshes/a.STL"

    @pytest.mark.parametrize("bad", ["G1", "g 1", "", "g1/x", "g*"])
    def test_robot_id_is_checked(self, bad: str) -> None:
        with pytest.raises(ValueError, match="robot id"):
            check_robot_id(bad)
        with pytest.raises(ValueError):
            Keys(bad)

    def test_unknown_ctl_verb(self) -> None:
        with pytest.raises(ValueError, match="unknown ctl verb"):
            Keys().ctl("explode")

    def test_every_wire_message_travels_on_a_topic(self) -> None:
        carried = {t.message for t in TOPICS} | {t.reply for t in TOPICS}
        missing = [m.__name__ for m in WIRE_TYPES if m not in carried]
        assert not missing, f"messages on no topic: {missing}"


@pytest.mark.parametrize("value", [b"1e300", b"-1", b"4.0", b'"steep"'])
def test_a_description_with_an_absurd_fall_threshold_is_refused_whole(value: bytes) -> None:
    """RobotInfo.fall_tilt_rad comes from a sim, or from a recording anyone can write: a tilt beyond [0, pi] rad
    (or not a number) refuses the whole description; a sane one decodes."""
    sim = World.alone("g1", robot_files("g1"), "floating", Limits(5000.0, 500.0), 0.5).robots[0]
    good = msgspec.json.encode(sim.robot_info(Keys("g1"), 100, 10, {"floating": mode_figures(sim.files, "floating", None)}))
    assert msgspec.json.decode(good, type=RobotInfo).fall_tilt_rad == 1.0
    with pytest.raises((msgspec.ValidationError, msgspec.DecodeError)):
        msgspec.json.decode(good.replace(b'"fall_tilt_rad":1.0', b'"fall_tilt_rad":' + value), type=RobotInfo)
