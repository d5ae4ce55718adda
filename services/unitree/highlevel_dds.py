"""The DDS side of the G1's high-level interface, on the adapter's participant (dds.py's):

    rt/api/sport/request     Request_         read    (LocoClient: the "sport" service)
    rt/api/sport/response    Response_        written
    rt/arm_sdk               LowCmd_          read    (raw bytes, decoded by codec.py like rt/lowcmd)
    rt/odommodestate         SportModeState_  written (unitree_go layout; 50 Hz of sim time)
    rt/lf/odommodestate      SportModeState_  written (the low-frequency copy; 10 Hz of sim time)

Its read conditions join the adapter's waitset, so the one DDS thread wakes for these too.
SportModeState_ is written as raw bytes packed with `struct` (SPORT_MODE_STATE_CDR, checked against the
binding's serializer in the tests): the binding's own serializer took ~0.3 ms of GIL-held Python per
message, which at 60 messages a second measurably slowed the DDS thread's LowCmd_ reading under load.
"""

from __future__ import annotations

import struct
from typing import Final

from cyclonedds._clayer import ddspy_write
from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from .dds import UnitreeDds, take_serialized
from .idl import LowCmd_, Request_, Response_, SportModeState_
from .requests import REQUEST_HISTORY

SPORT_REQUEST = "rt/api/sport/request"
SPORT_RESPONSE = "rt/api/sport/response"
ARM_SDK_TOPIC = "rt/arm_sdk"
ODOM_STATE_TOPIC = "rt/odommodestate"
ODOM_STATE_LF_TOPIC = "rt/lf/odommodestate"

SPORT_MODE_STATE_CDR: Final = struct.Struct("<iII" "4f3f3f3fB" "Bxx" "fBxxx" "f3ff3ff4f4h12f12f70f")
"""unitree_go SportModeState_ as XCDR1 little-endian after the 4-byte header: stamp (sec, nanosec),
error_code, imu_state (quaternion, gyroscope, accelerometer, rpy, temperature), mode, progress,
gait_type, foot_raise_height, position, body_height, velocity, yaw_speed, range_obstacle, foot_force,
foot_position_body, foot_speed_body, path_point (10 x 7 floats); each field aligned to its own size."""
CDR_HEADER: Final = b"\x00\x01\x00\x00"


def encode_sport_mode_state(state: SportModeState_) -> bytes:
    """The serialized form of `state` (header included), as the cyclonedds binding writes it."""
    imu = state.imu_state
    points = [v for p in state.path_point for v in (p.t_from_start, p.x, p.y, p.yaw, p.vx, p.vy, p.vyaw)]
    return CDR_HEADER + SPORT_MODE_STATE_CDR.pack(
        state.stamp.sec, state.stamp.nanosec, state.error_code, *imu.quaternion, *imu.gyroscope,
        *imu.accelerometer, *imu.rpy, imu.temperature, state.mode, state.progress, state.gait_type,
        state.foot_raise_height, *state.position, state.body_height, *state.velocity, state.yaw_speed,
        *state.range_obstacle, *state.foot_force, *state.foot_position_body, *state.foot_speed_body, *points)


class HighLevelDds:
    """Readers and writers of the sport service, arm_sdk and SportModeState_ on `dds`'s participant."""

    def __init__(self, dds: UnitreeDds) -> None:
        participant = dds.participant
        self.request_reader = DataReader(participant, Topic(participant, SPORT_REQUEST, Request_),
                                         qos=Qos(Policy.History.KeepLast(REQUEST_HISTORY)))
        self.response_writer = DataWriter(participant, Topic(participant, SPORT_RESPONSE, Response_))
        self.arm_sdk_reader = DataReader(participant, Topic(participant, ARM_SDK_TOPIC, LowCmd_))
        self.odom_writer = DataWriter(participant, Topic(participant, ODOM_STATE_TOPIC, SportModeState_))
        self.odom_lf_writer = DataWriter(participant, Topic(participant, ODOM_STATE_LF_TOPIC, SportModeState_))
        mask = SampleState.NotRead | ViewState.Any | InstanceState.Any
        self.request_ready = ReadCondition(self.request_reader, mask)
        self.arm_sdk_ready = ReadCondition(self.arm_sdk_reader, mask)
        dds.waitset.attach(self.request_ready)
        dds.waitset.attach(self.arm_sdk_ready)

    def has_request(self) -> bool:
        return bool(self.request_ready.triggered)

    def has_arm_sdk(self) -> bool:
        return bool(self.arm_sdk_ready.triggered)

    def take_requests(self) -> list[bytes]:
        """Every waiting sport request, serialized (requests.py decodes those it answers)."""
        return take_serialized(self.request_reader, REQUEST_HISTORY)

    def respond(self, response: Response_) -> None:
        self.response_writer.write(response)

    def take_arm_sdk(self, max_samples: int = 64) -> list[bytes]:
        """Serialized LowCmd_ samples from rt/arm_sdk (header included), oldest first."""
        return take_serialized(self.arm_sdk_reader, max_samples)

    def write_odom(self, state: SportModeState_, low_frequency: bool) -> None:
        data = encode_sport_mode_state(state)
        for writer in (self.odom_writer, self.odom_lf_writer) if low_frequency else (self.odom_writer,):
            ret = ddspy_write(writer._ref, data)
            if ret < 0:
                raise OSError(f"dds_write of SportModeState_ failed with {ret}")
