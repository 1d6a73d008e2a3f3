"""Host <-> device link messages (types 0x01-0x3F): one dataclass per message, payload codecs.

Every payload is little-endian and packed with ``struct`` (scans with numpy); byte layouts are in
protocol/SPEC.md. ``encode()`` returns the payload bytes that go into a frame
(protocol/framing.py); ``decode(payload)`` checks lengths and values and raises MessageError
naming what is wrong. A decoder accepts and ignores trailing bytes it does not know (that is how
minor protocol revisions add fields, see SPEC.md "Compatibility").

Ranges travel as u16 codes in quarter millimetres (RANGE_UNIT_M) with three reserved codes for
the REP 117 values, qualities as u8: 3 bytes per point.
"""

from __future__ import annotations

import enum
import math
import struct
import zlib
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from protocol.framing import OVERHEAD, PROTOCOL_VERSION

#: Message revision inside PROTOCOL_VERSION; raised for additive changes only (SPEC.md).
PROTOCOL_MINOR = 4  # 1: HEALTH fault counters; 2: request ids, boot id, ANGLES, HEARTBEAT; 3: signed ray interval; 4: ray times (SPEC.md 2)


class MsgType(enum.IntEnum):
    GET_INFO = 0x01
    INFO = 0x02
    GET_HEALTH = 0x03
    HEALTH = 0x04
    START = 0x05
    STOP = 0x06
    SET_CONFIG = 0x07
    ACK = 0x08
    NACK = 0x09
    GET_ANGLES = 0x0A
    ANGLES = 0x0B
    HEARTBEAT = 0x0C
    SCAN = 0x10
    LOG = 0x11


class NackCode(enum.IntEnum):
    UNKNOWN_MESSAGE = 1  # message type not known to the device
    BAD_PAYLOAD = 2  # payload does not decode
    OUT_OF_RANGE = 3  # a setting outside what the device supports
    EYE_SAFETY = 4  # a setting outside the IEC 60825-1 Class 1 envelope
    NOT_SUPPORTED = 5  # understood but not possible on this device (e.g. a replay)
    SOURCE_ERROR = 6  # the scan source failed to apply the request


class DeviceState(enum.IntEnum):
    IDLE = 0
    SCANNING = 1
    FAULT = 2


class ErrorCode(enum.IntEnum):
    """Codes in HEALTH.errors: conditions that are true now (a receiver keeps unknown codes as ints)."""

    SOURCE_FAILED = 1  # the scan source raised and scanning stopped; see the LOG messages
    SYNC_LOST = 2  # camera exposures and laser pulses are not locked
    LASER_FAULT = 3  # the co-MCU driving the laser is lost, was reset or latched a fault: laser off, re-syncing
    CAMERA_FAULT = 4  # the camera stalled or failed: laser off, camera being restarted
    PIPELINE_FAULT = 5  # the image pipeline raised on the last frame pair: that scan was skipped
    SYNC_DEGRADED = 6  # no GPIO edge timestamps of the laser trigger: synchronised by PING alone, less accurately
    SATURATED = 7  # bright light saturates the camera where the line is or could be: those rays are NaN


class MessageError(ValueError):
    """A payload that does not decode; ``reason`` is a short machine-readable word."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


# --- ranges: u16 codes of RANGE_UNIT_M, three reserved codes for REP 117 -----------------------
RANGE_UNIT_M = 0.00025
RANGE_CODE_NAN = 0xFFFF  # invalid measurement
RANGE_CODE_POS_INF = 0xFFFE  # no return within range_max
RANGE_CODE_NEG_INF = 0xFFFD  # object closer than range_min
RANGE_CODE_MAX = 0xFFFC  # largest finite code: 16.383 m
RANGE_MAX_ENCODABLE_M = RANGE_CODE_MAX * RANGE_UNIT_M


def _range_lut() -> np.ndarray:
    lut = np.arange(65536, dtype=np.float64) * RANGE_UNIT_M
    lut[RANGE_CODE_NEG_INF] = -np.inf
    lut[RANGE_CODE_POS_INF] = np.inf
    lut[RANGE_CODE_NAN] = np.nan
    return lut.astype(np.float32)


#: code -> metres (float32), read-only. 256 KiB; one gather decodes a whole scan.
RANGE_LUT = _range_lut()
RANGE_LUT.flags.writeable = False


def encode_ranges(ranges_m: np.ndarray) -> np.ndarray:
    """Metres (REP 117 values allowed) -> u16 codes, rounded to the nearest RANGE_UNIT_M.

    Raises ValueError for a finite range that is negative or beyond RANGE_MAX_ENCODABLE_M rather
    than sending a wrong number.
    """
    r = np.asarray(ranges_m, dtype=np.float64)
    if r.ndim != 1:
        raise ValueError(f"ranges must be 1-D, got shape {r.shape}")
    finite = np.isfinite(r)
    bad = finite & ((r < 0) | (r > RANGE_MAX_ENCODABLE_M))
    if bad.any():
        raise ValueError(
            f"{int(bad.sum())} finite ranges outside [0, {RANGE_MAX_ENCODABLE_M:.3f}] m, e.g. {r[bad][0]!r}"
        )
    codes = np.empty(r.shape, dtype="<u2")
    codes[finite] = np.rint(r[finite] / RANGE_UNIT_M)
    codes[np.isnan(r)] = RANGE_CODE_NAN
    codes[r == np.inf] = RANGE_CODE_POS_INF
    codes[r == -np.inf] = RANGE_CODE_NEG_INF
    return codes


def decode_ranges(codes: np.ndarray) -> np.ndarray:
    """u16 codes -> metres as float32 (REP 117 NaN / +inf / -inf for the reserved codes)."""
    return RANGE_LUT[codes]


# --- helpers ----------------------------------------------------------------------------------
def _need(payload: bytes, size: int, what: str) -> None:
    if len(payload) < size:
        raise MessageError("short", f"{what} needs {size} bytes, got {len(payload)}")


def _pack_str(text: str, what: str, *, clip: bool = False) -> bytes:
    """u8 length + UTF-8. Longer than 255 bytes: ValueError, or cut at a character boundary if clip."""
    data = text.encode("utf-8")
    if len(data) > 255:
        if not clip:
            raise ValueError(f"{what} is {len(data)} bytes in UTF-8, at most 255")
        data = data[:255].decode("utf-8", errors="ignore").encode("utf-8")
    return bytes([len(data)]) + data


def _unpack_str(payload: bytes, offset: int, what: str) -> tuple[str, int]:
    _need(payload, offset + 1, what)
    n = payload[offset]
    _need(payload, offset + 1 + n, what)
    try:
        return bytes(payload[offset + 1 : offset + 1 + n]).decode("utf-8"), offset + 1 + n
    except UnicodeDecodeError as exc:
        raise MessageError("utf8", f"{what}: {exc}") from None


def _finite(value: float, what: str) -> None:
    if not np.isfinite(value):
        raise MessageError("value", f"{what} is {value}")


# --- request ids (protocol minor 2) -----------------------------------------------------------
# A request of minor >= 2 ends with a u16 request_id (1..65535) that its reply echoes; 0 means
# "no id" and is not sent, so a request of an older host and its reply keep their old bytes.
_ID = struct.Struct("<H")


def _pack_id(request_id: int) -> bytes:
    return _ID.pack(request_id) if request_id else b""


def _unpack_id(payload: bytes, offset: int) -> int:
    """The request id at ``offset`` if the payload carries one, else 0 (a sender of minor < 2)."""
    if len(payload) >= offset + _ID.size:
        return _ID.unpack_from(payload, offset)[0]
    return 0


def angles_crc(angles: np.ndarray) -> int:
    """CRC-32 (as the frame CRC) of the angles as little-endian f32: names one scan geometry."""
    return zlib.crc32(np.ascontiguousarray(angles, dtype="<f4").tobytes())


# --- messages ---------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class GetInfo:
    """Host -> device. Carries the host's protocol version so the device can log a mismatch."""

    TYPE = MsgType.GET_INFO
    _S = struct.Struct("<BB")
    host_major: int = PROTOCOL_VERSION
    host_minor: int = PROTOCOL_MINOR
    request_id: int = 0  # minor 2

    def encode(self) -> bytes:
        return self._S.pack(self.host_major, self.host_minor) + _pack_id(self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> GetInfo:
        _need(payload, cls._S.size, "GET_INFO")
        return cls(*cls._S.unpack_from(payload), _unpack_id(payload, cls._S.size))


@dataclass(frozen=True, slots=True)
class ScanSettings:
    """What `set config` can change. None = leave as is (only in a SET_CONFIG request).

    roi_first / roi_count select the columns (indices into Info.angles) a scan carries;
    median_window is the odd length of the range median filter (1 = off); min_quality drops
    returns below this quality (they become NaN; +inf and -inf, which have no line, stay); laser_power_mw is the peak optical power;
    ray_times (protocol minor 4) makes every SCAN carry each ray's own time (SPEC.md "SCAN").

    Bit i of the block's mask is FIELDS[i]. The values of MINOR4_FIELDS are not in the block:
    they follow the message's other fields (encode_minor4), so that the block keeps its size.
    """

    scan_rate_hz: float | None = None
    exposure_us: int | None = None
    roi_first: int | None = None
    roi_count: int | None = None
    median_window: int | None = None
    min_quality: int | None = None
    laser_power_mw: float | None = None
    ray_times: bool | None = None  # minor 4

    _S: ClassVar = struct.Struct("<HfIHHBBf")
    _S4: ClassVar = struct.Struct("<B")  # ray_times: 0 off, 1 on
    FIELDS: ClassVar = ("scan_rate_hz", "exposure_us", "roi_first", "roi_count", "median_window", "min_quality",
                        "laser_power_mw", "ray_times")
    MINOR4_FIELDS: ClassVar = ("ray_times",)

    def encode(self) -> bytes:
        """The SETTINGS block (the values of MINOR4_FIELDS: encode_minor4)."""
        mask = 0
        values = []
        for bit, name in enumerate(self.FIELDS):
            v = getattr(self, name)
            mask |= (v is not None) << bit
            if name not in self.MINOR4_FIELDS:
                values.append(0 if v is None else v)
        return self._S.pack(mask, *values)

    def encode_minor4(self) -> bytes:
        """The values of the minor-4 fields that are set, to follow the message's other fields."""
        return b"" if self.ray_times is None else self._S4.pack(self.ray_times)

    @classmethod
    def decode(cls, payload: bytes, offset: int = 0, minor4_offset: int | None = None) -> ScanSettings:
        """The block at ``offset``, and the minor-4 values its mask announces at ``minor4_offset``
        (default: right after the block)."""
        minor4_offset = offset + cls._S.size if minor4_offset is None else minor4_offset
        _need(payload, offset + cls._S.size, "settings")
        mask, *values = cls._S.unpack_from(payload, offset)
        if mask >> len(cls.FIELDS):
            raise MessageError("value", f"settings mask 0x{mask:04x} has unknown bits")
        kw = {name: v for bit, (name, v) in enumerate(zip(cls.FIELDS, values)) if mask >> bit & 1}
        for name in ("scan_rate_hz", "laser_power_mw"):
            if name in kw:
                _finite(kw[name], name)
        if mask >> cls.FIELDS.index("ray_times") & 1:
            _need(payload, minor4_offset + cls._S4.size, "settings ray_times (protocol minor 4)")
            (v,) = cls._S4.unpack_from(payload, minor4_offset)
            if v > 1:
                raise MessageError("value", f"settings ray_times {v} is neither 0 (off) nor 1 (on)")
            kw["ray_times"] = bool(v)
        return cls(**kw)

    def merged(self, update: ScanSettings) -> ScanSettings:
        """These settings with every non-None field of ``update`` applied."""
        return ScanSettings(**{n: getattr(self, n) if getattr(update, n) is None else getattr(update, n) for n in self.FIELDS})

    def as_dict(self) -> dict:
        return {n: getattr(self, n) for n in self.FIELDS if getattr(self, n) is not None}

    def for_host(self, host_minor: int) -> ScanSettings:
        """These settings as a host of ``host_minor`` can read them in INFO: without the
        minor-4 fields for an older host (it would refuse their mask bits)."""
        return self if host_minor >= 4 else replace(self, **{n: None for n in self.MINOR4_FIELDS})


SETTINGS_SIZE = ScanSettings._S.size


@dataclass(frozen=True, slots=True, eq=False)
class Info:
    """Device -> host: who the device is and the geometry every scan refers to.

    ``angles`` (float32, rad, counter-clockwise from +x, REP 103) gives the bearing of every
    column a scan can carry; a scan's points are ``angles[first_index : first_index + n]``.

    Fields of protocol minor 2 (None from an older device; all present or all None):
    request_id echoes the GET_INFO's; boot_id is drawn at random when the device process
    starts (a new one = the device restarted); n_columns and angles_crc name the geometry - a
    device answers a host of minor >= 2 with ``angles`` empty, and the host fetches them with
    GET_ANGLES in frames smaller than a scan; startup_s is the longest the device takes from START
    to its first scan; host_timeout_s is how long the device keeps scanning without hearing from
    the host (0: forever).

    ``settings.ray_times`` (minor 4) follows the fields of minor 2; a device sets it only in an
    INFO for a host of minor >= 4 (an older host would refuse the settings' mask bit).
    """

    TYPE = MsgType.INFO
    _S = struct.Struct("<BBfffH")
    _S2: ClassVar = struct.Struct("<HIHIff")
    protocol_major: int
    protocol_minor: int
    software_version: str
    serial_number: str
    scan_rate_hz: float
    range_min_m: float
    range_max_m: float
    angles: np.ndarray
    settings: ScanSettings
    laser_limit_mw: float  # the Class 1 limit the device enforces on laser_power_mw
    # protocol minor 2
    request_id: int | None = None
    boot_id: int | None = None
    n_columns: int | None = None
    angles_crc: int | None = None
    startup_s: float | None = None
    host_timeout_s: float | None = None

    MINOR2_FIELDS: ClassVar = ("request_id", "boot_id", "n_columns", "angles_crc", "startup_s", "host_timeout_s")

    def encode(self) -> bytes:
        angles = np.ascontiguousarray(self.angles, dtype="<f4")
        head = self._S.pack(self.protocol_major, self.protocol_minor, self.scan_rate_hz,
                            self.range_min_m, self.range_max_m, angles.size)
        body = (head + _pack_str(self.software_version, "software_version")
                + _pack_str(self.serial_number, "serial_number") + angles.tobytes()
                + self.settings.encode() + struct.pack("<f", self.laser_limit_mw))
        minor2, minor4 = _pack_group(self, self.MINOR2_FIELDS, self._S2, "INFO", 2), self.settings.encode_minor4()
        if minor4 and not minor2:
            raise ValueError("INFO settings of protocol minor 4 need the fields of minor 2 before them")
        return body + minor2 + minor4

    @property
    def complete(self) -> bool:
        """Whether ``angles`` holds the whole geometry (False: fetch it with GET_ANGLES)."""
        return self.n_columns is None or self.angles.size == self.n_columns

    @classmethod
    def decode(cls, payload: bytes) -> Info:
        _need(payload, cls._S.size, "INFO")
        major, minor, rate, rmin, rmax, n = cls._S.unpack_from(payload)
        sw, off = _unpack_str(payload, cls._S.size, "software_version")
        serial, off = _unpack_str(payload, off, "serial_number")
        _need(payload, off + 4 * n + SETTINGS_SIZE + 4, "INFO angles and settings")
        angles = np.frombuffer(payload, dtype="<f4", count=n, offset=off).astype(np.float32)
        off += 4 * n
        settings = ScanSettings.decode(payload, off, off + SETTINGS_SIZE + 4 + cls._S2.size)
        (limit,) = struct.unpack_from("<f", payload, off + SETTINGS_SIZE)
        minor2 = _unpack_group(payload, off + SETTINGS_SIZE + 4, cls._S2, "INFO fields of protocol minor 2",
                               len(cls.MINOR2_FIELDS))
        for name, v in (("scan_rate_hz", rate), ("range_min_m", rmin), ("range_max_m", rmax)):
            _finite(v, name)
        if not np.isfinite(angles).all():
            raise MessageError("value", "INFO angles contain NaN or inf")
        if not 0 <= rmin < rmax:
            raise MessageError("value", f"range limits [{rmin}, {rmax}] m are not increasing")
        if not rate > 0:
            raise MessageError("value", f"scan_rate_hz {rate} is not positive")
        info = cls(major, minor, sw, serial, rate, rmin, rmax, angles, settings, limit, *minor2)
        if info.n_columns is not None:
            if info.n_columns < 1 or n not in (0, info.n_columns):
                raise MessageError("value", f"INFO carries {n} angles of n_columns {info.n_columns}")
            if n and angles_crc(angles) != info.angles_crc:
                raise MessageError("value", "INFO angles do not match their angles_crc")
            for name in ("startup_s", "host_timeout_s"):
                v = getattr(info, name)
                if not (np.isfinite(v) and v >= 0):
                    raise MessageError("value", f"{name} {v} is not a finite non-negative time")
        return info


def _pack_group(msg, fields: tuple, layout: struct.Struct, what: str, minor: int) -> bytes:
    """The fields appended in one protocol minor: all None -> nothing (an older device's
    message), all set -> packed; a mix is a bug of the sender."""
    values = [getattr(msg, n) for n in fields]
    if all(v is None for v in values):
        return b""
    missing = [n for n, v in zip(fields, values) if v is None]
    if missing:
        raise ValueError(f"{what} fields of protocol minor {minor} are all set or all None; missing {missing}")
    return layout.pack(*values)


def _unpack_group(payload: bytes, offset: int, layout: struct.Struct, what: str, count: int) -> tuple:
    """The values of a group appended in a later minor, or Nones if the payload ends before it."""
    if len(payload) <= offset:
        return (None,) * count
    _need(payload, offset + layout.size, what)
    return layout.unpack_from(payload, offset)


@dataclass(frozen=True, slots=True)
class GetHealth:
    TYPE = MsgType.GET_HEALTH
    request_id: int = 0  # minor 2

    def encode(self) -> bytes:
        return _pack_id(self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> GetHealth:
        return cls(_unpack_id(payload, 0))


@dataclass(frozen=True, slots=True)
class Health:
    """Device -> host. Counters are totals since the device process started (u32, wrap).

    The counters after ``errors`` were appended in protocol minor 1; they are None when the
    device speaks minor 0 (its payload ends after ``errors``) and encode to nothing when None.
    The fields of minor 2 (request_id, boot_id, host_timeouts) follow them likewise.
    """

    TYPE = MsgType.HEALTH
    _S = struct.Struct("<BBBxIIIQH")
    _S1: ClassVar = struct.Struct("<7I")
    _S2: ClassVar = struct.Struct("<HII")
    MINOR2_FIELDS: ClassVar = ("request_id", "boot_id", "host_timeouts")
    MINOR1_FIELDS: ClassVar = ("camera_restarts", "comcu_resets", "comcu_lost", "pipeline_errors",
                               "host_bytes_discarded", "host_frames_rejected", "host_sessions")
    state: DeviceState
    laser_on: bool
    sync_locked: bool
    frames_dropped: int  # camera frames the pipeline lost
    scans_dropped: int  # whole scans dropped because the link queue was full
    scans_sent: int
    device_time_us: int  # the device clock when the health was sampled
    errors: tuple[int, ...] = ()  # ErrorCode values active now
    # protocol minor 1
    camera_restarts: int | None = None  # camera restarted after a stall or an error
    comcu_resets: int | None = None  # the co-MCU rebooted (it announced a new boot)
    comcu_lost: int | None = None  # the co-MCU stopped answering
    pipeline_errors: int | None = None  # frame pairs the image pipeline raised on (scan skipped)
    host_bytes_discarded: int | None = None  # bytes from the host outside intact frames (garbage, CRC, decode)
    host_frames_rejected: int | None = None  # frames from the host dropped for CRC, decode or size errors
    host_sessions: int | None = None  # times the host link was opened (reopened after a port failure)
    # protocol minor 2
    request_id: int | None = None  # the GET_HEALTH's request id
    boot_id: int | None = None  # drawn at random when the device process started
    host_timeouts: int | None = None  # times scanning stopped because the host was silent for host_timeout_s

    def encode(self) -> bytes:
        head = self._S.pack(int(self.state), self.laser_on, self.sync_locked, self.frames_dropped & 0xFFFFFFFF,
                            self.scans_dropped & 0xFFFFFFFF, self.scans_sent & 0xFFFFFFFF,
                            self.device_time_us, len(self.errors)) + struct.pack(f"<{len(self.errors)}H", *self.errors)
        counters = [getattr(self, n) for n in self.MINOR1_FIELDS]
        minor2 = _pack_group(self, self.MINOR2_FIELDS, self._S2, "HEALTH", 2)
        if all(v is None for v in counters) and not minor2:
            return head
        missing = [n for n, v in zip(self.MINOR1_FIELDS, counters) if v is None]
        if missing:
            raise ValueError(f"HEALTH counters of protocol minor 1 are all set or all None; missing {missing}")
        return head + self._S1.pack(*(v & 0xFFFFFFFF for v in counters)) + minor2

    @classmethod
    def decode(cls, payload: bytes) -> Health:
        _need(payload, cls._S.size, "HEALTH")
        state, laser, sync, fd, sd, ss, t, n = cls._S.unpack_from(payload)
        off = cls._S.size + 2 * n
        _need(payload, off, "HEALTH errors")
        try:
            state = DeviceState(state)
        except ValueError:
            raise MessageError("value", f"unknown device state {state}") from None
        errors = struct.unpack_from(f"<{n}H", payload, cls._S.size)
        counters = _unpack_group(payload, off, cls._S1, "HEALTH counters (protocol minor 1)", len(cls.MINOR1_FIELDS))
        minor2 = _unpack_group(payload, off + cls._S1.size, cls._S2, "HEALTH fields of protocol minor 2",
                               len(cls.MINOR2_FIELDS))
        return cls(state, bool(laser), bool(sync), fd, sd, ss, t, tuple(errors), *counters, *minor2)


@dataclass(frozen=True, slots=True)
class Start:
    TYPE = MsgType.START
    request_id: int = 0  # minor 2

    def encode(self) -> bytes:
        return _pack_id(self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> Start:
        return cls(_unpack_id(payload, 0))


@dataclass(frozen=True, slots=True)
class Stop:
    TYPE = MsgType.STOP
    request_id: int = 0  # minor 2

    def encode(self) -> bytes:
        return _pack_id(self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> Stop:
        return cls(_unpack_id(payload, 0))


@dataclass(frozen=True, slots=True)
class SetConfig:
    """Host -> device. A device of minor >= 2 applies a SET_CONFIG repeated with the same
    request_id and settings once and answers the repeat as it answered the first. The settings'
    minor-4 values follow the request id."""

    TYPE = MsgType.SET_CONFIG
    settings: ScanSettings
    request_id: int = 0  # minor 2

    def encode(self) -> bytes:
        minor4 = self.settings.encode_minor4()  # after the request id, which is then always sent
        return self.settings.encode() + (_ID.pack(self.request_id) if minor4 else _pack_id(self.request_id)) + minor4

    @classmethod
    def decode(cls, payload: bytes) -> SetConfig:
        return cls(ScanSettings.decode(payload, 0, SETTINGS_SIZE + _ID.size), _unpack_id(payload, SETTINGS_SIZE))


@dataclass(frozen=True, slots=True)
class GetAngles:
    """Host -> device (minor 2): columns first .. first + count - 1 of the scan geometry."""

    TYPE = MsgType.GET_ANGLES
    first: int
    count: int
    request_id: int = 0
    _S: ClassVar = struct.Struct("<HHH")  # first, count, request_id

    def encode(self) -> bytes:
        return self._S.pack(self.first, self.count, self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> GetAngles:
        _need(payload, cls._S.size, "GET_ANGLES")
        return cls(*cls._S.unpack_from(payload))


#: The most angles one ANGLES frame carries: 1 KiB of f32, a fifth of a full scan's frame, so
#: the geometry gets through wherever scans do (SPEC.md "ANGLES").
ANGLES_PER_FRAME = 256


@dataclass(frozen=True, slots=True, eq=False)
class Angles:
    """Device -> host (minor 2): a chunk of the scan geometry, for the GET_ANGLES request_id.

    boot_id, angles_crc and n_columns are those of the INFO the chunk belongs to; ``angles``
    (float32) are columns first .. first + angles.size - 1.
    """

    TYPE = MsgType.ANGLES
    _S = struct.Struct("<HIIHHH")
    request_id: int
    boot_id: int
    angles_crc: int
    n_columns: int
    first: int
    angles: np.ndarray

    def encode(self) -> bytes:
        a = np.ascontiguousarray(self.angles, dtype="<f4")
        return self._S.pack(self.request_id, self.boot_id, self.angles_crc, self.n_columns, self.first, a.size) + a.tobytes()

    @classmethod
    def decode(cls, payload: bytes) -> Angles:
        _need(payload, cls._S.size, "ANGLES")
        rid, boot, crc, total, first, n = cls._S.unpack_from(payload)
        _need(payload, cls._S.size + 4 * n, f"ANGLES of {n} columns")
        if n == 0 or first + n > total:
            raise MessageError("value", f"ANGLES columns [{first}, {first + n}) not inside [0, {total})")
        angles = np.frombuffer(payload, dtype="<f4", count=n, offset=cls._S.size).astype(np.float32)
        if not np.isfinite(angles).all():
            raise MessageError("value", "ANGLES contain NaN or inf")
        return cls(rid, boot, crc, total, first, angles)


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """Host -> device (minor 2), no reply: the host is still listening (SPEC.md "Host liveness")."""

    TYPE = MsgType.HEARTBEAT

    def encode(self) -> bytes:
        return b""

    @classmethod
    def decode(cls, payload: bytes) -> Heartbeat:
        return cls()


@dataclass(frozen=True, slots=True)
class Ack:
    """Device -> host: the request (type, frame sequence number) was carried out."""

    TYPE = MsgType.ACK
    _S = struct.Struct("<BH")
    request_type: int
    request_seq: int
    request_id: int = 0  # minor 2: the request's id (0: it carried none)

    def encode(self) -> bytes:
        return self._S.pack(self.request_type, self.request_seq) + _pack_id(self.request_id)

    @classmethod
    def decode(cls, payload: bytes) -> Ack:
        _need(payload, cls._S.size, "ACK")
        return cls(*cls._S.unpack_from(payload), _unpack_id(payload, cls._S.size))


@dataclass(frozen=True, slots=True)
class Nack:
    """Device -> host: the request was refused; nothing of it was applied."""

    TYPE = MsgType.NACK
    _S = struct.Struct("<BHB")
    request_type: int
    request_seq: int
    code: NackCode
    reason: str
    request_id: int = 0  # minor 2: the request's id (0: it carried none)

    def encode(self) -> bytes:
        return (self._S.pack(self.request_type, self.request_seq, int(self.code))
                + _pack_str(self.reason, "reason", clip=True) + _pack_id(self.request_id))

    @classmethod
    def decode(cls, payload: bytes) -> Nack:
        _need(payload, cls._S.size, "NACK")
        rtype, rseq, code = cls._S.unpack_from(payload)
        reason, off = _unpack_str(payload, cls._S.size, "reason")
        try:
            code = NackCode(code)
        except ValueError:
            raise MessageError("value", f"unknown NACK code {code}") from None
        return cls(rtype, rseq, code, reason, _unpack_id(payload, off))


@dataclass(frozen=True, slots=True)
class Log:
    """Device -> host: an event for the host's log. ``level`` uses the logging module's numbers."""

    TYPE = MsgType.LOG
    _S = struct.Struct("<BQ")
    level: int
    device_time_us: int
    text: str

    def encode(self) -> bytes:
        return self._S.pack(self.level, self.device_time_us) + _pack_str(self.text, "text", clip=True)

    @classmethod
    def decode(cls, payload: bytes) -> Log:
        _need(payload, cls._S.size, "LOG")
        level, t = cls._S.unpack_from(payload)
        text, _ = _unpack_str(payload, cls._S.size, "text")
        return cls(level, t, text)


@dataclass(frozen=True, slots=True, eq=False)
class ScanMessage:
    """Device -> host: one scan, 20-byte header then ``n`` u16 range codes then ``n`` u8 qualities.

    device_time_us: device clock (µs, monotonic) when the first ray was exposed.
    ray_interval_ns: time from one ray (column) to the next; negative (minor 3) when the rays were
    measured latest first. A device sends a negative one only to a host of minor >= 3
    (:func:`scan_time_for_host`); it is read as signed from every device: one of minor < 3 never
    sent 2**31 ns (2.1 s) or more per ray.
    age_us: time from the first ray to the moment the device started sending this frame; the host
    uses it with the frame's arrival time to stamp the scan (host_sdk/scan.py).
    ranges_m (float32, REP 117) and quality (uint8) are per point, for columns
    ``first_index .. first_index + n - 1`` of Info.angles.
    boot_id (minor 2, after the qualities; None from an older device): the device process's
    boot id, as in INFO and HEALTH.
    ray_times_us (minor 4, after the boot id; None when the host did not ask for them, settings
    ``ray_times``): float64 (n,), the device clock (µs) at which each ray was measured, NaN for a
    ray without a measured time (its time is the line's, ``device_time_us + i ray_interval_ns``).
    On the wire: a base time and u16 µs after it per ray (SPEC.md "SCAN"), whole µs.
    """

    TYPE = MsgType.SCAN
    scan_seq: int
    device_time_us: int
    ray_interval_ns: int
    age_us: int
    first_index: int
    ranges_m: np.ndarray
    quality: np.ndarray
    boot_id: int | None = None
    ray_times_us: np.ndarray | None = None

    def encode(self) -> bytes:
        quality = np.asarray(self.quality)
        codes = encode_ranges(self.ranges_m)
        if quality.shape != codes.shape or quality.dtype != np.uint8:
            raise ValueError(f"quality must be uint8 of shape {codes.shape}, got {quality.dtype} {quality.shape}")
        if not -2**31 <= self.ray_interval_ns < 2**31:
            raise ValueError(f"ray_interval_ns {self.ray_interval_ns} does not fit SCAN's i32 field")
        head = _SCAN_HEAD.pack(self.scan_seq & 0xFFFFFFFF, self.device_time_us, self.ray_interval_ns,
                               min(self.age_us, 0xFFFFFFFF), self.first_index, codes.size)
        boot = b"" if self.boot_id is None else _SCAN_BOOT.pack(self.boot_id)
        times = b""
        if self.ray_times_us is not None:
            if self.boot_id is None:
                raise ValueError("SCAN ray times (protocol minor 4) need the boot id (minor 2) before them")
            times = _ray_time_block(self.device_time_us, self.ray_times_us, codes.size)
        return head + codes.tobytes() + quality.tobytes() + boot + times

    @classmethod
    def decode(cls, payload: bytes) -> ScanMessage:
        _need(payload, _SCAN_HEAD.size, "SCAN header")
        seq, t, dt, age, first, n = _SCAN_HEAD.unpack_from(payload)
        end = _SCAN_HEAD.size + 3 * n
        _need(payload, end, f"SCAN of {n} points")
        codes = np.frombuffer(payload, dtype="<u2", count=n, offset=_SCAN_HEAD.size)
        quality = np.frombuffer(payload, dtype=np.uint8, count=n, offset=_SCAN_HEAD.size + 2 * n)
        (boot,) = _unpack_group(payload, end, _SCAN_BOOT, "SCAN boot_id (protocol minor 2)", 1)
        times = _unpack_ray_times(payload, end + _SCAN_BOOT.size, t, n) if boot is not None else None
        return cls(seq, t, dt, age, first, decode_ranges(codes), quality.copy(), boot, times)


_SCAN_HEAD = struct.Struct("<IQiIHH")  # scan_seq, device_time_us, ray_interval_ns (signed: minor 3), age_us, first_index, n
_SCAN_BOOT = struct.Struct("<I")  # boot_id after the qualities (minor 2)
SCAN_HEADER_SIZE = _SCAN_HEAD.size  # 24
_SCAN_TIMES = struct.Struct("<Hi")  # minor 4, after boot_id: count (n, or 0: none), base - device_time_us (µs)
SCAN_TIMES_HEADER_SIZE = _SCAN_TIMES.size  # 6
BYTES_PER_RAY_TIME = 2
#: A ray's offset that means "no measured time": the ray's time is the line's.
RAY_TIME_NONE = 0xFFFF
#: Offsets are at most this many µs after the block's base. A scan's rays are measured in one
#: camera frame, within its readout: rows x line time, at most 2464 x 18.9 µs = 46.6 ms for the
#: IMX219's largest mode (device/camera/modes.py, from the kernel's imx219.c); a larger offset
#: lies outside any frame.
RAY_TIME_SPAN_MAX_US = 65_000


def _ray_time_block(device_time_us: int, times_us: np.ndarray, n: int) -> bytes:
    """The minor-4 block of ``times_us`` (device µs per ray, NaN: none): base = the earliest
    time (whole µs), each ray rounded to the µs after it. ValueError for times that do not fit."""
    t = np.asarray(times_us, dtype=np.float64)
    if t.shape != (n,) or np.isinf(t).any():
        raise ValueError(f"ray_times_us must be {n} finite times or NaN, got shape {t.shape}")
    ok = ~np.isnan(t)
    base = int(np.floor(t[ok].min())) if ok.any() else device_time_us
    offsets = np.full(n, RAY_TIME_NONE, dtype="<u2")
    rel = np.rint(t[ok] - base)
    if rel.size and rel.max() > RAY_TIME_SPAN_MAX_US:
        raise ValueError(f"ray times span {rel.max():.0f} µs, more than one frame's readout a SCAN carries "
                         f"({RAY_TIME_SPAN_MAX_US} µs)")
    offsets[ok] = rel
    if not -2**31 <= base - device_time_us < 2**31:
        raise ValueError(f"ray times start {base - device_time_us} µs from device_time_us: beyond SCAN's i32 field")
    return _SCAN_TIMES.pack(n, base - device_time_us) + offsets.tobytes()


def _unpack_ray_times(payload: bytes, offset: int, device_time_us: int, n: int) -> np.ndarray | None:
    """The minor-4 block at ``offset`` as device µs per ray (NaN: none), or None if the payload
    ends before it or it is empty (count 0); MessageError for a block that lies."""
    if len(payload) <= offset:
        return None
    _need(payload, offset + _SCAN_TIMES.size, "SCAN ray time block (protocol minor 4)")
    count, base = _SCAN_TIMES.unpack_from(payload, offset)
    if count == 0:
        return None
    if device_time_us + base < 0:
        raise MessageError("value", f"SCAN ray time block's base_us {base} puts its rays before device time 0 "
                                    f"(device_time_us {device_time_us})")
    if count != n:
        raise MessageError("value", f"SCAN ray time block has {count} times for {n} rays")
    _need(payload, offset + _SCAN_TIMES.size + BYTES_PER_RAY_TIME * n, f"SCAN ray time block of {n} rays")
    offsets = np.frombuffer(payload, dtype="<u2", count=n, offset=offset + _SCAN_TIMES.size)
    none = offsets == RAY_TIME_NONE
    outside = np.flatnonzero(~none & (offsets > RAY_TIME_SPAN_MAX_US))
    if outside.size:
        i = int(outside[0])
        raise MessageError("value", f"SCAN ray {i}'s time {int(offsets[i])} µs after the block's base lies outside "
                                    f"one frame's readout ({RAY_TIME_SPAN_MAX_US} µs); {outside.size} rays so")
    return np.where(none, np.nan, float(device_time_us + base) + offsets)


def scan_time_for_host(device_time_us: int, ray_interval_ns: int, n: int, host_minor: int) -> tuple[int, int]:
    """(device_time_us, ray_interval_ns) of an n-ray scan as a host of ``host_minor`` can read
    them: a host of minor < 3 reads the interval unsigned, so a negative one goes to it as the
    scan's middle time and no step (SPEC.md, SCAN)."""
    if ray_interval_ns >= 0 or host_minor >= 3:
        return device_time_us, ray_interval_ns
    return device_time_us + (n - 1) * ray_interval_ns // 2000, 0


SCAN_TRAILER_SIZE = _SCAN_BOOT.size  # 4
BYTES_PER_POINT = 3

MESSAGES: dict[int, type] = {cls.TYPE: cls for cls in (
    GetInfo, Info, GetHealth, Health, Start, Stop, SetConfig, Ack, Nack, GetAngles, Angles, Heartbeat,
    ScanMessage, Log)}


def decode_message(msg_type: int, payload: bytes):
    """Decode the payload of a frame of ``msg_type``; MessageError if unknown or malformed."""
    cls = MESSAGES.get(msg_type)
    if cls is None:
        raise MessageError("type", f"unknown message type 0x{msg_type:02x}")
    try:
        return cls.decode(payload)
    except struct.error as exc:  # defensive: every decode checks sizes first
        raise MessageError("short", f"{cls.__name__}: {exc}") from None


# --- wire budget ------------------------------------------------------------------------------
#: A UART at 8N1 sends 10 bits per byte (start, 8 data, stop).
UART_BITS_PER_BYTE = 10


def scan_wire_bytes(n_points: int, ray_times: bool = False) -> int:
    """Bytes on the wire for one scan frame of n_points from a device of minor >= 2: payload (with
    its boot id, and with ``ray_times`` the time block of minor 4), frame header and CRC, COBS
    overhead (at most one byte per 254) and the delimiter."""
    body = SCAN_HEADER_SIZE + BYTES_PER_POINT * n_points + SCAN_TRAILER_SIZE + OVERHEAD
    if ray_times:
        body += SCAN_TIMES_HEADER_SIZE + BYTES_PER_RAY_TIME * n_points
    return body + body // 254 + 1 + 1


def link_budget_refusal(n_points: int, scan_rate_hz: float, link_rate_bps: float | None,
                        ray_times: bool = False) -> str | None:
    """Why scans of ``n_points`` (with their ray times if ``ray_times``) at ``scan_rate_hz`` do
    not fit a host link of ``link_rate_bps`` bits/s, counted as a UART at 8N1
    (UART_BITS_PER_BYTE), or None if they fit (or the link is not limited: None). SPEC.md
    section 5 has the table."""
    if link_rate_bps is None:
        return None
    per_scan = scan_wire_bytes(n_points, ray_times)
    need_bps = per_scan * scan_rate_hz * UART_BITS_PER_BYTE
    if need_bps <= link_rate_bps:
        return None
    per_scan_bytes = link_rate_bps / (scan_rate_hz * UART_BITS_PER_BYTE)
    points = max((k for k in range(n_points) if scan_wire_bytes(k, ray_times) <= per_scan_bytes), default=0)
    what = " with ray times (ray_times)" if ray_times else ""
    off = ", ray_times off" if ray_times and link_budget_refusal(n_points, scan_rate_hz, link_rate_bps) is None else ""
    return (f"{n_points} points{what} at {scan_rate_hz:g} scans/s need {need_bps / 1e3:.1f} kbit/s on the host link "
            f"({per_scan} bytes per scan, 8N1), more than its {link_rate_bps / 1e3:.1f} kbit/s: "
            f"use at most {points} points (a narrower field of view), at most "
            f"{math.floor(100 * link_rate_bps / (per_scan * UART_BITS_PER_BYTE)) / 100:.2f} scans/s{off}, "
            "or USB")  # (rounded down: the advice must fit)
