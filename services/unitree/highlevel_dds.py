"""The DDS side of the G1's high-level interface, on the adapter's participant (dds.py's):

    rt/api/sport/request     Request_         read    (LocoClient: the "sport" service)
    rt/api/sport/response    Response_        written
    rt/arm_sdk               LowCmd_          read    (raw bytes, decoded by codec.py like rt/lowcmd)
    rt/odommodestate         SportModeState_  written (unitree_go layout; 50 Hz of sim time)
    rt/lf/odommodestate      SportModeState_  written (the low-frequency copy; 10 Hz of sim time)

Its read conditions join the adapter's waitset, so the one DDS thread wakes for these too.
"""

from __future__ import annotations

from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from .dds import UnitreeDds
from .idl import LowCmd_, Request_, Response_, SportModeState_

SPORT_REQUEST = "rt/api/sport/request"
SPORT_RESPONSE = "rt/api/sport/response"
ARM_SDK_TOPIC = "rt/arm_sdk"
ODOM_STATE_TOPIC = "rt/odommodestate"
ODOM_STATE_LF_TOPIC = "rt/lf/odommodestate"


class HighLevelDds:
    """Readers and writers of the sport service, arm_sdk and SportModeState_ on `dds`'s participant."""

    def __init__(self, dds: UnitreeDds) -> None:
        participant = dds.participant
        self.request_reader = DataReader(participant, Topic(participant, SPORT_REQUEST, Request_))
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

    def take_request(self) -> Request_ | None:
        """The next sport request (decoded by the binding).

        Raises:
            Exception: whatever the binding raises on a sample it cannot decode.
        """
        samples = self.request_reader.take(N=1)
        return samples[0] if samples and isinstance(samples[0], Request_) else None

    def respond(self, response: Response_) -> None:
        self.response_writer.write(response)

    def take_arm_sdk(self, max_samples: int = 64) -> list[bytes]:
        """Serialized LowCmd_ samples from rt/arm_sdk (header included), oldest first."""
        result = ddspy_take(self.arm_sdk_reader._ref, max_samples)
        if isinstance(result, int):
            return []
        return [data for data, info in result if info.valid_data]

    def write_odom(self, state: SportModeState_, low_frequency: bool) -> None:
        self.odom_writer.write(state)
        if low_frequency:
            self.odom_lf_writer.write(state)
