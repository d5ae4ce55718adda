"""The wire contract: message structs, key expressions and codecs.

Depends on msgspec only (no zenoh, no mujoco, no numpy), so any Python client
can use it without the simulator's dependencies.
"""

from .codec import JSON, MAX_ERROR_CHARS, MSGPACK, Codec, DecodeError, bounded, decode_scalar, encoding_of, is_json, short_repr
from .keys import DEFAULT_ROBOT_ID, ROOT, Keys, check_robot_id
from .topics import TOPICS, Topic, protocol_table
from .messages import (
    SCHEMA_VERSION,
    WIRE_TYPES,
    AdvanceReply,
    AppliedCommand,
    BandRequest,
    BandState,
    FaultsRequest,
    FaultsState,
    JointFault,
    LinkFaults,
    SensorFaults,
    PushRequest,
    PushState,
    Randomize,
    Variant,
    BridgeReport,
    Contacts,
    CtlReply,
    Gains,
    Imu,
    JointState,
    JointTargets,
    KeyInfo,
    Message,
    MODES,
    Mode,
    ModeRequest,
    MotorCommand,
    Odometry,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotInfo,
    Ros1Status,
    Ros2Status,
    RobotStates,
    WorldAdvanceReply,
    WorldAdvanceRequest,
    WorldInfo,
    WorldRobot,
    SimStatus,
    StepRequest,
    UnitreeStatus,
    VelocityCommand,
    ArmCommand,
    LocoRequest,
    LocoStatus,
    RemoteState,
)

__all__ = [
    "JSON", "MAX_ERROR_CHARS", "MSGPACK", "Codec", "DecodeError", "bounded", "decode_scalar", "encoding_of",
    "is_json", "short_repr",
    "DEFAULT_ROBOT_ID", "ROOT", "Keys", "check_robot_id", "TOPICS", "Topic", "protocol_table",
    "SCHEMA_VERSION", "WIRE_TYPES", "BridgeReport", "Contacts", "CtlReply", "Gains", "Imu", "JointState",
    "JointTargets", "KeyInfo", "Message", "MODES", "Mode", "ModeRequest", "MotorCommand", "Odometry",
    "PauseRequest", "ResetRequest", "ResumeRequest", "RobotInfo", "SimStatus", "StepRequest",
    "UnitreeStatus",
    "AdvanceReply", "AppliedCommand", "Ros1Status", "Ros2Status", "RobotStates", "WorldAdvanceReply", "WorldAdvanceRequest",
    "WorldInfo", "WorldRobot", "VelocityCommand", "ArmCommand", "LocoRequest", "LocoStatus", "RemoteState",
    "BandRequest", "BandState", "PushRequest", "PushState", "Randomize", "Variant",
    "FaultsRequest", "FaultsState", "JointFault", "LinkFaults", "SensorFaults",
]
