"""Size caps on input payloads, checked before a byte of them is decoded.

A service compares a sample's length with its key's cap first, so an
oversize payload costs a length check, not a parse (a 1.5 MB command with
100 000 unknown names took the physics down to RTF 0.1 when it was parsed).
Caps are sized from the largest valid message of the robot: every joint
named, every vector present, every number written out in full, times
`SLACK` for pretty-printed JSON, and never below `MIN_CAP_BYTES`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import msgspec

SLACK: Final = 4
"""Room over the largest compact message: indented JSON, long number spellings."""
MIN_CAP_BYTES: Final = 4096
"""No cap is smaller than this, so small robots keep room for hand-written JSON."""
SCALAR_CAP_BYTES: Final = 256
"""A bare number on cmd/joint/{joint}: `0.9`, a msgpack float, with whitespace to spare."""

STATE_CAP_BYTES: Final = 256 * 1024
"""A state sample read by a service that does not know the robot yet (the viz): generous, still bounded."""
INFO_CAP_BYTES: Final = 8 * 1024 * 1024
"""A RobotInfo reply: the protocol table and the mesh list included, with room for large robots."""
DESCRIPTION_CAP_BYTES: Final = 64 * 1024 * 1024
"""One info/urdf or info/mesh/{path} reply: the largest G1 mesh is 2.3 MB; a runaway reply is refused."""

_LONGEST_NUMBER: Final = -1.2345678901234567e-308
"""A float whose JSON spelling is as long as any (24 characters)."""


def vector_cap_bytes(joint_names: Sequence[str]) -> int:
    """Cap for messages that carry up to six joint vectors and the joint names (commands, resets, states).

    Args:
        joint_names: the robot's joints.

    Returns:
        The largest payload, in bytes, accepted on such a key.
    """
    n = len(joint_names)
    vectors = {field: [_LONGEST_NUMBER] * n for field in ("q", "dq", "kp", "kd", "tau", "x")}
    largest = msgspec.json.encode({"type": "motor_command", "names": list(joint_names), **vectors})
    return max(MIN_CAP_BYTES, SLACK * len(largest))
