"""Frame layer shared by both links (Pi <-> host, Pi <-> co-MCU).

On the wire a frame is ``COBS(body) + b"\\x00"``; the body is

    offset size field
    0      1    version      protocol version (PROTOCOL_VERSION)
    1      1    msg_type     message type
    2      2    seq          sequence number, u16 little-endian, wraps
    4      1    flags        message-specific bit flags
    5      2    length       payload length in bytes, u16 little-endian
    7      n    payload
    7+n    4    crc          CRC-32 (IEEE 802.3, as zlib.crc32) of bytes 0..7+n-1, little-endian

COBS comes from the `cobs` package and the CRC from `zlib.crc32`; see protocol/SPEC.md.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from cobs import cobs

PROTOCOL_VERSION = 1
HEADER = struct.Struct("<BBHBH")
HEADER_SIZE = HEADER.size  # 7
CRC_SIZE = 4
OVERHEAD = HEADER_SIZE + CRC_SIZE
DELIMITER = b"\x00"
#: Largest payload either end of the host link accepts: a 1664-point scan with its ray times
#: (protocol minor 4, 5 bytes a point) fits with room. 8192 before minor 4: only a SCAN with ray
#: times is longer, and a device sends those only to a host of minor >= 4 (SPEC.md section 1).
MAX_PAYLOAD_HOST = 16384
#: Largest payload on the co-MCU link (the ATmega328P has 2 KiB of RAM).
MAX_PAYLOAD_MCU = 48


class FrameError(ValueError):
    """A frame body that cannot be accepted; ``reason`` is a short machine-readable word."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Frame:
    msg_type: int
    seq: int
    flags: int
    payload: bytes
    version: int = PROTOCOL_VERSION


def encode_frame(
    msg_type: int, seq: int, payload: bytes = b"", flags: int = 0, *, max_payload: int = MAX_PAYLOAD_HOST
) -> bytes:
    """Return the complete wire bytes of one frame, delimiter included."""
    if len(payload) > max_payload:
        raise FrameError("oversize", f"payload of {len(payload)} bytes exceeds the maximum of {max_payload}")
    if not (0 <= msg_type <= 0xFF and 0 <= flags <= 0xFF):
        raise FrameError("header", f"msg_type {msg_type} and flags {flags} must each fit one byte")
    body = HEADER.pack(PROTOCOL_VERSION, msg_type, seq & 0xFFFF, flags, len(payload)) + payload
    body += struct.pack("<I", zlib.crc32(body))
    return cobs.encode(body) + DELIMITER


def decode_frame(encoded: bytes, *, max_payload: int = MAX_PAYLOAD_HOST) -> Frame:
    """Decode one COBS-encoded frame (without its delimiter) and check it.

    Raises FrameError with reason ``cobs``, ``short``, ``oversize``, ``length``, ``crc`` or
    ``version``; nothing is returned for a frame that fails any check.
    """
    if len(encoded) > max_payload + OVERHEAD + (max_payload + OVERHEAD) // 254 + 2:
        raise FrameError("oversize", f"encoded frame of {len(encoded)} bytes is longer than any valid frame")
    try:
        body = cobs.decode(encoded)
    except cobs.DecodeError as exc:
        raise FrameError("cobs", str(exc)) from None
    if len(body) < OVERHEAD:
        raise FrameError("short", f"{len(body)} bytes is shorter than header and CRC ({OVERHEAD})")
    version, msg_type, seq, flags, length = HEADER.unpack_from(body)
    if length > max_payload:
        raise FrameError("oversize", f"declared payload {length} exceeds the maximum of {max_payload}")
    if len(body) != OVERHEAD + length:
        raise FrameError("length", f"declared payload {length} but frame carries {len(body) - OVERHEAD}")
    (crc,) = struct.unpack_from("<I", body, len(body) - CRC_SIZE)
    if zlib.crc32(body[:-CRC_SIZE]) != crc:
        raise FrameError("crc", "CRC-32 mismatch")
    if version != PROTOCOL_VERSION:
        raise FrameError("version", f"protocol version {version}, this end speaks {PROTOCOL_VERSION}")
    return Frame(msg_type, seq, flags, bytes(body[HEADER_SIZE:-CRC_SIZE]), version)
