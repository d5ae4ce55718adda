"""What `zensim ros2` asks of a ROS 2 transport: publish CDR bytes on a topic, hand over what arrives.

Two transports implement it (zenoh_edge.py: rmw_zenoh's keys; dds_edge.py: Cyclone DDS), so the
gateway (service.py) builds each message once and every transport carries the same bytes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from .messages import RosType
from .rmw_zenoh import Qos

OnMessage = Callable[[bytes], None]
"""Called with a message's CDR bytes (header included) as it arrives."""
OnBad = Callable[[str], None]
"""Called with the reason when a transport refuses a sample before decoding (no attachment, oversize)."""


class Publisher(Protocol):
    def put(self, payload: bytes) -> None: ...


class Transport(Protocol):
    name: str
    """`zenoh` or `dds`, as the status reports it."""

    def publisher(self, topic: str, ros_type: RosType, qos: Qos) -> Publisher: ...

    def subscribe(self, topic: str, ros_type: RosType, on_message: OnMessage, on_bad: OnBad) -> None: ...

    def close(self) -> None: ...
