"""OMG CDR, the bytes every ROS 2 middleware carries a message in: a writer and a lenient, bounded reader.

The payload opens with a 4-byte encapsulation header (`00 01 00 00`: plain CDR, little-endian), then
each primitive sits at an offset, counted from the end of the header, that is a multiple of its size
(8-byte values on 8 in XCDR1; XCDR2, `00 07`, caps the alignment at 4). Strings are a uint32 length
counting the closing NUL, the bytes, the NUL; sequences a uint32 count then the items.

The reader is lenient where ROS 2's own encoder is loose and strict where a sender could hurt us:
- padding bytes are never checked (rclpy's `serialize_message` leaves them uninitialised) and bytes
  after the message are ignored (it appends 4);
- every length is checked against the bytes left before anything is allocated, so a count of 2**32
  in a 40-byte payload is refused at once, and a string must be UTF-8.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Final

HEADER_LE: Final = b"\x00\x01\x00\x00"
"""Plain CDR (XCDR1), little-endian: what rmw_zenoh, rmw_fastrtps and rmw_cyclonedds write."""
_KINDS: Final = {
    b"\x00\x00": (">", 8), b"\x00\x01": ("<", 8),  # XCDR1 big/little-endian
    b"\x00\x06": (">", 4), b"\x00\x07": ("<", 4),  # XCDR2 plain big/little-endian
}
"""Encapsulation id -> (struct byte order, largest alignment)."""


class CdrError(ValueError):
    """Bytes that are not the message they claim to be; the text says where."""


class CdrWriter:
    """Builds one little-endian XCDR1 payload, header included."""

    def __init__(self) -> None:
        self._buf = bytearray(HEADER_LE)

    def _align(self, size: int) -> None:
        pad = -(len(self._buf) - 4) % size
        self._buf += b"\x00" * pad

    def _put(self, fmt: str, size: int, value: float | int) -> None:
        self._align(size)
        self._buf += struct.pack("<" + fmt, value)

    def int32(self, value: int) -> None:
        self._put("i", 4, value)

    def uint32(self, value: int) -> None:
        self._put("I", 4, value)

    def float64(self, value: float) -> None:
        self._put("d", 8, value)

    def string(self, value: str) -> None:
        data = value.encode("utf-8")
        self.uint32(len(data) + 1)
        self._buf += data + b"\x00"

    def strings(self, values: Sequence[str]) -> None:
        self.uint32(len(values))
        for value in values:
            self.string(value)

    def float64s(self, values: Sequence[float]) -> None:
        """A sequence<double>: the count, then the values in one pack."""
        self.uint32(len(values))
        if values:
            self._align(8)
            self._buf += struct.pack(f"<{len(values)}d", *values)

    def bytes(self) -> bytes:
        return bytes(self._buf)


class CdrReader:
    """Reads one payload field by field; every failure is a CdrError.

    Args:
        data: the payload, encapsulation header included.
    """

    def __init__(self, data: bytes | bytearray | memoryview) -> None:
        data = bytes(data)
        if len(data) < 4:
            raise CdrError(f"{len(data)} bytes: shorter than the 4-byte CDR header")
        kind = _KINDS.get(data[:2])
        if kind is None:
            raise CdrError(f"unsupported CDR encapsulation {data[:2].hex()}")
        self._order, self._max_align = kind
        self._data = data
        self._pos = 4

    def _align(self, size: int) -> None:
        size = min(size, self._max_align)
        self._pos += -(self._pos - 4) % size

    def _take(self, fmt: str, size: int) -> tuple:
        self._align(size)
        end = self._pos + struct.calcsize(self._order + fmt)
        if end > len(self._data):
            raise CdrError(f"the message ends at byte {len(self._data)}, inside a field at {self._pos}")
        values = struct.unpack_from(self._order + fmt, self._data, self._pos)
        self._pos = end
        return values

    def int32(self) -> int:
        return int(self._take("i", 4)[0])

    def uint32(self) -> int:
        return int(self._take("I", 4)[0])

    def float64(self) -> float:
        return float(self._take("d", 8)[0])

    def _count(self, item_size: int) -> int:
        count = self.uint32()
        if count * item_size > len(self._data) - self._pos:
            raise CdrError(f"a sequence of {count} items does not fit the {len(self._data) - self._pos} bytes left")
        return count

    def string(self) -> str:
        length = self._count(1)
        if length == 0:  # a sender that leaves out the NUL of an empty string
            return ""
        raw = self._data[self._pos:self._pos + length]
        self._pos += length
        try:
            return raw.rstrip(b"\x00").decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CdrError(f"a string that is not UTF-8: {exc}") from None

    def strings(self) -> list[str]:
        return [self.string() for _ in range(self._count(4))]  # each string takes at least its length

    def float64s(self) -> list[float]:
        count = self._count(8)
        return list(self._take(f"{count}d", 8)) if count else []

    def skip_string(self) -> None:
        self.string()
