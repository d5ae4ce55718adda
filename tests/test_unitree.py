"""The Unitree adapter's pure parts: CRC, the numpy codec against the cyclonedds serializer, the mapping."""

import math

import numpy as np
import pytest

from unitree_sdk import low_cmd_crc, low_state_crc, new_low_cmd
from zensim.unitree.codec import decode_low_cmd, encode_low_state, new_low_state
from zensim.unitree.crc import crc32_mpeg2, unitree_crc, unitree_crc_reference
from zensim.unitree.idl import LowState_
from zensim.unitree.lowlevel import LowCmdError, motor_command, rpy_from_wxyz

NAMES = tuple(f"j{i}" for i in range(29))


def test_crc_check_values():
    assert crc32_mpeg2(b"123456789") == 0x0376E6E7  # CRC-32/MPEG-2's catalogue check value
    assert unitree_crc(bytes(1004)) == 0xFE172F9F  # a default hg LowCmd_, as the SDK computes it
    for seed in range(5):
        data = np.random.default_rng(seed).bytes(2092)
        assert unitree_crc(data) == unitree_crc_reference(data)


def sample_cmd():
    cmd = new_low_cmd()
    for i in range(35):
        m = cmd.motor_cmd[i]
        m.mode, m.q, m.dq, m.tau, m.kp, m.kd = (1 if i < 29 else 0), 0.1 * i, -0.01 * i, 0.5, 40.0 + i, 1.5
    cmd.motor_cmd[3].mode = 0  # disabled
    cmd.crc = low_cmd_crc(cmd)
    return cmd


def test_low_cmd_decodes_as_the_binding_serializes_it():
    cmd = sample_cmd()
    decoded = decode_low_cmd(cmd.serialize())
    assert decoded.crc_ok
    assert decoded.motors["kp"][:5].tolist() == [40, 41, 42, 43, 44]
    assert decoded.motors["mode"][:4].tolist() == [1, 1, 1, 0]
    cmd.motor_cmd[0].q = 9.0  # changed after the crc was computed
    assert not decode_low_cmd(cmd.serialize()).crc_ok


def test_low_state_encodes_as_the_binding_does():
    state = new_low_state()
    state["tick"] = 1234
    state["imu_state"]["quaternion"] = (1, 0, 0, 0)
    state["imu_state"]["temperature"] = -3
    state["motor_state"]["q"][:29] = np.arange(29) * 0.1
    state["motor_state"]["mode"][:29] = 1
    state["wireless_remote"][:] = np.arange(40)
    data = encode_low_state(state)
    decoded = LowState_.deserialize(data)
    assert decoded.serialize() == data  # byte for byte what cyclonedds writes
    assert decoded.tick == 1234 and decoded.motor_state[0].mode == 1 and decoded.imu_state.temperature == -3
    assert math.isclose(decoded.motor_state[3].q, 0.3, rel_tol=1e-6)
    assert low_state_crc(decoded) == decoded.crc


def test_disabled_motors_apply_no_torque():
    translated = motor_command(decode_low_cmd(sample_cmd().serialize()), NAMES)
    command = translated.command
    assert command.names == NAMES and len(command.q) == 29
    assert command.kp[3] == command.kd[3] == command.tau[3] == 0.0
    assert command.kp[4] == 44.0 and command.tau[4] == 0.5
    assert not translated.ab_mode


@pytest.mark.parametrize("field,value,message", [
    ("q", float("nan"), "motor_cmd[7].q"),
    ("kd", float("inf"), "motor_cmd[7].kd"),
    ("kp", -1.0, "negative"),
    ("mode", 3, "mode is 3"),
])
def test_invalid_commands_are_rejected_whole(field, value, message):
    cmd = sample_cmd()
    setattr(cmd.motor_cmd[7], field, value)
    cmd.crc = low_cmd_crc(cmd)
    with pytest.raises(LowCmdError, match=message.replace("[", r"\[").replace("]", r"\]")):
        motor_command(decode_low_cmd(cmd.serialize()), NAMES)


def test_mode_pr():
    cmd = sample_cmd()
    cmd.mode_pr = 1
    cmd.crc = low_cmd_crc(cmd)
    assert motor_command(decode_low_cmd(cmd.serialize()), NAMES).ab_mode
    cmd.mode_pr = 2
    cmd.crc = low_cmd_crc(cmd)
    with pytest.raises(LowCmdError, match="mode_pr"):
        motor_command(decode_low_cmd(cmd.serialize()), NAMES)


def test_rpy():
    half = math.radians(30) / 2
    roll, pitch, yaw = rpy_from_wxyz(math.cos(half), 0.0, 0.0, math.sin(half))
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9 and math.isclose(yaw, math.radians(30))
