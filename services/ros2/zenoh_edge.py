"""ROS 2 on Zenoh: `zensim ros2` as an rmw_zenoh node on zensim's own session (and so its router).

One node token per robot served (one robot: one node), one endpoint token per publisher (MP) and subscription (MS), so
`ros2 node list`, `ros2 topic list/info` on rmw_zenoh see them; data on rmw_zenoh's keys, each sample
with its attachment. A latched topic (transient local) goes out through zenoh-ext's advanced
publisher, whose cache answers the history query of a subscription that joins late; a plain put
would reach nobody who subscribes afterwards. The rules (keys, tokens, attachments) are in rmw_zenoh.py.

Samples from ROS 2 are refused before decoding when they carry no rmw_zenoh attachment or exceed the
payload cap; what is left is handed to the gateway as bytes, on zenoh's callback thread.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import zenoh
import zenoh.ext

from .messages import RosType
from .rmw_zenoh import Node, Qos, attachment, data_key, read_attachment
from .transport import OnBad, OnMessage


class ZenohPublisher:
    """One rmw_zenoh publisher: its own GID and sequence numbers."""

    def __init__(self, publisher: Any) -> None:
        self._publisher = publisher
        self._gid = os.urandom(16)
        self._seq = itertools.count(1)
        self._lock = threading.Lock()  # zenoh threads of several states may publish on one topic
        self._closed = False

    def put(self, payload: bytes) -> None:
        # The put under the lock too: a publisher undeclared by the closing main thread while a state's
        # thread puts on it raised "Already borrowed" (zensim ros2 exited 1 at a SIGTERM, once in CI).
        with self._lock:
            if self._closed:
                return
            seq = next(self._seq)
            self._publisher.put(payload, attachment=attachment(seq, time.time_ns(), self._gid))

    def undeclare(self) -> None:
        with self._lock:
            self._closed = True
            self._publisher.undeclare()


class ZenohEdge:
    """The node on one zenoh session.

    Args:
        session: zensim's session (its router is where ROS 2 nodes on rmw_zenoh connect).
        domain: the ROS domain id.
        namespace: the node's namespace (`/` for the root).
        node_name: the node's name.
        cap_bytes: the largest payload a subscription accepts.
        humble: name types as Humble's rmw_zenoh does.
        ids: where the node's id and its endpoints' ids come from; several nodes on one session (the
            robots of a world) share one counter, as rmw_zenoh's nodes share their context's.
    """

    name = "zenoh"

    def __init__(self, session: zenoh.Session, domain: int, namespace: str, node_name: str, cap_bytes: int,
                 humble: bool = False, ids: Iterator[int] | None = None) -> None:
        self._session = session
        self._domain = domain
        self._humble = humble
        self._cap_bytes = cap_bytes
        self._entity_ids = itertools.count(0) if ids is None else ids
        self.node = Node(domain, str(session.zid()), next(self._entity_ids), namespace, node_name)
        self._tokens = [session.liveliness().declare_token(self.node.token())]
        self._publishers: list[ZenohPublisher] = []
        self._subscribers: list[zenoh.Subscriber] = []

    def publisher(self, topic: str, ros_type: RosType, qos: Qos) -> ZenohPublisher:
        key = data_key(self._domain, topic, ros_type, self._humble)
        if qos.transient_local:
            inner: Any = zenoh.ext.declare_advanced_publisher(
                self._session, key, cache=zenoh.ext.CacheConfig(max_samples=qos.depth), publisher_detection=True)
        else:
            inner = self._session.declare_publisher(key)
        publisher = ZenohPublisher(inner)
        self._publishers.append(publisher)
        self._token(self.node.endpoint_token(next(self._entity_ids), "MP", topic, ros_type, qos, self._humble))
        return publisher

    def subscribe(self, topic: str, ros_type: RosType, on_message: OnMessage, on_bad: OnBad) -> None:
        key = data_key(self._domain, topic, ros_type, self._humble)
        cap = self._cap_bytes

        def handle(sample: zenoh.Sample) -> None:
            size = len(sample.payload)
            if size > cap:
                on_bad(f"{size} bytes on {topic} (at most {cap})")
                return
            try:
                read_attachment(None if sample.attachment is None else sample.attachment.to_bytes())
            except ValueError as exc:
                on_bad(f"{topic}: {exc}")
                return
            on_message(sample.payload.to_bytes())

        self._subscribers.append(self._session.declare_subscriber(key, handle))
        self._token(self.node.endpoint_token(next(self._entity_ids), "MS", topic, ros_type, Qos(), self._humble))

    def _token(self, key: str) -> None:
        self._tokens.append(self._session.liveliness().declare_token(key))

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        for publisher in self._publishers:
            publisher.undeclare()
        for token in self._tokens:
            token.undeclare()
