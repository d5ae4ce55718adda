"""LowCmd_ and LowState_ to and from their serialized DDS form (XCDR, little-endian), with numpy.

Cyclone DDS's Python (de)serializer builds one Python object per motor: about 0.7 ms to read a
LowCmd_ and 1.5 ms to write a LowState_ here, more than a 500 Hz loop has. The two messages have a
fixed size, so they are read and written here as numpy structured arrays instead (a few
microseconds). types in idl.py stay the definition of record; tests check that both agree.

Two layouts of the same fields matter:
- the CDR on the wire: the 4-byte encapsulation header, then each field aligned to its own size
  counted from the end of the header; a nested struct is not padded to its own alignment, so the
  first motor's `mode` byte sits right after `mode_machine` (LowCmd_) or the IMU's `temperature`
  (LowState_) and every later motor starts 4 bytes earlier than in C;
- the C struct the SDK packs for the CRC, where every motor starts on a 4-byte boundary.
Both are spelled out below as dtypes with explicit offsets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from .crc import unitree_crc

NUM_MOTORS: Final = 35
"""Motor slots in LowCmd_/LowState_ (the G1 29-DoF uses 0..28); idl.py's DDS types read it too."""

CDR_LE: Final = b"\x00\x01"
"""Encapsulation id of XCDR1 little-endian (what Cyclone DDS 0.10 writes for these types)."""
CDR2_LE: Final = (b"\x00\x07", b"\x00\x09", b"\x00\x0b")
"""XCDR2 little-endian (plain, delimited, parameter list): with no 8-byte members the layout is the same."""
HEADER: Final = CDR_LE + b"\x00\x00"

MOTOR_CMD_C = np.dtype({
    "names": ["mode", "q", "dq", "tau", "kp", "kd", "reserve"],
    "formats": ["u1", "<f4", "<f4", "<f4", "<f4", "<f4", "<u4"],
    "offsets": [0, 4, 8, 12, 16, 20, 24], "itemsize": 28,
})
LOW_CMD_C = np.dtype({
    "names": ["mode_pr", "mode_machine", "motor_cmd", "reserve", "crc"],
    "formats": ["u1", "u1", (MOTOR_CMD_C, NUM_MOTORS), ("<u4", 4), "<u4"],
    "offsets": [0, 1, 4, 984, 1000], "itemsize": 1004,
})
LOW_CMD_CDR_SIZE: Final = 1000
"""LowCmd_ after the header: the C struct less the 4 bytes of padding before motor 0's floats."""

IMU_C = np.dtype({
    "names": ["quaternion", "gyroscope", "accelerometer", "rpy", "temperature"],
    "formats": [("<f4", 4), ("<f4", 3), ("<f4", 3), ("<f4", 3), "<i2"],
    "offsets": [0, 16, 28, 40, 52], "itemsize": 56,
})
MOTOR_STATE_C = np.dtype({
    "names": ["mode", "q", "dq", "ddq", "tau_est", "temperature", "vol", "sensor", "motorstate", "reserve"],
    "formats": ["u1", "<f4", "<f4", "<f4", "<f4", ("<i2", 2), "<f4", ("<u4", 2), "<u4", ("<u4", 4)],
    "offsets": [0, 4, 8, 12, 16, 20, 24, 28, 36, 40], "itemsize": 56,
})
LOW_STATE_C = np.dtype({
    "names": ["version", "mode_pr", "mode_machine", "tick", "imu_state", "motor_state",
              "wireless_remote", "reserve", "crc"],
    "formats": [("<u4", 2), "u1", "u1", "<u4", IMU_C, (MOTOR_STATE_C, NUM_MOTORS), ("u1", 40), ("<u4", 4), "<u4"],
    "offsets": [0, 8, 9, 12, 16, 72, 2032, 2072, 2088], "itemsize": 2092,
})


class CodecError(ValueError):
    """A serialized sample that is not a LowCmd_ of this layout."""


@dataclass(frozen=True)
class LowCmd:
    """A decoded LowCmd_: `motors` is a structured array of the 35 MotorCmd_ (fields mode, q, dq, tau, kp, kd)."""

    mode_pr: int
    mode_machine: int
    motors: np.ndarray
    crc: int
    crc_ok: bool


def decode_low_cmd(data: bytes) -> LowCmd:
    """Read a serialized LowCmd_ (header included) and check its CRC.

    Raises:
        CodecError: wrong length or encapsulation.
    """
    if len(data) < 4 + LOW_CMD_CDR_SIZE or len(data) > 4 + LOW_CMD_CDR_SIZE + 3:  # writers pad to 4
        raise CodecError(f"a LowCmd_ is {4 + LOW_CMD_CDR_SIZE} bytes serialized, got {len(data)}")
    encapsulation = data[:2]
    if encapsulation != CDR_LE and encapsulation not in CDR2_LE:
        raise CodecError(f"unsupported encapsulation {encapsulation.hex()} (only little-endian CDR)")
    body = data[4:4 + LOW_CMD_CDR_SIZE]
    # C layout: mode_pr, mode_machine, 2 pad, motor 0's mode, 3 pad, then the CDR bytes from motor
    # 0's q on, which line up with C from there to the end.
    packed = bytearray(LOW_CMD_C.itemsize)
    packed[0:2] = body[0:2]
    packed[4] = body[2]
    packed[8:] = body[4:]
    raw = np.frombuffer(bytes(packed), LOW_CMD_C)[0]
    # Re-pack field by field so padding is zero whatever the sender left in it, as the SDK packs it.
    clean = np.zeros((), LOW_CMD_C)
    for name in ("mode_pr", "mode_machine", "reserve", "crc"):
        clean[name] = raw[name]
    for name in MOTOR_CMD_C.names or ():
        clean["motor_cmd"][name] = raw["motor_cmd"][name]
    crc = int(clean["crc"])
    return LowCmd(
        mode_pr=int(clean["mode_pr"]), mode_machine=int(clean["mode_machine"]),
        motors=clean["motor_cmd"], crc=crc, crc_ok=unitree_crc(clean.tobytes()) == crc,
    )


def new_low_state() -> np.ndarray:
    """A zeroed LowState_ in C layout, to fill field by field (`state["motor_state"]["q"][:29] = ...`)."""
    return np.zeros((), LOW_STATE_C)


def encode_low_state(state: np.ndarray) -> bytes:
    """Set the CRC of a C-layout LowState_ and serialize it as XCDR1 little-endian, header included."""
    state["crc"] = unitree_crc(state.tobytes())
    c = state.tobytes()
    # The reverse of the LowCmd_ shuffle: CDR has motor 0's mode right after the IMU temperature.
    return HEADER + c[0:70] + c[72:73] + b"\x00" + c[76:]
