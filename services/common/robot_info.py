"""Learning the robot from the sim: ask info/robot until a usable description comes back.

The bridge and the Unitree adapter both start this way (and the bridge again after a sim restart).
A reply is read like every other input (size cap, one decode path); what a service cannot use
(`usable` raises ValueError) is logged at a bounded rate and asked for again.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TypeVar

import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.wire import error_text, read_payload
from zensim.schemas import Codec, DecodeError, Keys, RobotInfo
from zensim.schemas.bounds import DESCRIPTION_CAP_BYTES, INFO_CAP_BYTES

T = TypeVar("T")

RETRY_PAUSE_S = 0.2
"""Pause between info/robot queries that found no sim."""


def fetch_robot(session: zenoh.Session, keys: Keys, timeout_s: float, stop: threading.Event,
                usable: Callable[[RobotInfo], T], logger: logging.Logger) -> T | None:
    """`usable(info)` for the first RobotInfo the sim answers that it accepts.

    Returns:
        What `usable` made of it, or None when `stop` was set first.
    """
    codec = Codec(RobotInfo)
    waiting = RateLimitedLog(logger, 10.0)
    while not stop.is_set():
        for reply in session.get(keys.robot_info, timeout=timeout_s):
            if reply.ok is None:
                waiting.warning("info/robot answered an error: %s", error_text(reply.err))
                continue
            try:
                return usable(codec.decode(*read_payload(reply.ok, INFO_CAP_BYTES)))
            except (DecodeError, ValueError) as exc:
                waiting.warning("unusable RobotInfo on %s: %s", keys.robot_info, exc)
        waiting.warning("no sim answers on %s yet; retrying", keys.robot_info)
        stop.wait(RETRY_PAUSE_S)
    return None


def description_bytes(session: zenoh.Session, key: str, timeout_s: float) -> bytes:
    """The first reply of a description queryable (info/urdf, info/mesh/...), size-capped.

    Raises:
        LookupError: no reply within `timeout_s`, an error reply, or one over the cap.
    """
    for reply in session.get(key, timeout=timeout_s):
        if reply.ok is None:
            raise LookupError(f"{key}: {error_text(reply.err)}")
        try:
            return read_payload(reply.ok, DESCRIPTION_CAP_BYTES)[0]
        except DecodeError as exc:
            raise LookupError(f"{key}: {exc}") from None
    raise LookupError(f"no reply on {key} within {timeout_s} s")
