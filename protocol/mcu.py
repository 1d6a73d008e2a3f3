"""Messages of the Pi <-> co-MCU link (types 0x40-0x7F), carried by protocol/framing.py.

The numbers, layouts and reason codes are the firmware's (firmware_pwm/src/msg.h);
tests/test_mcu_protocol.py checks that both files agree.  Byte layouts (all little-endian) and
units are documented in firmware_pwm/README.md.  Times are MCU ticks: Timer1 counts at
F_CPU / 8, so one tick is 0.5 us in the default 16 MHz firmware (TICKS_PER_SECOND) and 1 us in
the 8 MHz one; Info.ticks_per_second is the running firmware's.

Pi -> MCU: Ping, Schedule, Trim, Stop, StatusRequest, Heartbeat, InfoRequest.
MCU -> Pi: Pong, Ack, Nack, Status, Edge, Info.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, fields
from typing import ClassVar

from protocol.framing import MAX_PAYLOAD_MCU, Frame, FrameError, encode_frame

TICKS_PER_SECOND = 2_000_000  # the default 16 MHz build's; ask Info for the running firmware's

_RANGES = {
    "B": (0, 0xFF), "H": (0, 0xFFFF), "I": (0, 0xFFFF_FFFF), "Q": (0, 0xFFFF_FFFF_FFFF_FFFF),
    "i": (-(2**31), 2**31 - 1),
}


class NackReason(enum.IntEnum):
    MALFORMED = 1        # COBS, length, version or payload size wrong
    CRC = 2              # CRC-32 mismatch
    UNKNOWN_TYPE = 3
    ENVELOPE_WIDTH = 4   # detail = the firmware's MAX_PULSE_TICKS
    ENVELOPE_DUTY = 5    # detail = smallest off time (ticks) the duty envelope allows
    BUSY = 6             # SCHEDULE while running or in a fault (STOP first); detail = state
    BAD_TIME = 7         # start too close (< 200 ticks), in the past, or > 10 s ahead; detail = now (low 32 bits)
    BAD_PATTERN = 8      # n outside 1..32, no lit frame, or mask bits at or above n
    BAD_VALUE = 9        # width below 200 ticks (detail = that minimum) or a trimmed period too short
    NOT_RUNNING = 10     # TRIM without a running schedule
    ENVELOPE_RATE = 11   # pulses closer than the firmware's MIN_PERIOD_TICKS (rise to rise or fall to fall); detail = it


class McuState(enum.IntEnum):
    IDLE = 0
    RUNNING = 1
    FAULT = 2


class Fault(enum.IntFlag):
    HEARTBEAT = 0x01     # heartbeats stopped: laser switched off
    WIDTH = 0x02         # run-time guard saw a pulse longer than the envelope
    DUTY = 0x04          # run-time guard refused a pulse that would break the duty envelope
    LATE = 0x08          # a rise could not be armed in time
    RATE = 0x10          # run-time guard refused a pulse closer than the envelope's minimum period


class EdgeFlag(enum.IntFlag):
    FALL_FORCED = 0x01   # the fall could not be armed in time: software ended the pulse, late
    CUT = 0x02           # the pulse was cut by STOP or a fault


class _Message:
    """Fixed-layout payload: the dataclass fields, in order, packed with FORMAT."""

    MSG_TYPE: ClassVar[int]
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<")

    def encode(self) -> bytes:
        values = []
        for f, code in zip(fields(self), self.FORMAT.format.lstrip("<")):
            v = int(getattr(self, f.name))
            lo, hi = _RANGES[code]
            if not lo <= v <= hi:
                raise ValueError(f"{type(self).__name__}.{f.name} = {v} is outside [{lo}, {hi}]")
            values.append(v)
        return self.FORMAT.pack(*values)

    @classmethod
    def decode(cls, payload: bytes):
        if len(payload) != cls.FORMAT.size:
            raise FrameError("length", f"{cls.__name__} payload is {len(payload)} bytes, expected {cls.FORMAT.size}")
        return cls(*cls.FORMAT.unpack(payload))


@dataclass(frozen=True, slots=True)
class Ping(_Message):
    MSG_TYPE: ClassVar[int] = 0x40


@dataclass(frozen=True, slots=True)
class Schedule(_Message):
    """Pulse k (k = 0, 1, ...) starts at first_rise_ticks + k * period_ticks and lasts
    width_ticks if bit (k mod n) of mask is set (n = 2, mask = 0b01: every other frame lit)."""

    MSG_TYPE: ClassVar[int] = 0x41
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<QIIIBB")
    first_rise_ticks: int
    period_ticks: int
    width_ticks: int
    mask: int = 1
    n: int = 1
    stream_edges: bool = False

    def __post_init__(self):
        object.__setattr__(self, "stream_edges", bool(self.stream_edges))


@dataclass(frozen=True, slots=True)
class Trim(_Message):
    """Moves the first slot starting >= 100 us after arrival by phase_ticks; the slots after it
    follow at period + period_ticks.  A pulse in flight or armed < 100 us ahead is never touched
    (the trim then applies to the slot after it).  ACK.info = the slot moved."""

    MSG_TYPE: ClassVar[int] = 0x42
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<ii")
    phase_ticks: int
    period_ticks: int


@dataclass(frozen=True, slots=True)
class Stop(_Message):
    MSG_TYPE: ClassVar[int] = 0x43


@dataclass(frozen=True, slots=True)
class StatusRequest(_Message):
    MSG_TYPE: ClassVar[int] = 0x44


@dataclass(frozen=True, slots=True)
class Heartbeat(_Message):
    MSG_TYPE: ClassVar[int] = 0x45


@dataclass(frozen=True, slots=True)
class InfoRequest(_Message):
    MSG_TYPE: ClassVar[int] = 0x46


@dataclass(frozen=True, slots=True)
class Pong(_Message):
    """MCU time when the PING's last byte arrived and when the PONG was started."""

    MSG_TYPE: ClassVar[int] = 0x60
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<QQ")
    rx_ticks: int
    tx_ticks: int


@dataclass(frozen=True, slots=True)
class Ack(_Message):
    """info: SCHEDULE -> index of the first lit pulse; TRIM -> index of the slot it moved;
    STOP -> pulses emitted so far; HEARTBEAT -> state | faults << 8."""

    MSG_TYPE: ClassVar[int] = 0x61
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BI")
    acked_type: int
    info: int


@dataclass(frozen=True, slots=True)
class Nack(_Message):
    MSG_TYPE: ClassVar[int] = 0x62
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BBI")
    acked_type: int
    reason: int
    detail: int

    @property
    def reason_name(self) -> str:
        try:
            return NackReason(self.reason).name.lower()
        except ValueError:
            return f"reason_{self.reason}"


@dataclass(frozen=True, slots=True)
class Status(_Message):
    MSG_TYPE: ClassVar[int] = 0x63
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BBBBIHHHHHIIQQ")
    state: int
    faults: int
    reset_cause: int          # MCUSR at boot: 0x08 watchdog, 0x04 brown-out, 0x02 external, 0x01 power-on
    stream_edges: int
    frames_ok: int
    crc_errors: int
    malformed: int
    unknown: int
    refused: int
    late: int
    pulses: int
    pulse_index: int          # pulse in flight, or the next one
    last_rise_ticks: int
    last_fall_ticks: int


@dataclass(frozen=True, slots=True)
class Edge(_Message):
    """Both edges of pulse `index` in MCU ticks (the compare-match ticks, exact)."""

    MSG_TYPE: ClassVar[int] = 0x64
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<IQQB")
    index: int
    rise_ticks: int
    fall_ticks: int
    flags: int


@dataclass(frozen=True, slots=True)
class Info(_Message):
    """Sent unsolicited at boot (seq 0) and on InfoRequest: the compiled-in envelope."""

    MSG_TYPE: ClassVar[int] = 0x65
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BBHIIII")
    firmware_version: int
    reset_cause: int
    heartbeat_timeout_ms: int
    max_pulse_ticks: int
    max_duty_ppm: int
    ticks_per_second: int
    min_period_ticks: int   # shortest rise-to-rise (and fall-to-fall) interval of two pulses

    @property
    def first_rise_min_ticks(self) -> int:
        """Earliest tick of this boot a pulse may rise at.  The firmware boots as if a pulse of
        max_pulse_ticks had just ended at tick 0 (firmware_pwm/src/core.c, core_init: the pulse
        before a reset may have ended at the reset), so the first rise needs both the rate rule's
        min_period_ticks and the duty rule's off time after the longest pulse."""
        duty_gap = -(-self.max_pulse_ticks * (1_000_000 - self.max_duty_ppm) // self.max_duty_ppm)
        return max(self.min_period_ticks, duty_gap)


MESSAGES: dict[int, type[_Message]] = {
    cls.MSG_TYPE: cls
    for cls in (Ping, Schedule, Trim, Stop, StatusRequest, Heartbeat, InfoRequest,
                Pong, Ack, Nack, Status, Edge, Info)
}


def encode_message(msg: _Message, seq: int) -> bytes:
    """Wire bytes (delimiter included) of one co-MCU message."""
    return encode_frame(msg.MSG_TYPE, seq, msg.encode(), max_payload=MAX_PAYLOAD_MCU)


def decode_message(frame: Frame) -> _Message:
    """The message a decoded frame carries; FrameError('unknown'|'length') if it is none."""
    cls = MESSAGES.get(frame.msg_type)
    if cls is None:
        raise FrameError("unknown", f"message type 0x{frame.msg_type:02x} is not a co-MCU message")
    return cls.decode(frame.payload)
