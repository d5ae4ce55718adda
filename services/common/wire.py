"""Glue between zenoh samples and the codecs in zensim.schemas, and the one way every service reads input.

Every input a service takes from the network goes through `read_payload`
(size cap before a byte is copied) and a `Codec` (which turns every decode
failure into DecodeError), and every refusal through `Refusals` (counted,
text cut, logged at a bounded rate). One path, so no handler can forget a
step.
"""

from __future__ import annotations

import itertools
import logging
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from zensim.schemas import Codec, DecodeError, Keys, Message, Topic, bounded, encoding_of
from zensim.schemas.codec import Format

from .logs import RateLimitedLog

M = TypeVar("M", bound=Message)
N = TypeVar("N", bound=Message)

WILDCARD_CHARS = ("*", "$")
"""Characters that make a key expression match more than one key."""


def payload_of(sample: zenoh.Sample | zenoh.Query) -> tuple[bytes, str | None]:
    """The raw bytes and encoding label of a sample or query (empty bytes when a query has none)."""
    payload = sample.payload
    data = payload.to_bytes() if payload is not None else b""
    encoding = sample.encoding
    return data, (str(encoding) if encoding is not None else None)


def read_payload(sample: zenoh.Sample | zenoh.Query, max_bytes: int) -> tuple[bytes, str | None]:
    """`payload_of`, after checking the size: an oversize payload is refused before it is copied.

    Raises:
        DecodeError: the payload is larger than `max_bytes`.
    """
    payload = sample.payload
    size = len(payload) if payload is not None else 0
    if size > max_bytes:
        raise DecodeError(f"payload of {size} bytes is over this key's cap of {max_bytes} bytes")
    return payload_of(sample)


def decode_input(sample: zenoh.Sample | zenoh.Query, codec: Codec[M], max_bytes: int) -> M:
    """Size check, then decode: the one way a service turns an input sample into a message.

    Raises:
        DecodeError: oversize, malformed or invalid (the text names why, cut to a bounded length).
    """
    return codec.decode(*read_payload(sample, max_bytes))


def error_text(reply_error: zenoh.ReplyError | None) -> str:
    """The text of an error reply (`reply.err`), bounded and safe whatever bytes it holds."""
    if reply_error is None:
        return ""
    payload = reply_error.payload
    return bounded(payload.to_bytes()[:4096].decode("utf-8", errors="replace") if payload is not None else "")


def is_wildcard(key_expr: object) -> bool:
    """True when a key expression can match several keys (`**`, `*`, `$*`)."""
    text = str(key_expr)
    return any(char in text for char in WILDCARD_CHARS)


class Refusals:
    """Counts the inputs a service refused and logs them at a bounded rate, with bounded text.

    Thread-safe: zenoh callbacks on several threads report here.

    Args:
        logger: where the warnings go.
        what: how the log line names the inputs (`command`, `request`).
        period_s: at most one log line per period; the rest are counted in the next line.
        log: a limiter shared with other counters (a world's robots share one, so a flood to all of them
            is still one line per period); None: one of its own.
    """

    def __init__(self, logger: logging.Logger, what: str, period_s: float = 1.0,
                 log: RateLimitedLog | None = None) -> None:
        self.what = what
        self.count = 0
        self.last_error: str | None = None
        self._lock = threading.Lock()
        self._log = log or RateLimitedLog(logger, period_s)

    def refuse(self, key: object, reason: str, count: int = 1) -> str:
        """Count `count` refused inputs (one reason: the last's); returns the bounded reason (for a reply or a report)."""
        text = bounded(reason)
        with self._lock:
            self.count += count
            self.last_error = text
        self._log.warning("rejected %s on %s: %s", self.what, bounded(str(key), 120), text)
        return text


class TypedPublisher(Generic[M]):
    """A zenoh publisher declared once that writes one message type in one format.

    Every sample says its source (zenoh's source info: this publisher's id and a sequence number),
    so a reader can tell a newer sample of the same source from another source's (the sim sheds a
    command that a newer one from its source follows, docs/protocol.md).

    `TypedPublisher.of(session, keys, topics.JOINTS)` takes the key and the type from the registry.
    """

    @staticmethod
    def of(session: zenoh.Session, keys: Keys, topic: Topic[N], fmt: Format = "msgpack",
           priority: zenoh.Priority | None = None) -> TypedPublisher[N]:
        """The publisher of a topic of the registry (schemas/topics.py) for one robot."""
        return TypedPublisher(session, keys.of(topic), topic.message_type(), fmt, priority)

    def __init__(self, session: zenoh.Session, key: str, message_type: type[M], fmt: Format = "msgpack",
                 priority: zenoh.Priority | None = None) -> None:
        self.key = key
        self._codec = Codec(message_type)
        self._fmt = fmt
        encoding = zenoh.Encoding(encoding_of(fmt))
        self._publisher = (session.declare_publisher(key, encoding=encoding) if priority is None else
                           session.declare_publisher(key, encoding=encoding, priority=priority))
        self._source = self._publisher.id
        self._sn = itertools.count(1)  # next() is atomic under the GIL: puts from several threads stay unique

    def put(self, message: M) -> None:
        self._publisher.put(self._codec.encode(message, self._fmt),
                            source_info=zenoh.SourceInfo(self._source, next(self._sn)))

    def undeclare(self) -> None:
        self._publisher.undeclare()


class TypedSubscriber(Generic[M]):
    """A zenoh subscriber that reads one message type: every sample size-checked, then decoded.

    `on_message` gets each message that decoded; `on_refused` each sample that did not, with the reason
    (oversize, malformed, invalid), to count and log it at a bounded rate. Both run on zenoh's threads.
    """

    def __init__(self, session: zenoh.Session, key: str, message_type: type[M], cap_bytes: int,
                 on_message: Callable[[M], None], on_refused: Callable[[zenoh.Sample, str], None]) -> None:
        self.key = key
        self._codec = Codec(message_type)
        self._cap_bytes = cap_bytes
        self._on_message = on_message
        self._on_refused = on_refused
        self._subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            message = decode_input(sample, self._codec, self._cap_bytes)
        except DecodeError as exc:
            self._on_refused(sample, str(exc))
            return
        self._on_message(message)

    def undeclare(self) -> None:
        self._subscriber.undeclare()


def reply(query: zenoh.Query, key: str, message: Message, fmt: Format, codec: Codec | None = None) -> None:
    """Answer a query with a message on `key` (the queryable's own key, never the query's wildcard)."""
    codec = codec or Codec(type(message))
    query.reply(key, codec.encode(message, fmt), encoding=zenoh.Encoding(encoding_of(fmt)))
