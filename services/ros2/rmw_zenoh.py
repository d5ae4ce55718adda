"""rmw_zenoh's wire format, as pure rules: the key expressions, liveliness tokens, QoS strings and
attachments a ROS 2 node on rmw_zenoh (Jazzy, Kilted, Rolling) uses, so that `zensim ros2` is one.

From ros2/rmw_zenoh docs/design.md (the format since rmw_zenoh jazzy 0.2.4 / kilted 0.6):

    data key   <domain>/<topic, outer slashes stripped>/<pkg::msg::dds_::Type_>/<RIHS01_hash>
    node       @ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>
    endpoint   @ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP|MS/<enclave>/<namespace>/<node>/
               <topic>/<type>/<hash>/<qos>

A name in a token has its `/` written `%`; an empty one (the root namespace, no enclave) is `%`.
The QoS chunk lists `reliability:durability:history,depth:deadline:lifespan:liveliness` with every
field equal to rmw_zenoh's default (reliable, volatile, keep last, depth 42, no deadline, no lifespan,
automatic liveliness) left empty. Humble's rmw_zenoh has no type hashes: `TypeHashNotSupported`
stands in their place, so Humble and Jazzy+ never meet on one key.

The attachment each sample carries (rmw_zenoh drops samples without one) is zenoh-ext's serialisation
of (int64 sequence number, int64 source timestamp in ns, 16-byte GID): 8 + 8 + a 1-byte length + 16.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final, Literal

from .messages import RosType

LIVELINESS_ROOT: Final = "@ros2_lv"
HUMBLE_TYPE_HASH: Final = "TypeHashNotSupported"
DEFAULT_DEPTH: Final = 42
"""rmw_zenoh's default history depth: a token leaves a depth equal to it empty."""
GID_SIZE: Final = 16
ATTACHMENT_SIZE: Final = 8 + 8 + 1 + GID_SIZE
_ATTACHMENT = struct.Struct("<qqB")

EndpointKind = Literal["MP", "MS"]
"""A publisher (MP) or a subscription (MS)."""


@dataclass(frozen=True)
class Qos:
    """The QoS a publisher or subscription announces (the parts `zensim ros2` sets)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def token(self) -> str:
        """The QoS chunk of an endpoint token: `::,10:,:,:,,` for reliable, volatile, depth 10."""
        reliability = "" if self.reliable else "2"
        durability = "1" if self.transient_local else ""
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        return f"{reliability}:{durability}:,{depth}:,:,:,,"


def mangle(name: str) -> str:
    """A ROS name as one key chunk: `/` -> `%`; empty (or the root namespace `/`) -> `%`."""
    return name.replace("/", "%") if name else "%"


def type_hash(ros_type: RosType, humble: bool = False) -> str:
    return HUMBLE_TYPE_HASH if humble else ros_type.type_hash


def data_key(domain: int, topic: str, ros_type: RosType, humble: bool = False) -> str:
    """The key a topic's samples travel on (`0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_...`)."""
    return f"{domain}/{topic.strip('/')}/{ros_type.dds_name}/{type_hash(ros_type, humble)}"


@dataclass(frozen=True)
class Node:
    """Who the tokens say publishes: a node of this session."""

    domain: int
    zid: str
    """The zenoh session's id, as zenoh prints it (hex)."""
    node_id: int
    namespace: str
    """`/` for the root namespace, else `/a/b`."""
    name: str
    enclave: str = ""

    def _prefix(self, entity_id: int, kind: str) -> str:
        namespace = "" if self.namespace == "/" else self.namespace
        return (f"{LIVELINESS_ROOT}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(namespace)}/{self.name}")

    def token(self) -> str:
        """The node's own liveliness token."""
        return self._prefix(self.node_id, "NN")

    def endpoint_token(self, entity_id: int, kind: EndpointKind, topic: str, ros_type: RosType, qos: Qos,
                       humble: bool = False) -> str:
        """A publisher's or subscription's liveliness token."""
        return (f"{self._prefix(entity_id, kind)}/{mangle(topic)}/{ros_type.dds_name}/"
                f"{type_hash(ros_type, humble)}/{qos.token()}")


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment of one sample."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return _ATTACHMENT.pack(sequence_number, source_timestamp_ns, GID_SIZE) + gid


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def read_attachment(data: bytes | None) -> Attachment:
    """A sample's attachment; ValueError when it is missing or not rmw_zenoh's."""
    if data is None:
        raise ValueError("no attachment (rmw_zenoh sends one with every sample)")
    if len(data) != ATTACHMENT_SIZE:
        raise ValueError(f"an attachment of {len(data)} bytes (rmw_zenoh's has {ATTACHMENT_SIZE})")
    seq, ts, size = _ATTACHMENT.unpack_from(data)
    if size != GID_SIZE:
        raise ValueError(f"an attachment whose GID has {size} bytes")
    return Attachment(seq, ts, bytes(data[_ATTACHMENT.size:]))
