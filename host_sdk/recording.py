"""Recordings of the raw wire bytes a sensor sent, with host arrival times (``.lpr`` files).

Format (all little-endian), version 1:

    header
      8  magic          b"LPREC\\r\\n\\x1a" (a text-mode copy or a truncated download shows)
      2  version        u16, 1
      4  baudrate       u32, of the port while recording (for time stamps)
      8  wall_start_ns  i64, time.time_ns() when recording began (UTC, for ROS bags)
      8  mono_start_ns  i64, time.monotonic_ns() at the same moment
      2  name_len       u16, then name_len bytes: the port name, UTF-8
    records, until end of file
      8  t_ns           i64, host time.monotonic_ns() when the chunk was read
      4  length         u32
      n  bytes          the chunk exactly as read from the port (device -> host only)

The bytes are not decoded or cleaned: a recording keeps corrupt frames, so replaying it
exercises the decoder exactly as the live link did. A file cut short in the middle of a record
(the recorder was killed) is read up to its last complete record. At 921600 baud a recording
grows by at most 92 kB/s.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

from host_sdk.receiver import InfoAssembler, Receiver, Stats
from host_sdk.scan import Scan
from protocol import messages as m

log = logging.getLogger(__name__)

MAGIC = b"LPREC\r\n\x1a"
VERSION = 1
_HEAD = struct.Struct("<8sHIqqH")
_RECORD = struct.Struct("<qI")
MAX_CHUNK = 1 << 20  # a longer record length means the file is corrupt


@dataclass(frozen=True)
class RecordingHeader:
    baudrate: int
    wall_start_ns: int
    mono_start_ns: int
    port: str


class RecordingWriter:
    """Append chunks to a new recording; use as a context manager."""

    def __init__(self, path: str | Path, header: RecordingHeader):
        self._f: BinaryIO = open(path, "xb")
        name = header.port.encode()
        self._f.write(_HEAD.pack(MAGIC, VERSION, header.baudrate, header.wall_start_ns, header.mono_start_ns,
                                 len(name)) + name)

    def write(self, t_ns: int, data: bytes) -> None:
        self._f.write(_RECORD.pack(t_ns, len(data)) + data)
        self._f.flush()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_recording(path: str | Path) -> tuple[RecordingHeader, Iterator[tuple[int, bytes]]]:
    """The header and an iterator of (t_ns, chunk), read from the file as it goes (memory stays
    bounded by one chunk). ValueError if the file is not a recording."""
    with open(path, "rb") as f:
        head = f.read(_HEAD.size)
        if len(head) < _HEAD.size or head[:8] != MAGIC:
            raise ValueError(f"{path} is not a LaserPi recording (bad magic)")
        _, version, baud, wall, mono, n = _HEAD.unpack(head)
        if version != VERSION:
            raise ValueError(f"{path} is a version {version} recording; this SDK reads version {VERSION}")
        name = f.read(n)
        if len(name) < n:
            raise ValueError(f"{path}: header cut short")
        offset = f.tell()
    header = RecordingHeader(baud, wall, mono, name.decode("utf-8", errors="replace"))

    def records() -> Iterator[tuple[int, bytes]]:
        with open(path, "rb") as f:
            f.seek(offset)
            while True:
                pos = f.tell()
                head = f.read(_RECORD.size)
                if not head:
                    return
                if len(head) == _RECORD.size:
                    t_ns, length = _RECORD.unpack(head)
                    chunk = f.read(length) if length <= MAX_CHUNK else b""
                    if length <= MAX_CHUNK and len(chunk) == length:
                        yield t_ns, chunk
                        continue
                log.warning("%s: record at byte %d is cut short or corrupt; stopping there", path, pos)
                return

    return header, records()


class Replay:
    """Iterate the scans of a recording, decoded by the same Receiver as the live link.

    ``stats`` counts what was dropped (corrupt frames, gaps); ``info`` is the INFO the recording
    carried, completed by the ANGLES chunks that followed it (a recording cannot ask, so it takes
    them as they come; scans before it cannot be placed and are counted in
    stats.scans_without_info).
    Scan.stamp is in the recording host's time.monotonic() (header.mono_start_ns is its start).
    """

    def __init__(self, path: str | Path, link_rate_bps: float | None = None):
        self.path = Path(path)
        self.header, self._records = read_recording(path)
        self._receiver = Receiver(link_rate_bps or self.header.baudrate)

    @property
    def stats(self) -> Stats:
        return self._receiver.stats

    @property
    def info(self) -> m.Info | None:
        return self._receiver.info

    def __iter__(self) -> Iterator[Scan]:
        chunks = None
        for t_ns, chunk in self._records:
            for item in self._receiver.feed(chunk, t_ns * 1e-9):
                if isinstance(item, Scan):
                    yield item
                    continue
                if isinstance(item, m.Info):
                    chunks = InfoAssembler(item)
                elif isinstance(item, m.Angles) and chunks is not None:
                    chunks.add(item)
                else:
                    continue
                info = chunks.complete()
                if info is not None:
                    self._receiver.set_info(info)
                    chunks = None


def replay(path: str | Path) -> Replay:
    """``for scan in host_sdk.replay("run.lpr"): ...`` (see Replay)."""
    return Replay(path)
