"""Streaming frame decoder: feed it bytes as they arrive, get back every intact frame.

The decoder never raises on bad input. It splits the stream at 0x00 delimiters, checks each
frame (COBS, length, CRC-32, version: protocol/framing.py), drops what fails and counts it in
LinkStats, and so resynchronises at the next delimiter by construction. After opening a port
the first bytes may be the tail of a frame sent before we listened, so until the first
delimiter everything is discarded (``synced=False``). Its memory is bounded: a frame that grows
beyond the largest valid encoded frame is dropped as it arrives (counted in
``oversize_frames``) and the rest of it is skipped up to the next delimiter.
Empty frames (0x00 after a delimiter) are idle fill: counted in ``zero_bytes``; a run of more
than ZERO_RUN_MIN of them in a row (no sender idles that long: a flood of zeros, a line break
condition, or a baud-rate mismatch, whose framing errors a UART driver reads as 0x00) is counted
once in ``zero_runs``. A frame sequence number that goes backwards is the sender's counter
starting again (``seq_restarts``), not 65 000 frames lost.
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
    seq_gaps: int = 0  # times the frame sequence number jumped forward
    frames_missing: int = 0  # frames those jumps skipped
    seq_restarts: int = 0  # times the frame sequence number went backwards (the sender started again)
    bytes_received: int = 0  # every byte fed in
    bytes_discarded: int = 0  # bytes that were not part of an accepted frame (idle 0x00 excluded)
    zero_bytes: int = 0  # idle 0x00 bytes (empty frames)
    zero_runs: int = 0  # runs of more than ZERO_RUN_MIN idle 0x00 in a row: noise, a break, a baud mismatch
    version_seen: int | None = None  # the last foreign protocol version seen, if any

    def as_dict(self) -> dict:
        return asdict(self)


#: A sender idles with at most one 0x00 between frames (SPEC.md "Idle fill"): with the previous
#: frame's delimiter that is 2 zeros in a row. Longer runs are line noise.
ZERO_RUN_MIN = 2

#: A forward jump of the u16 frame sequence number of at least this many is taken as the
#: sender's counter going backwards (it restarted), not as lost frames.
SEQ_BACKWARDS = 0x8000


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
        self._zero_run = 0  # empty frames in a row so far

    def feed(self, data: bytes) -> list[Received]:
        stats = self.stats
        out: list[Received] = []
        pos = 0
        n = len(data)
        stats.bytes_received += n
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
                if not encoded:
                    self._idle_zero()
                else:
                    self._zero_run = 0
                    if len(encoded) > self.max_encoded:
                        stats.oversize_frames += 1
                        stats.bytes_discarded += len(encoded) + 1
                    else:
                        frame = self._check(encoded)
                        if frame is not None:
                            out.append(Received(frame, len(encoded) + 1, n - end - 1))
            pos = end + 1
        return out

    def _idle_zero(self) -> None:
        self.stats.zero_bytes += 1
        self._zero_run += 1
        if self._zero_run == ZERO_RUN_MIN:  # this zero makes ZERO_RUN_MIN + 1 in a row
            self.stats.zero_runs += 1

    def _hold(self, data: bytes, pos: int, n: int) -> None:
        self._zero_run = 0
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
            if gap >= SEQ_BACKWARDS:
                stats.seq_restarts += 1
            elif gap:
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
