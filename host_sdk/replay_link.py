"""Serve a recording (host_sdk/recording.py) to a host again, as if it were the sensor.

The server answers the host's requests itself - GET_INFO with the recording's INFO (all its
angles in it), GET_HEALTH, START and STOP with ACK, SET_CONFIG with NACK (a recording cannot
change), each echoing the request's id - and, while started,
writes the recorded bytes at their recorded times divided by ``speed``. STOP pauses the playback
and START resumes it, so a LaserPi opening the link (STOP, GET_INFO, START) sees the recording
from its beginning. Recorded control replies (INFO, HEALTH, ACK, NACK, ANGLES) are taken out of the
stream so that they cannot be mistaken for answers; everything else, corrupt bytes included,
is sent verbatim. (The removed frames show up as frame sequence gaps on the host.)
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time

from host_sdk.receiver import InfoAssembler
from host_sdk.recording import read_recording
from protocol import messages as m
from protocol.framing import FrameError, decode_frame, encode_frame
from protocol.server import device_clock_us
from protocol.stream import StreamDecoder

log = logging.getLogger(__name__)

_CONTROL = {m.MsgType.INFO, m.MsgType.HEALTH, m.MsgType.ACK, m.MsgType.NACK, m.MsgType.ANGLES}


class ControlFilter:
    """Removes intact control-reply frames from a byte stream, passing everything else verbatim."""

    def __init__(self):
        self._carry = b""

    def feed(self, chunk: bytes) -> bytes:
        segments = (self._carry + chunk).split(b"\x00")
        self._carry = segments.pop()
        out = []
        for seg in segments:
            try:
                if seg and decode_frame(seg).msg_type in _CONTROL:
                    continue
            except FrameError:
                pass
            out.append(seg)
        return b"".join(s + b"\x00" for s in out)


def recorded_info(path) -> m.Info:
    """The last complete INFO in a recording (its angles from the ANGLES chunks that followed
    it, from a device of protocol minor >= 2); ValueError if it has none."""
    _, records = read_recording(path)
    dec, info, chunks = StreamDecoder(), None, None
    for _, chunk in records:
        for rec in dec.feed(chunk):
            if rec.frame.msg_type not in (m.MsgType.INFO, m.MsgType.ANGLES):
                continue
            try:
                msg = m.decode_message(rec.frame.msg_type, rec.frame.payload)
            except m.MessageError:
                continue
            if isinstance(msg, m.Info):
                chunks = InfoAssembler(msg)
            elif chunks is not None:
                chunks.add(msg)
            info = (chunks.complete() if chunks is not None else None) or info
    if info is None:
        raise ValueError(f"{path} holds no complete INFO message; a host could not place its scans")
    return info


class ReplayServer:
    """Play ``path`` on ``port`` (protocol/ports.py surface) at ``speed`` x real time."""

    def __init__(self, port, path, speed: float = 1.0):
        if not speed > 0:
            raise ValueError(f"speed must be positive, got {speed}")
        self.port, self.speed = port, speed
        self.info = recorded_info(path)
        _, self._records = read_recording(path)
        self._playing = threading.Event()
        self._write_lock = threading.Lock()
        self._seq = 0
        self._sent_scans = 0
        self.finished = threading.Event()

    def serve(self, stop: threading.Event) -> None:
        reader = threading.Thread(target=self._read_loop, args=(stop,), name="replay-reader", daemon=True)
        reader.start()
        self._play(stop)
        reader.join(timeout=1.0)

    def _play(self, stop: threading.Event) -> None:
        flt = ControlFilter()
        t0_rec = clock0 = None
        for t_ns, chunk in self._records:
            if t0_rec is None:
                t0_rec = t_ns
            while not self._playing.is_set():  # paused: shift the schedule by the pause
                if stop.wait(0.05):
                    return
                clock0 = None
            if clock0 is None:
                clock0 = time.monotonic() - (t_ns - t0_rec) * 1e-9 / self.speed
            wait = clock0 + (t_ns - t0_rec) * 1e-9 / self.speed - time.monotonic()
            if wait > 0 and stop.wait(wait):
                return
            data = flt.feed(chunk)
            if data:
                with self._write_lock:
                    self.port.write(data)
        self.finished.set()

    def _read_loop(self, stop: threading.Event) -> None:
        dec = StreamDecoder()
        while not stop.is_set() and not self.finished.is_set():
            try:
                data = self.port.read(4096)
            except OSError:
                return
            for rec in dec.feed(data):
                self._answer(rec.frame)

    def _answer(self, frame) -> None:
        t = frame.msg_type
        try:
            msg = m.decode_message(t, frame.payload)
        except m.MessageError:
            msg = None
        rid = getattr(msg, "request_id", 0)
        if t == m.MsgType.HEARTBEAT:
            return
        if t == m.MsgType.GET_INFO:
            reply = self.info if self.info.boot_id is None else dataclasses.replace(self.info, request_id=rid)
            reply = dataclasses.replace(reply, settings=reply.settings.for_host(0 if msg is None else msg.host_minor))
        elif t == m.MsgType.GET_HEALTH:
            playing = self._playing.is_set()
            state = m.DeviceState.SCANNING if playing else m.DeviceState.IDLE
            newer = {} if self.info.boot_id is None else dict(
                {n: 0 for n in m.Health.MINOR1_FIELDS}, request_id=rid, boot_id=self.info.boot_id, host_timeouts=0)
            reply = m.Health(state, playing, playing, 0, 0, 0, device_clock_us(), **newer)
        elif t in (m.MsgType.START, m.MsgType.STOP):
            (self._playing.set if t == m.MsgType.START else self._playing.clear)()
            reply = m.Ack(t, frame.seq, rid)
        elif t == m.MsgType.SET_CONFIG:
            reply = m.Nack(t, frame.seq, m.NackCode.NOT_SUPPORTED, "a replayed recording cannot change its settings", rid)
        else:
            reply = m.Nack(t, frame.seq, m.NackCode.UNKNOWN_MESSAGE, f"unknown request 0x{t:02x}", rid)
        with self._write_lock:
            self.port.write(b"\x00" + encode_frame(reply.TYPE, self._seq, reply.encode()))
            self._seq = (self._seq + 1) & 0xFFFF
