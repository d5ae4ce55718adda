"""A stand-in for a unitree_sdk2_python program: what an SDK controller does on DDS, and nothing of zensim.

Written with the `cyclonedds` binding and zensim's IDL type definitions (the layouts Unitree's SDK
puts on the wire), the way the SDK does it: a domain configured for one interface, default QoS,
LowCmd_ on rt/lowcmd with the CRC computed by packing the C struct (the SDK's pack format, a fact
of the layout) and running the CRC bit by bit, LowState_ read from rt/lowstate, and the
motion-switcher client's Request_/Response_ exchange. It deliberately does not use zensim's
numpy codec, so a test that passes shows two independent encoders agree.
"""

from __future__ import annotations

import json
import random
import struct
import threading
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from zensim.unitree.dds import domain_config
from zensim.unitree.idl import (
    LowCmd_,
    LowState_,
    MotorCmd_,
    Request_,
    RequestHeader_,
    RequestIdentity_,
    RequestPolicy_,
    Response_,
)

G1_NUM_MOTOR = 29
# The gains of unitree_sdk2_python's example/g1/low_level/g1_low_level_example.py.
KP = [60, 60, 60, 100, 40, 40] * 2 + [60, 40, 40] + [40] * 14
KD = [1, 1, 1, 2, 1, 1] * 2 + [1, 1, 1] + [1] * 14
LEFT_ANKLE_PITCH, LEFT_ANKLE_ROLL, RIGHT_ANKLE_PITCH, RIGHT_ANKLE_ROLL = 4, 5, 10, 11

LOW_CMD_PACK = struct.Struct("<2B2x" + "B3x5fI" * 35 + "5I")
LOW_STATE_PACK = struct.Struct("<2I2B2xI" + "13fh2x" + "B3x4f2hf7I" * 35 + "40B5I")


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7 if crc & 0x80000000 else crc << 1) & 0xFFFFFFFF
        table.append(crc)
    return table


CRC_TABLE = _crc_table()


def sdk_crc(packed: bytes) -> int:
    """Unitree's CRC (CRC-32/MPEG-2 over the 32-bit words, each fed most significant byte first), by table."""
    crc = 0xFFFFFFFF
    for i in range(0, len(packed) - 4, 4):
        for byte in (packed[i + 3], packed[i + 2], packed[i + 1], packed[i]):
            crc = ((crc << 8) & 0xFFFFFFFF) ^ CRC_TABLE[(crc >> 24) ^ byte]
    return crc


_DOMAINS_TAKEN: set[int] = set()


def unused_domain_id() -> int:
    """A DDS domain for one test, so parallel runs on this host never see each other's samples: random, and
    never one this process took before (Cyclone refuses a second Domain with an id the process still holds,
    PRECONDITION_NOT_MET, and the test process keeps its DDS clients until the session's end)."""
    free = [domain_id for domain_id in range(100, 231) if domain_id not in _DOMAINS_TAKEN]
    domain_id = random.choice(free)
    _DOMAINS_TAKEN.add(domain_id)
    return domain_id


def low_cmd_crc(cmd: LowCmd_) -> int:
    values: list = [cmd.mode_pr, cmd.mode_machine]
    for m in cmd.motor_cmd:
        values += [m.mode, m.q, m.dq, m.tau, m.kp, m.kd, m.reserve]
    values += [*cmd.reserve, 0]
    return sdk_crc(LOW_CMD_PACK.pack(*values))


def low_state_crc(state: LowState_) -> int:
    imu = state.imu_state
    values: list = [*state.version, state.mode_pr, state.mode_machine, state.tick, *imu.quaternion,
                    *imu.gyroscope, *imu.accelerometer, *imu.rpy, imu.temperature]
    for m in state.motor_state:
        values += [m.mode, m.q, m.dq, m.ddq, m.tau_est, *m.temperature, m.vol, *m.sensor, m.motorstate, *m.reserve]
    values += [*state.wireless_remote, *state.reserve, 0]
    return sdk_crc(LOW_STATE_PACK.pack(*values))


def new_low_cmd() -> LowCmd_:
    return LowCmd_(motor_cmd=[MotorCmd_() for _ in range(35)])


OPEN_CLIENTS: list[SdkClient] = []
"""Clients not closed yet (conftest.py closes them after each test module, and at the session's end)."""


class SdkClient:
    """One DDS participant with the SDK's low-level channels and a motion-switcher client.

    Close it (conftest.py does, after every test module): Cyclone keeps every entity in a class-level table, so
    an unclosed participant and its sockets live as long as the pytest process, and at its exit Cyclone's
    receive thread spun on the closed sockets (30 000 `recvUC ... retcode -52` lines in a CI log).
    """

    def __init__(self, domain_id: int, interface: str = "lo") -> None:
        self.domain = Domain(domain_id, domain_config(interface))
        self.participant = DomainParticipant(domain_id)
        self.lowcmd = DataWriter(self.participant, Topic(self.participant, "rt/lowcmd", LowCmd_))
        # Keep only the newest state: a controller reads the latest, and decoding every 500 Hz
        # sample in Python would cost this test process a core.
        self.lowstate = DataReader(self.participant, Topic(self.participant, "rt/lowstate", LowState_),
                                   qos=Qos(Policy.History.KeepLast(1)))
        self.requests = DataWriter(self.participant, Topic(self.participant, "rt/api/motion_switcher/request", Request_))
        self.responses = DataReader(self.participant, Topic(self.participant, "rt/api/motion_switcher/response", Response_))
        self._lock = threading.Lock()
        OPEN_CLIENTS.append(self)  # only a client made whole: close() needs every part

    def close(self) -> None:
        """Delete the participant (with its readers and writers) and the domain: their sockets close now."""
        if self in OPEN_CLIENTS:
            OPEN_CLIENTS.remove(self)
            self.participant.__del__()
            self.domain.__del__()

    def latest_state(self) -> LowState_ | None:
        samples = [s for s in self.lowstate.take(N=8) if isinstance(s, LowState_)]
        return samples[-1] if samples else None

    def wait_state(self, timeout_s: float = 20.0, after_tick: int = -1) -> LowState_:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            state = self.latest_state()
            if state is not None and state.tick > after_tick:
                return state
            time.sleep(0.002)
        raise AssertionError(f"no LowState_ on rt/lowstate within {timeout_s} s")

    def write(self, cmd: LowCmd_, crc: int | None = None) -> None:
        cmd.crc = low_cmd_crc(cmd) if crc is None else crc
        self.lowcmd.write(cmd)

    def call(self, api_id: int, parameter: dict | None = None, timeout_s: float = 10.0) -> tuple[int, str]:
        """A motion-switcher call as MotionSwitcherClient makes it; (status code, data)."""
        request_id = time.monotonic_ns()
        request = Request_(header=RequestHeader_(identity=RequestIdentity_(id=request_id, api_id=api_id),
                                                 policy=RequestPolicy_(priority=0, noreply=False)),
                           parameter=json.dumps(parameter or {}), binary=[])
        deadline = time.monotonic() + timeout_s
        next_send = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_send:  # discovery may still be under way: resend
                self.requests.write(request)
                next_send = time.monotonic() + 0.5
            for response in self.responses.take(N=8):
                if isinstance(response, Response_) and response.header.identity.id == request_id:
                    assert response.header.identity.api_id == api_id
                    return response.header.status.code, response.data
            time.sleep(0.01)
        raise AssertionError(f"no motion-switcher response to api {api_id} within {timeout_s} s")

    def check_and_release_mode(self) -> list[tuple[int, str]]:
        """What the SDK's low-level examples do first: CheckMode, ReleaseMode while a mode is active."""
        calls = [self.call(1001)]
        code, data = calls[-1]
        assert code == 0, calls
        for _ in range(5):  # the SDK's examples loop until released; a test must not loop for ever
            if not json.loads(data)["name"]:
                break
            calls.append(self.call(1003))
            calls.append(self.call(1001))
            code, data = calls[-1]
        else:
            raise AssertionError(f"a mode is still active after 5 ReleaseMode calls: {calls}")
        calls.append(self.call(1003))  # release once more: it must succeed with nothing active
        return calls
