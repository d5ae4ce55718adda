"""Unitree's DDS message types, as Cyclone DDS IDL structs (our own definitions of their layout).

The names and field layouts are what unitree_sdk2 and unitree_sdk2_python put on the wire for the
G1 (`unitree_hg`) and for their request/response services (`unitree_api`); both ends must agree
field by field, so nothing here may be reordered or retyped. All structs are `final` with
sequential member ids, as Unitree's IDL declares them.

Only this module and dds.py import cyclonedds: the mapping (lowlevel.py) and the CRC (crc.py)
are plain Python that tests can drive without DDS.
"""


from dataclasses import dataclass, field


from cyclonedds.idl import IdlStruct, annotations as annotate, types

from .codec import NUM_MOTORS  # the motor slots of LowCmd_/LowState_, one home for both wire forms


def _zeros(n: int):  # noqa: ANN202 (a dataclass field)
    return field(default_factory=lambda: [0] * n)


# --- unitree_hg: the G1's low-level interface -------------------------------------------


@dataclass
@annotate.final
@annotate.autoid("sequential")
class MotorCmd_(IdlStruct, typename="unitree_hg.msg.dds_.MotorCmd_"):
    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.uint32 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class LowCmd_(IdlStruct, typename="unitree_hg.msg.dds_.LowCmd_"):
    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    motor_cmd: types.array[MotorCmd_, NUM_MOTORS] = field(
        default_factory=lambda: [MotorCmd_() for _ in range(NUM_MOTORS)])
    reserve: types.array[types.uint32, 4] = _zeros(4)
    crc: types.uint32 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class IMUState_(IdlStruct, typename="unitree_hg.msg.dds_.IMUState_"):
    quaternion: types.array[types.float32, 4] = _zeros(4)
    gyroscope: types.array[types.float32, 3] = _zeros(3)
    accelerometer: types.array[types.float32, 3] = _zeros(3)
    rpy: types.array[types.float32, 3] = _zeros(3)
    temperature: types.int16 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class MotorState_(IdlStruct, typename="unitree_hg.msg.dds_.MotorState_"):
    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    temperature: types.array[types.int16, 2] = _zeros(2)
    vol: types.float32 = 0.0
    sensor: types.array[types.uint32, 2] = _zeros(2)
    motorstate: types.uint32 = 0
    reserve: types.array[types.uint32, 4] = _zeros(4)


@dataclass
@annotate.final
@annotate.autoid("sequential")
class LowState_(IdlStruct, typename="unitree_hg.msg.dds_.LowState_"):
    version: types.array[types.uint32, 2] = _zeros(2)
    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    tick: types.uint32 = 0
    imu_state: IMUState_ = field(default_factory=IMUState_)
    motor_state: types.array[MotorState_, NUM_MOTORS] = field(
        default_factory=lambda: [MotorState_() for _ in range(NUM_MOTORS)])
    wireless_remote: types.array[types.uint8, 40] = _zeros(40)
    reserve: types.array[types.uint32, 4] = _zeros(4)
    crc: types.uint32 = 0


# --- unitree_api: request/response services (the motion switcher) ------------------------


@dataclass
@annotate.final
@annotate.autoid("sequential")
class RequestIdentity_(IdlStruct, typename="unitree_api.msg.dds_.RequestIdentity_"):
    id: types.int64 = 0
    api_id: types.int64 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class RequestLease_(IdlStruct, typename="unitree_api.msg.dds_.RequestLease_"):
    id: types.int64 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class RequestPolicy_(IdlStruct, typename="unitree_api.msg.dds_.RequestPolicy_"):
    priority: types.int32 = 0
    noreply: bool = False


@dataclass
@annotate.final
@annotate.autoid("sequential")
class RequestHeader_(IdlStruct, typename="unitree_api.msg.dds_.RequestHeader_"):
    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    lease: RequestLease_ = field(default_factory=RequestLease_)
    policy: RequestPolicy_ = field(default_factory=RequestPolicy_)


@dataclass
@annotate.final
@annotate.autoid("sequential")
class Request_(IdlStruct, typename="unitree_api.msg.dds_.Request_"):
    header: RequestHeader_ = field(default_factory=RequestHeader_)
    parameter: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)


@dataclass
@annotate.final
@annotate.autoid("sequential")
class ResponseStatus_(IdlStruct, typename="unitree_api.msg.dds_.ResponseStatus_"):
    code: types.int32 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class ResponseHeader_(IdlStruct, typename="unitree_api.msg.dds_.ResponseHeader_"):
    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    status: ResponseStatus_ = field(default_factory=ResponseStatus_)


@dataclass
@annotate.final
@annotate.autoid("sequential")
class Response_(IdlStruct, typename="unitree_api.msg.dds_.Response_"):
    header: ResponseHeader_ = field(default_factory=ResponseHeader_)
    data: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)


# --- unitree_go: the high-level state the G1 publishes on rt/odommodestate ---------------


@dataclass
@annotate.final
@annotate.autoid("sequential")
class TimeSpec_(IdlStruct, typename="unitree_go.msg.dds_.TimeSpec_"):
    sec: types.int32 = 0
    nanosec: types.uint32 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class GoIMUState_(IdlStruct, typename="unitree_go.msg.dds_.IMUState_"):
    quaternion: types.array[types.float32, 4] = _zeros(4)
    gyroscope: types.array[types.float32, 3] = _zeros(3)
    accelerometer: types.array[types.float32, 3] = _zeros(3)
    rpy: types.array[types.float32, 3] = _zeros(3)
    temperature: types.uint8 = 0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class PathPoint_(IdlStruct, typename="unitree_go.msg.dds_.PathPoint_"):
    t_from_start: types.float32 = 0.0
    x: types.float32 = 0.0
    y: types.float32 = 0.0
    yaw: types.float32 = 0.0
    vx: types.float32 = 0.0
    vy: types.float32 = 0.0
    vyaw: types.float32 = 0.0


@dataclass
@annotate.final
@annotate.autoid("sequential")
class SportModeState_(IdlStruct, typename="unitree_go.msg.dds_.SportModeState_"):
    stamp: TimeSpec_ = field(default_factory=TimeSpec_)
    error_code: types.uint32 = 0
    imu_state: GoIMUState_ = field(default_factory=GoIMUState_)
    mode: types.uint8 = 0
    progress: types.float32 = 0.0
    gait_type: types.uint8 = 0
    foot_raise_height: types.float32 = 0.0
    position: types.array[types.float32, 3] = _zeros(3)
    body_height: types.float32 = 0.0
    velocity: types.array[types.float32, 3] = _zeros(3)
    yaw_speed: types.float32 = 0.0
    range_obstacle: types.array[types.float32, 4] = _zeros(4)
    foot_force: types.array[types.int16, 4] = _zeros(4)
    foot_position_body: types.array[types.float32, 12] = _zeros(12)
    foot_speed_body: types.array[types.float32, 12] = _zeros(12)
    path_point: types.array[PathPoint_, 10] = field(default_factory=lambda: [PathPoint_() for _ in range(10)])
