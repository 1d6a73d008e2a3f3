"""Pi side of the co-MCU link: CoMcu speaks protocol/mcu.py over any pyserial-like port.

The port needs ``write(bytes) -> int`` (the bytes it took), ``read(size) -> bytes`` (returning
fewer bytes, or none, when its ``timeout`` expires) and ``in_waiting``: a ``serial.Serial`` at
250000 baud 8N1 on the Pi, its descriptor read and written directly (``open_comcu``, UartPort), or device.sim.comcu_emulator.SteppedMcuPort for the
firmware running in simavr. Every frame is one write; one the port took only part of is a lost
link (OSError).

Every command waits for its reply (matched by sequence number), except the heartbeat:
``send_heartbeat`` only writes it, and its ACK, read with the next command or ``edges()``, sets
``heartbeat_state``.  EDGE reports and unsolicited INFO frames (the MCU announces every boot with
one) that arrive meanwhile are kept, see ``edges()`` and ``boot_infos``.  A refusal raises
CoMcuNack naming the reason.
"""

from __future__ import annotations

import logging
import os
import select
import time
from dataclasses import dataclass
from typing import Callable

from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, FrameError, decode_frame

log = logging.getLogger(__name__)

BAUDRATE = 250_000
#: Sequence number of every HEARTBEAT (send_heartbeat); requests use 1..0xFFFE, so an ACK of a
#: heartbeat never answers a request.
HEARTBEAT_SEQ = 0xFFFF
_REPLY_TYPES = {mcu.Ack.MSG_TYPE, mcu.Nack.MSG_TYPE, mcu.Pong.MSG_TYPE, mcu.Status.MSG_TYPE, mcu.Info.MSG_TYPE}
_NAMES = {cls.MSG_TYPE: cls.__name__.upper() for cls in mcu.MESSAGES.values()}


class CoMcuError(RuntimeError):
    """The co-MCU did not answer as the protocol says."""


class CoMcuTimeout(CoMcuError):
    """No reply before the port's read timeout."""


class CoMcuNack(CoMcuError):
    """The co-MCU refused a command; ``reason`` is a NackReason name such as 'envelope_width'."""

    def __init__(self, nack: mcu.Nack):
        self.nack = nack
        self.reason = nack.reason_name
        self.detail = nack.detail
        super().__init__(f"{_NAMES.get(nack.acked_type, hex(nack.acked_type))} refused by the co-MCU: "
                         f"{self.reason} (detail {nack.detail})")


@dataclass(frozen=True, slots=True)
class PingResult:
    """MCU time of the reply, bracketed by host CLOCK_MONOTONIC times (ns): the MCU read its
    clock (mcu_ticks) somewhere between host_send_ns and host_recv_ns."""

    mcu_ticks: int
    host_send_ns: int
    host_recv_ns: int
    mcu_rx_ticks: int  # MCU time the PING's last byte arrived

    @property
    def round_trip_ns(self) -> int:
        return self.host_recv_ns - self.host_send_ns


def open_comcu(path: str, clock_ns: Callable[[], int] = time.monotonic_ns) -> CoMcu:
    """A CoMcu on the serial device ``path`` (the Pi's UART, or the simulated co-MCU's pty); OSError
    if it cannot be opened. Its writes do not block (pyserial ``write_timeout=0``: one write(2),
    without the select(2) after it with which a blocking pyserial write waits until the kernel
    has taken every byte): frames of at most 36 bytes, ~1 kB/s in all (67 heartbeats a second),
    never fill the kernel's transmit buffer of a UART that drains 25 kB/s (a page:
    UART_XMIT_SIZE, include/linux/serial_core.h); if it is full, the UART is stuck, and CoMcu
    reports the write the port took only part of as a lost link."""
    import serial

    try:
        return CoMcu(UartPort(serial.Serial(path, BAUDRATE, timeout=0.05, write_timeout=0)), clock_ns=clock_ns)
    except serial.SerialException as exc:
        raise OSError(str(exc)) from exc


class UartPort:
    """A ``serial.Serial`` as CoMcu's port: pyserial opens and configures the UART (baud rate, raw
    8N1, its file descriptor non-blocking: serial/serialposix.py ``Serial.open``), and the bytes
    move by one read(2) or write(2) on that descriptor. pyserial's ``read`` selects before every
    read and its ``write`` builds a Timeout object around each; with the caches cold, as between
    frames, that costs more than the system call: on this machine's pty a 12-byte heartbeat took
    73 us through ``Serial.write`` after 15 ms idle, 33 us through os.write (BENCHMARKS.md "Device
    process"), and the co-MCU gets ~110 such calls a second. ``read(size)`` waits up to ``timeout``
    for ``size`` bytes and returns what came, and a descriptor that select(2) reports readable
    but that reads no byte is a disconnected device (OSError), as in pyserial's read. ``write``
    returns the bytes the kernel took at once, 0 when its buffer is full (CoMcu: a lost link, as
    ``open_comcu`` says); pyserial's write with ``write_timeout=0`` instead retried a write(2)
    that would block in a busy loop until the kernel took a byte (serialposix.py ``write``
    swallows EAGAIN), which on a stuck UART spun forever holding LockedComcu's lock."""

    def __init__(self, port):
        if not (isinstance(port.timeout, (int, float)) and 0 <= port.timeout < float("inf")):
            raise ValueError(f"UartPort needs a port with a finite read timeout, got {port.timeout!r}")
        self.serial = port
        self.fd = port.fileno()
        self.timeout = port.timeout

    @property
    def in_waiting(self) -> int:
        return self.serial.in_waiting

    def read(self, size: int = 1) -> bytes:
        out = b""
        deadline = None
        readable = False  # select(2) said so just before this read
        while len(out) < size:
            try:
                chunk = os.read(self.fd, size - len(out))
            except BlockingIOError:
                chunk = None
            if chunk:
                out += chunk
                readable = False
                continue
            if chunk == b"" and readable:
                raise OSError(f"{self.serial.port}: readable but no data (device disconnected?)")
            now = time.monotonic()
            deadline = now + self.timeout if deadline is None else deadline
            if now >= deadline:
                break
            readable = bool(select.select([self.fd], [], [], deadline - now)[0])
            if not readable:
                break
        return out

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.fd, data)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        # no later read or write on the number, which the kernel may give to another file
        self.fd = -1
        self.serial.close()


class CoMcu:
    """Commands to the laser co-MCU; one instance per port, not thread-safe."""

    def __init__(self, port, *, clock_ns: Callable[[], int] = time.monotonic_ns, max_skipped_frames: int = 256):
        self.port = port
        self._clock_ns = clock_ns
        self._max_skipped = max_skipped_frames
        self._seq = 0
        self._buf = bytearray()
        self._edges: list[mcu.Edge] = []
        self.boot_infos: list[mcu.Info] = []
        self.bad_frames = 0
        self._heartbeat_wire = b"\x00" + mcu.encode_message(mcu.Heartbeat(), HEARTBEAT_SEQ)
        #: a heartbeat's ACK without faults as it comes off the wire (COBS, no delimiter) -> its
        #: state: the ~67 a second are counted by a lookup, not decoded (they are all the same few)
        self._fault_free_heartbeat_acks = {
            mcu.encode_message(mcu.Ack(mcu.Heartbeat.MSG_TYPE, state), HEARTBEAT_SEQ)[:-1]: (state, mcu.Fault(0))
            for state in mcu.McuState}
        self.heartbeats_sent = 0
        self.heartbeat_acks = 0
        #: (state, latched faults) from the newest heartbeat ACK since the last STOP; None before one
        self.heartbeat_state: tuple[mcu.McuState, mcu.Fault] | None = None

    # ---- commands -----------------------------------------------------------------------
    def ping(self) -> PingResult:
        send_ns = self._clock_ns()
        pong = self._request(mcu.Ping(), mcu.Pong)
        recv_ns = self._clock_ns()
        return PingResult(pong.tx_ticks, send_ns, recv_ns, pong.rx_ticks)

    def schedule(self, first_rise_ticks: int, period_ticks: int, width_ticks: int, mask: int = 1, n: int = 1,
                 stream_edges: bool = False) -> int:
        """Start a pulse pattern (see protocol.mcu.Schedule); returns the index of the first lit pulse."""
        msg = mcu.Schedule(first_rise_ticks, period_ticks, width_ticks, mask, n, stream_edges)
        return self._request(msg, mcu.Ack).info

    def trim(self, phase_ticks: int = 0, period_ticks: int = 0) -> int:
        """Move the first slot starting >= 100 us from now by phase_ticks and change the period
        by period_ticks from there (see protocol.mcu.Trim); returns the index of that slot."""
        return self._request(mcu.Trim(phase_ticks, period_ticks), mcu.Ack).info

    def stop(self) -> int:
        """Laser off now, schedule dropped, faults cleared; returns the pulse count."""
        pulses = self._request(mcu.Stop(), mcu.Ack).info
        self.heartbeat_state = None  # the MCU answers in order: every ACK before the STOP's was read
        return pulses

    def status(self) -> mcu.Status:
        return self._request(mcu.StatusRequest(), mcu.Status)

    def info(self) -> mcu.Info:
        return self._request(mcu.InfoRequest(), mcu.Info)

    def send_heartbeat(self) -> None:
        """Keep a running schedule alive (the MCU switches the laser off without one for
        Info.heartbeat_timeout_ms).  Only written: one 12-byte write, no round trip.  Its ACK,
        read with the next command or ``edges()``, updates ``heartbeat_state`` and
        ``heartbeat_acks``."""
        self._write(self._heartbeat_wire)
        self.heartbeats_sent += 1

    def edges(self) -> list[mcu.Edge]:
        """EDGE reports received so far (streamed when the schedule asked for them), oldest
        first; also takes any complete frames already waiting on the port, without blocking."""
        waiting = self.port.in_waiting
        if waiting:
            self._buf += self.port.read(waiting)
            while (frame := self._next_buffered_frame()) is not None:
                self._keep_unsolicited(frame)
        out, self._edges = self._edges, []
        return out

    # ---- plumbing -----------------------------------------------------------------------
    def _request(self, msg, reply_cls):
        self._seq = self._seq % (HEARTBEAT_SEQ - 1) + 1  # 1..0xFFFE: 0 is the MCU's unsolicited traffic
        # A leading delimiter ends any partial frame line noise left in the MCU's receiver.
        self._write(b"\x00" + mcu.encode_message(msg, self._seq))
        for _ in range(self._max_skipped):
            frame = self._read_frame()
            if frame.seq == self._seq and frame.msg_type in _REPLY_TYPES:
                reply = mcu.decode_message(frame)
                if isinstance(reply, mcu.Nack):
                    raise CoMcuNack(reply)
                if not isinstance(reply, reply_cls):
                    raise CoMcuError(f"{type(msg).__name__} answered by {type(reply).__name__}, "
                                     f"expected {reply_cls.__name__}")
                return reply
            self._keep_unsolicited(frame)
        raise CoMcuError(f"no reply to {type(msg).__name__} among {self._max_skipped} frames")

    def _write(self, wire: bytes) -> None:
        n = self.port.write(wire)
        if n != len(wire):
            raise OSError(f"the co-MCU's port took {n} of a frame's {len(wire)} bytes (its transmit buffer is full)")

    def _keep_unsolicited(self, frame) -> None:
        try:
            msg = mcu.decode_message(frame)
        except FrameError as exc:
            self.bad_frames += 1
            log.warning("co-MCU frame dropped: %s", exc)
            return
        if isinstance(msg, mcu.Edge):
            self._edges.append(msg)
        elif isinstance(msg, mcu.Ack) and frame.seq == HEARTBEAT_SEQ:
            self._heartbeat_acked((mcu.McuState(msg.info & 0xFF), mcu.Fault((msg.info >> 8) & 0xFF)))
        elif isinstance(msg, mcu.Info) and frame.seq == 0:
            log.info("co-MCU (re)started: reset cause 0x%02x", msg.reset_cause)
            self.boot_infos.append(msg)
        else:
            log.debug("co-MCU frame ignored: %s seq %d", type(msg).__name__, frame.seq)

    def _heartbeat_acked(self, state: tuple[mcu.McuState, mcu.Fault]) -> None:
        self.heartbeat_acks += 1
        self.heartbeat_state = state

    def _next_buffered_frame(self):
        while (end := self._buf.find(b"\x00")) >= 0:
            encoded = bytes(self._buf[:end])
            del self._buf[: end + 1]
            if not encoded:
                continue
            state = self._fault_free_heartbeat_acks.get(encoded)
            if state is not None:  # what _keep_unsolicited would make of it, without decoding it
                self._heartbeat_acked(state)
                continue
            try:
                return decode_frame(encoded, max_payload=MAX_PAYLOAD_MCU)
            except FrameError as exc:
                self.bad_frames += 1
                log.warning("co-MCU frame dropped: %s", exc)
        return None

    def _read_frame(self):
        while (frame := self._next_buffered_frame()) is None:
            chunk = self.port.read(max(1, self.port.in_waiting))
            if not chunk:
                raise CoMcuTimeout("co-MCU did not answer before the port timeout")
            self._buf += chunk
        return frame


class CoMcuTrain:
    """The pulse train as device.sync.control.LaserScheduler sees it, on a CoMcu.

    ``schedule`` replaces any running train (STOP, which also acknowledges latched faults, then
    SCHEDULE with EDGE streaming on; the pattern as a list of lit flags), ``trim`` takes the new
    absolute period and sends the difference, ``stop`` stops.  Refusals raise CoMcuNack.
    """

    def __init__(self, comcu: CoMcu):
        self.comcu = comcu
        self._period: int | None = None

    def schedule(self, first_start_tick: int, period_ticks: int, width_ticks: int, pattern) -> int:
        lit = [bool(x) for x in pattern]
        if not 1 <= len(lit) <= 32 or not any(lit):
            raise ValueError(f"pattern must have 1..32 slots with at least one lit, got {lit}")
        self.comcu.stop()
        self._period = None
        mask = sum(1 << i for i, x in enumerate(lit) if x)
        first_lit = self.comcu.schedule(first_start_tick, period_ticks, width_ticks, mask, len(lit), stream_edges=True)
        self._period = period_ticks
        return first_lit

    def trim(self, phase_ticks: int, period_ticks: int) -> int:
        if self._period is None:
            raise CoMcuError("trim without a running train: schedule first")
        moved = self.comcu.trim(phase_ticks, period_ticks - self._period)
        self._period = period_ticks
        return moved

    def stop(self) -> None:
        self.comcu.stop()
        self._period = None
