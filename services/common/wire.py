"""Glue between zenoh samples and the codecs in zensim.schemas."""

from __future__ import annotations

from typing import Generic, TypeVar

import zenoh

from zensim.schemas import Codec, Message, encoding_of
from zensim.schemas.codec import Format

M = TypeVar("M", bound=Message)


def payload_of(sample: zenoh.Sample | zenoh.Query) -> tuple[bytes, str | None]:
    """The raw bytes and encoding label of a sample or query (empty bytes when a query has none)."""
    payload = sample.payload
    data = payload.to_bytes() if payload is not None else b""
    encoding = sample.encoding
    return data, (str(encoding) if encoding is not None else None)


class TypedPublisher(Generic[M]):
    """A zenoh publisher declared once that writes one message type in one format."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type[M], fmt: Format = "msgpack") -> None:
        self.key = key
        self._codec = Codec(message_type)
        self._fmt = fmt
        self._publisher = session.declare_publisher(key, encoding=zenoh.Encoding(encoding_of(fmt)))

    def put(self, message: M) -> None:
        self._publisher.put(self._codec.encode(message, self._fmt))

    def undeclare(self) -> None:
        self._publisher.undeclare()


def reply(query: zenoh.Query, message: Message, fmt: Format = "msgpack") -> None:
    """Answer a query with a message, on the query's own key."""
    query.reply(query.key_expr, Codec(type(message)).encode(message, fmt), encoding=zenoh.Encoding(encoding_of(fmt)))
