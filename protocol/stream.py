"""Streaming frame decoder: feed it bytes as they arrive, get back every intact frame.

The decoder never raises on bad input. It splits the stream at 0x00 delimiters, checks each
frame (COBS, length, CRC-32, version: protocol/framing.py), drops what fails and counts it in
LinkStats, and so resynchronises at the next delimiter by construction. After opening a port
the first bytes may be the tail of a frame sent before we listened, so until the first
delimiter everything is discarded (``synced=False``). Its memory is bounded: a frame that grows
beyond the largest valid encoded frame is dropped as it arrives (counted in
``oversize_frames``) and the rest of it is skipped up to the next delimiter.
Empty frames (runs of 0x00) are idle fill and count as nothing.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

from cobs import cobs

from protocol.framing import MAX_PAYLOAD_HOST, OVERHEAD, Frame, FrameError, decode_frame


@dataclass
class LinkStats:
    """Counters of one receiving end. All are totals since the decoder was created."""

    frames_ok: int = 0
    crc_errors: int = 0
    decode_errors: int = 0  # bad COBS, short, length mismatch, wrong version, malformed payload
    oversize_frames: int = 0
    seq_gaps: int = 0  # times the frame sequence number jumped
    frames_missing: int = 0  # frames those jumps skipped
    bytes_discarded: int = 0  # bytes that were not part of an accepted frame (idle 0x00 excluded)
    version_seen: int | None = None  # the last foreign protocol version seen, if any

    def as_dict(self) -> dict:
        return asdict(self)


class Received(NamedTuple):
    frame: Frame
    wire_len: int  # encoded length including the delimiter
    tail: int  # bytes of the fed chunk that came after this frame's delimiter


def max_encoded_len(max_payload: int) -> int:
    """Longest COBS-encoded body (without delimiter) a valid frame can have."""
    body = max_payload + OVERHEAD
    return body + body // 254 + 1


class StreamDecoder:
    """Bytes in, intact frames out; see the module docstring. One instance per byte stream."""

    def __init__(self, max_payload: int = MAX_PAYLOAD_HOST, *, synced: bool = False, stats: LinkStats | None = None):
        self.max_payload = max_payload
        self.max_encoded = max_encoded_len(max_payload)
        self.stats = LinkStats() if stats is None else stats
        self._buf = bytearray()
        self._synced = synced
        self._skipping = False  # inside an oversize frame: drop until the next delimiter
        self._last_seq: int | None = None

    def feed(self, data: bytes) -> list[Received]:
        stats = self.stats
        out: list[Received] = []
        pos = 0
        n = len(data)
        while pos < n:
            end = data.find(0, pos)
            if end < 0:  # no delimiter in the rest: keep it, bounded
                self._hold(data, pos, n)
                break
            if not self._synced:
                stats.bytes_discarded += len(self._buf) + end - pos
                self._buf.clear()
                self._synced = True
            elif self._skipping:
                stats.bytes_discarded += end - pos + 1
                self._skipping = False
            else:
                if self._buf:
                    self._buf += data[pos:end]
                    encoded = bytes(self._buf)
                    self._buf.clear()
                else:
                    encoded = data[pos:end]
                if encoded:
                    if len(encoded) > self.max_encoded:
                        stats.oversize_frames += 1
                        stats.bytes_discarded += len(encoded) + 1
                    else:
                        frame = self._check(encoded)
                        if frame is not None:
                            out.append(Received(frame, len(encoded) + 1, n - end - 1))
            pos = end + 1
        return out

    def _hold(self, data: bytes, pos: int, n: int) -> None:
        if not self._synced or self._skipping:
            self.stats.bytes_discarded += n - pos
            return
        self._buf += data[pos:n]
        if len(self._buf) > self.max_encoded:
            self.stats.oversize_frames += 1
            self.stats.bytes_discarded += len(self._buf)
            self._buf.clear()
            self._skipping = True

    def _check(self, encoded: bytes) -> Frame | None:
        stats = self.stats
        try:
            frame = decode_frame(encoded, max_payload=self.max_payload)
        except FrameError as exc:
            stats.bytes_discarded += len(encoded) + 1
            if exc.reason == "crc":
                stats.crc_errors += 1
            elif exc.reason == "oversize":
                stats.oversize_frames += 1
            else:
                stats.decode_errors += 1
                if exc.reason == "version":
                    stats.version_seen = encoded_version(encoded)
            return None
        stats.frames_ok += 1
        if self._last_seq is not None:
            gap = (frame.seq - self._last_seq - 1) & 0xFFFF
            if gap:
                stats.seq_gaps += 1
                stats.frames_missing += gap
        self._last_seq = frame.seq
        return frame


def encoded_version(encoded: bytes) -> int | None:
    """The version byte of a COBS-encoded frame (its first data byte), or None if unreadable."""
    try:
        return cobs.decode(encoded)[0]
    except (cobs.DecodeError, IndexError):
        return None
