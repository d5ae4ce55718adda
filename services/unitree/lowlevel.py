"""The mapping between Unitree's low-level messages and zensim's: no DDS, no zenoh.

LowCmd_ -> MotorCommand: motor i is joint i of the sim's canonical order (for the G1 29-DoF the
URDF's order, which is Unitree's motor order: 0 left_hip_pitch ... 28 right_wrist_yaw); slots past
the robot's joints (29-34 on the G1) are ignored. Every joint is sent, so a LowCmd_ is one complete
command as on the robot: an enabled motor (mode 1) gets its q, dq, kp, kd, tau; a disabled one
(mode 0) applies no torque, so it gets kp = kd = tau = 0.

`mode_pr` 1 (A/B: the ankle's two parallel-linkage motors) is not simulated: zensim's ankles are
plain pitch and roll joints. Such a command is applied as if it were pitch/roll (what
unitree_mujoco does) and counted, so a controller that switches to A/B keeps running but its
ankle targets mean pitch/roll. Any other mode_pr, a motor mode other than 0 or 1, a non-finite
value or a negative gain rejects the whole command.

JointState + Imu -> LowState_: tick is the sim time in ms, the IMU's quaternion, gyro and
accelerometer with roll/pitch/yaw derived from the quaternion, per motor q, dq and tau_est
(the torque applied in the last step), and `wireless_remote` from the newest RemoteState (cmd/remote) in
the remote's byte layout (`wireless_remote`). Fields the sim does not model stay 0.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Final

import numpy as np

from zensim.schemas import Imu, JointState, MotorCommand, RemoteState
from zensim.schemas.messages import REMOTE_BUTTONS

from .codec import NUM_MOTORS, LowCmd, encode_low_state, new_low_state

MODE_PR: Final = 0
MODE_AB: Final = 1
MOTOR_DISABLED: Final = 0
MOTOR_ENABLED: Final = 1


class LowCmdError(ValueError):
    """A LowCmd_ that is rejected whole; the message says which field and motor."""


@dataclass(frozen=True)
class Translated:
    """A LowCmd_ turned into a zensim command."""

    command: MotorCommand
    ab_mode: bool
    """True when the command asked for A/B ankle control, applied as pitch/roll."""


def motor_command(cmd: LowCmd, joint_names: tuple[str, ...]) -> Translated:
    """The MotorCommand for every joint of the robot from one LowCmd_ (CRC checked by the caller).

    Raises:
        LowCmdError: the command is invalid (see the module docstring).
    """
    if cmd.mode_pr not in (MODE_PR, MODE_AB):
        raise LowCmdError(f"mode_pr {cmd.mode_pr} is neither 0 (pitch/roll) nor 1 (A/B)")
    n = len(joint_names)
    motors = cmd.motors[:n]
    bad_mode = np.flatnonzero((motors["mode"] != MOTOR_DISABLED) & (motors["mode"] != MOTOR_ENABLED))
    if bad_mode.size:
        i = int(bad_mode[0])
        raise LowCmdError(f"motor_cmd[{i}].mode is {int(motors['mode'][i])}, expected 0 (disable) or 1 (enable)")
    for field in ("q", "dq", "tau", "kp", "kd"):
        bad = np.flatnonzero(~np.isfinite(motors[field]))
        if bad.size:
            i = int(bad[0])
            raise LowCmdError(f"motor_cmd[{i}].{field} is {float(motors[field][i])}")
    for field in ("kp", "kd"):
        bad = np.flatnonzero(motors[field] < 0)
        if bad.size:
            i = int(bad[0])
            raise LowCmdError(f"motor_cmd[{i}].{field} is negative ({float(motors[field][i])})")
    enabled = motors["mode"] == MOTOR_ENABLED
    zero = np.zeros(n)
    command = MotorCommand(
        names=joint_names,
        q=tuple(motors["q"].astype(float).tolist()),
        dq=tuple(motors["dq"].astype(float).tolist()),
        kp=tuple(np.where(enabled, motors["kp"], zero).tolist()),
        kd=tuple(np.where(enabled, motors["kd"], zero).tolist()),
        tau=tuple(np.where(enabled, motors["tau"], zero).tolist()),
    )
    return Translated(command=command, ab_mode=cmd.mode_pr == MODE_AB)


def rpy_from_wxyz(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad; Z-Y-X intrinsic, as Unitree's IMU reports them) of a unit quaternion."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


WIRELESS_REMOTE_BYTES: Final = 40
REMOTE_STICKS: Final = struct.Struct("<5f")
"""Bytes 4..23 of the remote: lx, rx, ry, L2 (analog, unused by the G1 programs), ly, little-endian float32."""


def wireless_remote(remote: RemoteState) -> bytes:
    """LowState_.wireless_remote for a remote state, in Unitree's layout (unitree_sdk2's
    `example/wireless_controller`): bytes 0-1 a header (0), bytes 2 and 3 the button bits in REMOTE_BUTTONS
    order (R1 is bit 0 of byte 2, A bit 0 of byte 3), then the sticks (REMOTE_STICKS), the rest 0."""
    bits = 0
    for name in remote.buttons:
        bits |= 1 << REMOTE_BUTTONS.index(name)
    l2 = 1.0 if "L2" in remote.buttons else 0.0
    data = bytes(2) + bytes((bits & 0xFF, bits >> 8)) + REMOTE_STICKS.pack(remote.lx, remote.rx, remote.ry, l2, remote.ly)
    return data + bytes(WIRELESS_REMOTE_BYTES - len(data))


class LowStateBuilder:
    """Pairs the sim's JointState and Imu of one instant into a serialized LowState_.

    The sim publishes both for every state it takes (same `seq`); whichever arrives second
    completes the pair. Not thread-safe: the caller holds a lock.

    Args:
        num_joints: the robot's joint count (at most 35).
        mode_machine: the robot type code LowState_ reports.
    """

    def __init__(self, num_joints: int, mode_machine: int) -> None:
        if num_joints > NUM_MOTORS:
            raise ValueError(f"LowState_ has {NUM_MOTORS} motor slots, the robot has {num_joints} joints")
        self._n = num_joints
        self._state = new_low_state()
        self._state["mode_machine"] = mode_machine
        self._state["motor_state"]["mode"][:num_joints] = MOTOR_ENABLED
        self._joints: JointState | None = None
        self._imu: Imu | None = None
        self._done_seq = -1
        self.mode_pr = MODE_PR
        """Echoed in LowState_.mode_pr: the mode of the last accepted command."""
        self.remote = bytes(WIRELESS_REMOTE_BYTES)
        """LowState_.wireless_remote (`wireless_remote`), from the newest cmd/remote."""

    def joints(self, message: JointState) -> bytes | None:
        """Take a JointState; returns the LowState_ when the pair is complete."""
        if len(message.q) != self._n or len(message.dq) != self._n or len(message.tau) != self._n:
            raise ValueError(f"JointState has {len(message.q)} joints, the robot {self._n}")
        self._joints = message
        return self._complete()

    def imu(self, message: Imu) -> bytes | None:
        """Take an Imu; returns the LowState_ when the pair is complete."""
        if len(message.quat_wxyz) != 4 or len(message.gyro) != 3 or len(message.accel) != 3:
            raise ValueError("Imu vectors have the wrong length")
        self._imu = message
        return self._complete()

    def pair(self) -> tuple[JointState, Imu] | None:
        """The JointState and Imu of the newest completed LowState_ (None before the first)."""
        if self._joints is None or self._imu is None or self._joints.seq != self._done_seq:
            return None
        return self._joints, self._imu

    def _complete(self) -> bytes | None:
        joints, imu = self._joints, self._imu
        if joints is None or imu is None or joints.seq != imu.seq or joints.seq == self._done_seq:
            return None
        self._done_seq = joints.seq
        state = self._state
        state["tick"] = int(round(joints.sim_time_s * 1000.0)) & 0xFFFFFFFF
        state["mode_pr"] = self.mode_pr
        imu_state = state["imu_state"]
        imu_state["quaternion"] = imu.quat_wxyz
        imu_state["gyroscope"] = imu.gyro
        imu_state["accelerometer"] = imu.accel
        imu_state["rpy"] = rpy_from_wxyz(*imu.quat_wxyz)
        motors = state["motor_state"]
        motors["q"][: self._n] = joints.q
        motors["dq"][: self._n] = joints.dq
        motors["tau_est"][: self._n] = joints.tau
        state["wireless_remote"] = np.frombuffer(self.remote, np.uint8)
        return encode_low_state(state)
