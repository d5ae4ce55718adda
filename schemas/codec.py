"""Encoding and decoding of wire messages: msgpack by default, JSON for anyone.

Readers accept both. A sample is read as JSON when its encoding says
`application/json` (or `text/...`), or when it carries no useful encoding and
its payload is JSON text: `z_put` from the zenoh command line sets no
encoding, and a msgpack map can never start with `{` (0x7b is a msgpack
integer), so the sniff is unambiguous.

Every decode failure raises `DecodeError` (a ValueError) whose message names
the field, so services can log and report it as is. "Every" is meant
literally: besides msgspec's own errors, deep nesting surfaces as
RecursionError and invalid UTF-8 as UnicodeDecodeError, and a hostile client
sends exactly those. The message is cut to `MAX_ERROR_CHARS`, since it may
quote the input (a 10 MB joint name must not become a 10 MB status).
"""

from __future__ import annotations

import math
from typing import Final, Generic, Literal, TypeVar

import msgspec

from .messages import Message

MSGPACK: Final = "application/msgpack"
JSON: Final = "application/json"

Format = Literal["msgpack", "json"]
M = TypeVar("M", bound=Message)

MAX_ERROR_CHARS: Final = 240
"""Longest error text that goes into a log line, a status or a reply."""

_JSON_START: Final = frozenset(b"{[")

# What decoding untrusted bytes can raise besides msgspec's own errors.
_DECODE_FAILURES: Final = (msgspec.MsgspecError, RecursionError, UnicodeError, ValueError, TypeError, OverflowError)
_WHITESPACE: Final = b" \t\r\n"


class DecodeError(ValueError):
    """A payload that is not a valid message of the expected type."""


def bounded(text: str, limit: int = MAX_ERROR_CHARS) -> str:
    """`text` cut to `limit` characters, saying how long it was: for anything that may echo input."""
    if len(text) <= limit:
        return text
    return f"{text[: limit - 30]}... ({len(text)} chars, cut)"


def short_repr(value: object, limit: int = 40) -> str:
    """repr() of a value taken from input (a joint name), cut to `limit` characters."""
    return bounded(repr(value), limit)


def is_json(payload: bytes, encoding: str | None) -> bool:
    """Whether a payload is to be read as JSON (see the module docstring)."""
    if encoding:
        if encoding.startswith(JSON) or encoding.startswith("text/"):
            return True
        if encoding.startswith(MSGPACK):
            return False
    stripped = payload.lstrip(_WHITESPACE)
    return bool(stripped) and stripped[0] in _JSON_START


class Codec(Generic[M]):
    """One message type's encoders and decoders, built once and reused.

    Args:
        message_type: the Struct this codec reads and writes.
    """

    def __init__(self, message_type: type[M]) -> None:
        self.message_type = message_type
        self._msgpack_encoder = msgspec.msgpack.Encoder()
        self._json_encoder = msgspec.json.Encoder()
        self._msgpack_decoder = msgspec.msgpack.Decoder(message_type)
        self._json_decoder = msgspec.json.Decoder(message_type)

    def encode(self, message: M, fmt: Format = "msgpack") -> bytes:
        """Encode `message` as msgpack (default) or JSON."""
        if fmt == "json":
            return self._json_encoder.encode(message)
        return self._msgpack_encoder.encode(message)

    def decode(self, payload: bytes, encoding: str | None = None) -> M:
        """Decode a payload; an empty payload means a message with all defaults.

        Raises:
            DecodeError: the payload is malformed or a field is invalid.
        """
        if not payload.strip(_WHITESPACE):
            payload, encoding = b"{}", JSON
        as_json = is_json(payload, encoding)
        try:
            if as_json:
                return self._json_decoder.decode(payload)
            return self._msgpack_decoder.decode(payload)
        except _DECODE_FAILURES as exc:
            read_as = "JSON" if as_json else "msgpack"
            raise DecodeError(bounded(f"invalid {self.message_type.__name__} (read as {read_as}): {_reason(exc)}")) from None


def encoding_of(fmt: Format) -> str:
    """The zenoh encoding string a writer sets for `fmt`."""
    return JSON if fmt == "json" else MSGPACK


def decode_scalar(payload: bytes, encoding: str | None = None) -> float:
    """Decode a bare number: JSON or plain text (`0.9`), or a msgpack number.

    Raises:
        DecodeError: not a number, or not finite.
    """
    try:
        if (encoding is None or not encoding.startswith(MSGPACK)) and _is_printable(payload):
            value = msgspec.json.decode(payload.strip(_WHITESPACE), type=float)
        else:
            value = msgspec.msgpack.decode(payload, type=float)
    except _DECODE_FAILURES as exc:
        raise DecodeError(bounded(f"expected a bare number: {_reason(exc)}")) from None
    if not math.isfinite(value):
        raise DecodeError(f"expected a finite number, got {value}")
    return value


def _is_printable(payload: bytes) -> bool:
    """Text typed by a person; a msgpack number starts with a control or high byte."""
    return all(32 <= byte < 127 or byte in _WHITESPACE for byte in payload)


def _reason(exc: BaseException) -> str:
    """What went wrong, in words: msgspec's text, or the kind of failure for the others."""
    if isinstance(exc, RecursionError):
        return "nested too deeply"
    if isinstance(exc, UnicodeError):
        return "invalid UTF-8 in a string"
    return str(exc) or type(exc).__name__
