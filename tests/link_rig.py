"""A device for host SDK tests, through sim:// or a real pty, whose frames a test can forge.

Rig("sim") opens ``sim://`` (the link server in process behind an in-memory pipe paced like a
UART); Rig("pty") runs the same LinkServer here on a real pseudo-terminal (protocol/ports.py
PtyLink, raw mode) that the SDK opens by path. Either way the server writes through a
ForgingPort: a test can change or drop the next frames the device sends (well-formed lies: an
INFO nobody asked for, a scan with a wrong age, a reply that never arrives) or write raw bytes,
and restart the device (a new server with a new boot id on the same line, as a device process
restarting behind a UART). OldDevicePort makes the server speak protocol minor 1.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from pathlib import Path

import host_sdk
from protocol import messages as m
from protocol.framing import decode_frame, encode_frame
from protocol.mock_wall import AnalyticWallSource, default_settings
from protocol.ports import NoisyPort, PacedPort, PtyLink
from protocol.server import DeviceConfig, LinkServer
from protocol.stream import StreamDecoder

DROP = object()


class ForgingPort:
    """The device's port with its outgoing frames open to editing: ``forge(edit, times)`` calls
    edit(msg) on each frame written until ``times`` edits took effect; it returns None (unchanged),
    DROP, or the message to send instead (same frame sequence number)."""

    def __init__(self, port):
        self.port = port
        self._lock = threading.Lock()
        self._edit = None
        self._left = 0
        self.forged = 0

    def forge(self, edit, times: int = 1) -> None:
        with self._lock:
            self._edit, self._left = edit, times

    def raw(self, data: bytes) -> None:
        with self._lock:
            self.port.write(data)

    def read(self, size: int = 4096) -> bytes:
        return self.port.read(size)

    def write(self, data: bytes) -> int:
        with self._lock:
            data = self._edited(data)
            if data:
                self.port.write(data)
        return len(data)

    def _edited(self, data: bytes) -> bytes:
        out = self._rewrite(data)
        if self._edit is None or self._left <= 0:
            return out
        frame, msg = _decode(out)
        if msg is None:
            return out
        new = self._edit(msg)
        if new is None:
            return out
        self._left -= 1
        self.forged += 1
        if new is DROP:
            return b""
        return b"\x00" + encode_frame(new.TYPE, frame.seq, new.encode())

    def _rewrite(self, data: bytes) -> bytes:
        return data


def _decode(data: bytes):
    try:
        frame = decode_frame(data.strip(b"\x00"))
        return frame, m.decode_message(frame.msg_type, frame.payload)
    except (ValueError, m.MessageError):
        return None, None


class OldDevicePort(ForgingPort):
    """The port of a device of protocol minor 1: requests reach the server without their ids
    (minor-2 request types as an unknown type), replies and scans leave without the fields of
    minor 2."""

    OLD_MINOR2 = {m.Info: m.Info.MINOR2_FIELDS, m.Health: m.Health.MINOR2_FIELDS, m.ScanMessage: ("boot_id",)}

    def __init__(self, port):
        super().__init__(port)
        self._dec = StreamDecoder()

    def read(self, size: int = 4096) -> bytes:
        out = bytearray()
        for rec in self._dec.feed(self.port.read(size)):
            f = rec.frame
            try:
                msg = m.decode_message(f.msg_type, f.payload)
            except m.MessageError:
                out += b"\x00" + encode_frame(f.msg_type, f.seq, f.payload)
                continue
            if f.msg_type in (m.MsgType.GET_ANGLES, m.MsgType.HEARTBEAT):
                out += b"\x00" + encode_frame(0x3F, f.seq, f.payload)  # unknown to a minor-1 device
                continue
            if hasattr(msg, "request_id"):
                msg = dataclasses.replace(msg, request_id=0)
            if isinstance(msg, m.GetInfo):
                msg = dataclasses.replace(msg, host_minor=1)
            out += b"\x00" + encode_frame(f.msg_type, f.seq, msg.encode())
        return bytes(out)

    def _rewrite(self, data: bytes) -> bytes:
        frame, msg = _decode(data)
        if msg is None:
            return data
        fields = self.OLD_MINOR2.get(type(msg), ())
        if isinstance(msg, (m.Ack, m.Nack)):
            msg = dataclasses.replace(msg, request_id=0)
        elif fields:
            msg = dataclasses.replace(msg, **{n: None for n in fields})
            if isinstance(msg, m.Info):
                msg = dataclasses.replace(msg, protocol_minor=1)
        else:
            return data
        prefix = b"\x00" if data.startswith(b"\x00") else b""
        return prefix + encode_frame(frame.msg_type, frame.seq, msg.encode())


class Rig:
    """One simulated device on ``kind`` ("sim" or "pty"); see the module docstring."""

    def __init__(self, kind: str, tmp_path: Path, *, points: int = 200, rate: float = 20.0,
                 host_timeout_s: float = 5.0, start_delay_s: float = 0.0, old: bool = False, ber: float = 0.0,
                 seed: int = 0):
        self.kind, self.points, self.rate = kind, points, rate
        self.host_timeout_s, self.start_delay_s, self.old = host_timeout_s, start_delay_s, old
        self.ber, self.seed = ber, seed
        self.server: LinkServer | None = None
        self._pty = None
        if kind == "pty":
            self.link = tmp_path / "laserpi"
            self._pty = PtyLink(self.link)
            line = NoisyPort(self._pty.port, ber, seed=seed)  # a bad cable: bits flip on the way to the host
            self.forge_port = (OldDevicePort if old else ForgingPort)(PacedPort(line, 921600))
            self.server = LinkServer(self.forge_port, self.source(), self.config()).start()
        elif old:
            raise ValueError("the old device runs on a pty")

    def source(self) -> AnalyticWallSource:
        return AnalyticWallSource(2.0, n_points=self.points, noise_floor_m=0.0, noise_rel_per_m=0.0, dropout=0.0,
                                  start_delay_s=self.start_delay_s)

    def config(self) -> DeviceConfig:
        settings = default_settings(self.points).merged(m.ScanSettings(scan_rate_hz=self.rate))
        return DeviceConfig(laser_limit_mw=5.0, settings=settings, host_timeout_s=self.host_timeout_s)

    @property
    def url(self) -> str:
        if self.kind == "pty":
            return str(self.link)
        return (f"sim://wall?points={self.points}&rate={self.rate}&noise=0&host_timeout={self.host_timeout_s}"
                f"&start_delay={self.start_delay_s}&ber={self.ber}&seed={self.seed}")

    def open(self, **kw) -> host_sdk.LaserPi:
        sensor = host_sdk.LaserPi(self.url, **kw)
        if self.kind == "sim":
            self._serial = sensor._serial
            self.server = sensor._serial._server
            self.forge_port = self.server.port = ForgingPort(self.server.port)
        return sensor

    def restart(self) -> None:
        """The device process restarts behind the same line: a new server, a new boot id, idle."""
        port = self.server.port
        self.server.close()
        self.server = LinkServer(port, self.source(), self.config()).start()
        if self.kind == "sim":
            self._serial._server = self.server

    def close(self) -> None:
        if self._pty is not None:
            self.server.close()
            self._pty.close()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wall_truth(scan) -> "np.ndarray":
    import numpy as np

    from protocol.mock_wall import wall_ranges

    t = wall_ranges(scan.angles, 2.0)
    return np.where(t > scan.range_max, math.inf, t)
