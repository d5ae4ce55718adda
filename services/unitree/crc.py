"""Unitree's CRC-32 of LowCmd_/LowState_ (our own implementation of their documented algorithm).

The SDK packs the message as its C struct (little-endian, natural alignment, zeroed padding),
takes it as 32-bit words without the last one (the crc field itself) and runs CRC-32/MPEG-2 over
them: polynomial 0x04C11DB7, initial value 0xFFFFFFFF, no reflection, no final xor, each word fed
most significant bit first. A bit-by-bit loop in Python costs milliseconds per message, too slow
for 500 Hz, so this uses zlib's table-driven CRC-32, which is the same polynomial run reflected:
feeding it the bit-reversed input and bit-reversing its raw register gives the unreflected CRC.
"""

from __future__ import annotations

import sys
import zlib
from array import array
from typing import Final

_REVERSE_BITS: Final = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def _reverse32(value: int) -> int:
    return int(f"{value:032b}"[::-1], 2)


def crc32_mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 of a byte string (check value of b"123456789": 0x0376E6E7)."""
    raw = zlib.crc32(data.translate(_REVERSE_BITS)) ^ 0xFFFFFFFF  # zlib xors its output: undo it
    return _reverse32(raw)


def unitree_crc(packed: bytes) -> int:
    """Unitree's CRC of a message packed as its C struct, the trailing crc word included.

    Args:
        packed: the struct's bytes, a multiple of 4 long; the last word (the crc) is left out.

    Returns:
        The CRC to put in (or to compare with) the message's `crc` field.
    """
    if len(packed) % 4:
        raise ValueError(f"a packed message is whole 32-bit words, got {len(packed)} bytes")
    words = array("I", packed[:-4])
    if sys.byteorder == "little":
        words.byteswap()  # each little-endian word is fed most significant byte first
    return crc32_mpeg2(words.tobytes())


def unitree_crc_reference(packed: bytes) -> int:
    """The same CRC computed bit by bit, word by word, as the algorithm is written (slow; for tests)."""
    crc = 0xFFFFFFFF
    for i in range(0, len(packed) - 4, 4):
        word = int.from_bytes(packed[i:i + 4], "little")
        for bit in range(31, -1, -1):
            top = crc & 0x80000000
            crc = (crc << 1) & 0xFFFFFFFF
            if top:
                crc ^= 0x04C11DB7
            if word >> bit & 1:
                crc ^= 0x04C11DB7
    return crc
