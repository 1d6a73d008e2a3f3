"""Device end of the host link: answer host commands and stream scans from a scan source.

The same server runs the mock device (protocol/mock_wall.py behind ``sim://`` or
``laserpi serve --simulate --mock``) and the real device process (the image pipeline as the
source). It is in protocol/ because both ends use it: the host SDK's ``sim://`` runs it in
process, so it imports nothing but protocol/ (and needs no OpenCV).

Scan-source interface (ScanSource, below): six small methods. ``next_scan(timeout_s)`` blocks
until the source has a scan or the timeout passes; the server calls it only while scanning. All
times are the device clock: ``device_clock_us()`` = CLOCK_MONOTONIC in microseconds.

Threads (all owned by LinkServer, stopped by ``close()``):
  reader  reads host bytes, decodes frames (protocol/stream.py), handles each request and puts
          the reply on the control queue;
  scanner pulls scans from the source while scanning and puts them on the scan queue, which is
          bounded (``DeviceConfig.queue_scans``): when it is full the oldest queued scan is
          dropped whole and counted (HEALTH.scans_dropped) - a slow link never gets half scans
          and never grows memory;
  writer  sends control replies first, then scans, one whole frame at a time.
Every reply is preceded by one extra 0x00 (idle fill) so that a host that just opened the port
and discards its partial first frame does not lose the reply.

Replies echo the request's id (protocol minor 2); a SET_CONFIG repeated with the id and settings
of the last one is not applied again but answered as before, so a host may retry it. Scans,
INFO and HEALTH carry the device's boot id (DeviceConfig.boot_id, one per device process).
Each ray's own time (settings ``ray_times``, protocol minor 4) is sent only to a host that said
minor >= 4 in its GET_INFO; from any other host a SET_CONFIG turning it on is refused.
Host liveness: while scanning, if no intact frame came from the host for
``DeviceConfig.host_timeout_s``, the server stops the source (laser off) and the stream, counts
it (HEALTH.host_timeouts) and says so in a LOG message (SPEC.md "Host liveness").
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from protocol import messages as m
from protocol.framing import PROTOCOL_VERSION, encode_frame
from protocol.stream import LinkStats, StreamDecoder

log = logging.getLogger(__name__)


def device_clock_us() -> int:
    """The device clock every device_time_us refers to: CLOCK_MONOTONIC in microseconds."""
    return time.monotonic_ns() // 1000


# --- scan-source interface ---------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ScanGeometry:
    """What the source can see: the bearing of every column and the range limits.

    angles: float32 (n,), rad, counter-clockwise from +x (REP 103); column i of a scan with
    first_index f is at angles[f + i].
    """

    angles: np.ndarray
    range_min_m: float
    range_max_m: float

    def __post_init__(self):
        a = np.asarray(self.angles)
        if a.ndim != 1 or a.size == 0 or not np.isfinite(a).all():
            raise ValueError(f"angles must be a finite non-empty 1-D array, got shape {a.shape}")
        if not 0 <= self.range_min_m < self.range_max_m:
            raise ValueError(f"range limits [{self.range_min_m}, {self.range_max_m}] m are not increasing")


@dataclass(frozen=True, eq=False)
class SourceScan:
    """One scan as a source delivers it.

    device_time_us: device_clock_us() when the first ray (column first_index) was exposed.
    ranges_m: float32 (n,), REP 117 (NaN invalid, +inf no return, -inf too close).
    quality: uint8 (n,), 0 = no signal .. 255 = strongest.
    ray_interval_ns: time between consecutive rays (0 for a global exposure; negative when the
    rays were measured latest first).
    ray_times_ns: float64 (n,), device_clock_us() x 1000 at which each ray was measured, NaN for
    a ray without a measured time; None: the source does not time its rays one by one (each is
    on the line ``device_time_us + i ray_interval_ns``). Sent to a host that asked (ray_times).
    """

    device_time_us: int
    ranges_m: np.ndarray
    quality: np.ndarray
    first_index: int = 0
    ray_interval_ns: int = 0
    ray_times_ns: np.ndarray | None = None


@dataclass(frozen=True)
class SourceStatus:
    """What a source reports for HEALTH; counters are totals since it was made (fields of
    protocol.messages.Health of the same names)."""

    laser_on: bool = False
    sync_locked: bool = False
    frames_dropped: int = 0
    errors: tuple[int, ...] = ()  # protocol.messages.ErrorCode values active now
    camera_restarts: int = 0
    comcu_resets: int = 0
    comcu_lost: int = 0
    pipeline_errors: int = 0


class ScanSource(Protocol):
    """What the link server needs from whatever produces scans (the pipeline, a simulator).

    next_scan is called from the server's scanner thread, the other methods from its reader
    thread (one request at a time), so a source must tolerate that (a lock around its settings).
    """

    def geometry(self) -> ScanGeometry:
        """Bearings and range limits; constant while the server runs."""

    def apply(self, settings: m.ScanSettings) -> None:
        """Take all of ``settings`` (complete, already range-checked by the server) or none of
        them; raise ValueError with a reason to refuse."""

    def start(self) -> None:
        """Begin producing scans (laser on)."""

    def stop(self) -> None:
        """Stop producing scans (laser off)."""

    def next_scan(self, timeout_s: float) -> SourceScan | None:
        """The next scan, or None if none is ready within timeout_s."""

    def status(self) -> SourceStatus:
        """Laser, sync and error state for HEALTH."""


# --- device configuration and the settings check -----------------------------------------------
@dataclass(frozen=True)
class DeviceConfig:
    """Fixed facts about this device that the server enforces and reports.

    laser_limit_mw: the IEC 60825-1 Class 1 limit on peak laser power; any set-config above it
    is refused (NackCode.EYE_SAFETY). Passed in by whoever builds the device (the eye-safety
    model computes it), never chosen by the host. link_rate_bps: what the host link carries,
    bits/s (a UART's baud rate); settings whose scans need more are refused, also at power-on
    (messages.link_budget_refusal); None: not limited.
    """

    laser_limit_mw: float
    settings: m.ScanSettings  # settings at power-on; every field set
    software_version: str = "0.1.0"
    serial_number: str = "LP-SIM-0001"
    scan_rate_range_hz: tuple[float, float] = (1.0, 30.0)
    exposure_range_us: tuple[int, int] = (10, 50_000)
    max_median_window: int = 15
    queue_scans: int = 4  # bounded outgoing scan queue, in whole scans
    #: longest time from START to the first scan (camera start, laser lock); reported in INFO
    startup_s: float = 5.0
    #: stop scanning (laser off) when the host sent no intact frame for this long; 0: never
    #: (a one-way cable). SPEC.md "Host liveness".
    host_timeout_s: float = 5.0
    #: drawn at random once per device process; a host that sees another one knows the device restarted
    boot_id: int = field(default_factory=lambda: secrets.randbits(32))
    link_rate_bps: float | None = None

    def __post_init__(self):
        missing = [n for n in m.ScanSettings.FIELDS if getattr(self.settings, n) is None]
        if missing:
            raise ValueError(f"DeviceConfig.settings must set every field; missing {missing}")
        if self.queue_scans < 1:
            raise ValueError("queue_scans must be at least 1")
        # the eye-safety check compares with this limit: NaN would let every power through
        if not 0 < self.laser_limit_mw < float("inf"):
            raise ValueError(f"laser_limit_mw must be a finite power > 0 mW, got {self.laser_limit_mw}")
        for name in ("startup_s", "host_timeout_s"):
            v = getattr(self, name)
            if not (v >= 0 and v < float("inf")):
                raise ValueError(f"{name} must be a finite time >= 0 s, got {v}")
        refusal = m.link_budget_refusal(self.settings.roi_count, self.settings.scan_rate_hz, self.link_rate_bps,
                                        self.settings.ray_times)
        if refusal is not None:
            raise ValueError(f"the power-on settings do not fit the host link: {refusal}")


def settings_refusal(s: m.ScanSettings, config: DeviceConfig, n_columns: int) -> tuple[m.NackCode, str] | None:
    """Why the complete settings ``s`` cannot be applied, or None if they can."""
    lo, hi = config.scan_rate_range_hz
    if not lo <= s.scan_rate_hz <= hi:
        return m.NackCode.OUT_OF_RANGE, f"scan_rate_hz {s.scan_rate_hz:g} outside [{lo:g}, {hi:g}]"
    lo, hi = config.exposure_range_us
    if not lo <= s.exposure_us <= hi:
        return m.NackCode.OUT_OF_RANGE, f"exposure_us {s.exposure_us} outside [{lo}, {hi}]"
    # frame differencing takes a lit and an unlit frame per scan (docs/thesis-notes.md N10)
    frame_budget_us = 1e6 / (2 * s.scan_rate_hz)
    if s.exposure_us > frame_budget_us:
        return m.NackCode.OUT_OF_RANGE, (
            f"exposure_us {s.exposure_us} longer than a frame ({frame_budget_us:.0f} us at "
            f"{s.scan_rate_hz:g} Hz, two frames per scan)")
    if s.roi_count < 1 or s.roi_first + s.roi_count > n_columns:
        return m.NackCode.OUT_OF_RANGE, (
            f"region of interest columns [{s.roi_first}, {s.roi_first + s.roi_count}) not inside [0, {n_columns})")
    if s.median_window % 2 == 0 or not 1 <= s.median_window <= config.max_median_window:
        return m.NackCode.OUT_OF_RANGE, f"median_window {s.median_window} must be odd in [1, {config.max_median_window}]"
    if not s.laser_power_mw >= 0:
        return m.NackCode.OUT_OF_RANGE, f"laser_power_mw {s.laser_power_mw:g} is negative"
    if s.laser_power_mw > config.laser_limit_mw:
        return m.NackCode.EYE_SAFETY, (
            f"laser_power_mw {s.laser_power_mw:g} exceeds the Class 1 limit of {config.laser_limit_mw:g} mW")
    refusal = m.link_budget_refusal(s.roi_count, s.scan_rate_hz, config.link_rate_bps, s.ray_times)
    return None if refusal is None else (m.NackCode.OUT_OF_RANGE, refusal)


# --- the server -------------------------------------------------------------------------------
@dataclass
class LinkCounters:
    """Totals of the host link. One LinkServer counts into its own, or into one shared by the
    successive sessions of a device process (device.link.supervisor.LinkSupervisor), so that HEALTH
    reports totals since the process started."""

    scans_sent: int = 0
    scans_dropped: int = 0  # whole scans dropped because the outgoing queue was full
    requests: int = 0
    refused: int = 0  # requests answered with NACK
    source_failures: int = 0
    host_timeouts: int = 0  # scanning stopped because the host was silent for host_timeout_s
    sessions: int = 0  # link servers that counted here (the host port opened)
    host: LinkStats = field(default_factory=LinkStats)  # what the decoders made of the host's bytes

    @property
    def host_frames_rejected(self) -> int:
        """Frames from the host dropped for a CRC, decode or size error."""
        return self.host.crc_errors + self.host.decode_errors + self.host.oversize_frames


class LinkServer:
    """Serve one host over ``port`` (anything with read(size) -> bytes and write(data), where
    read returns what arrived, b"" after a short timeout) with scans from ``source``, counting
    into ``counters`` (a fresh LinkCounters if None)."""

    def __init__(self, port, source: ScanSource, config: DeviceConfig, counters: LinkCounters | None = None, *,
                 on_stop: Callable[[], None] | None = None):
        """on_stop: called when the threads are told to stop (the port failed, or ``close()``), from
        the thread that did so; it may be called more than once."""
        self.port = port
        self.source = source
        self.config = config
        self.geometry = source.geometry()
        self.settings = config.settings
        refusal = settings_refusal(self.settings, config, self.geometry.angles.size)
        if refusal:
            raise ValueError(f"DeviceConfig.settings refused: {refusal[1]}")
        source.apply(self.settings)
        self.counters = LinkCounters() if counters is None else counters
        self.counters.sessions += 1
        self.decoder = StreamDecoder(stats=self.counters.host)
        self._lock = threading.Condition()
        self._control: collections.deque = collections.deque()  # replies and LOG messages
        self._scans: collections.deque[m.ScanMessage] = collections.deque(maxlen=config.queue_scans)
        self._scanning = False
        self._fault: str | None = None
        self._seq = 0
        self._stop = threading.Event()
        self._on_stop = on_stop
        self._threads: list[threading.Thread] = []
        self._angles_crc = m.angles_crc(self.geometry.angles)
        self._last_config: tuple[int, m.ScanSettings, m.Ack | m.Nack] | None = None  # id, settings, answer
        self._heard_at = time.monotonic()  # the host's last intact frame
        self._host_minor = 0  # from its GET_INFO; until then, what every host reads
        self._requests = {m.GetInfo: self._info, m.GetHealth: self._reply_health, m.Start: self._start,
                          m.Stop: self._stop_request, m.SetConfig: self._configure, m.GetAngles: self._angles,
                          m.Heartbeat: lambda frame, msg: None}

    # lifecycle
    def start(self) -> LinkServer:
        for name, target in (("reader", self._read_loop), ("scanner", self._scan_loop), ("writer", self._write_loop)):
            t = threading.Thread(target=target, name=f"link-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def close(self) -> None:
        """Stop the threads and the source; safe to call twice."""
        self._end()
        with self._lock:
            self._lock.notify_all()
        for t in self._threads:
            t.join(timeout=2.0)
        if self._scanning:
            self.source.stop()
            self._scanning = False

    def serve(self, stop: threading.Event) -> None:
        """Run until ``stop`` is set or the port fails."""
        self.start()
        while not stop.wait(0.1) and not self._stop.is_set():
            pass
        self.close()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def _end(self) -> None:
        """Tell the threads to stop, and whoever waits for that (``on_stop``)."""
        self._stop.set()
        if self._on_stop is not None:
            self._on_stop()

    def __enter__(self) -> LinkServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # reader: requests
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.port.read(4096)
            except Exception as exc:  # any port failure ends the session, cleanly
                if not self._stop.is_set():
                    log.warning("link port read failed, stopping: %s", exc)
                self._end()
                break
            for rec in self.decoder.feed(data):
                self._heard_at = time.monotonic()
                self._handle(rec.frame)
            self._check_host_alive()

    def _check_host_alive(self) -> None:
        limit = self.config.host_timeout_s
        silent = time.monotonic() - self._heard_at
        if not limit or silent <= limit or not self._scanning:
            return
        with self._lock:
            if not self._scanning:
                return
            self._stop_scanning()
            self.counters.host_timeouts += 1
            self._control.append(m.Log(logging.WARNING, device_clock_us(),
                                       f"no frame from the host for {silent:.1f} s (host_timeout_s "
                                       f"{limit:g}): scanning stopped, laser off"))
            self._lock.notify_all()
        log.warning("host silent for %.1f s: scanning stopped, laser off", silent)

    def _handle(self, frame) -> None:
        self.counters.requests += 1
        try:
            msg = m.decode_message(frame.msg_type, frame.payload)
        except m.MessageError as exc:
            code = m.NackCode.UNKNOWN_MESSAGE if exc.reason == "type" else m.NackCode.BAD_PAYLOAD
            self._nack(frame, code, str(exc))
            return
        handler = self._requests.get(type(msg))
        if handler is None:
            self._nack(frame, m.NackCode.UNKNOWN_MESSAGE, f"{type(msg).__name__} is not a request",
                       getattr(msg, "request_id", 0))
            return
        handler(frame, msg)

    def _info(self, frame, msg: m.GetInfo) -> None:
        self._host_minor = msg.host_minor  # what it can read (SCAN's signed ray interval: minor 3; ray times: 4)
        if msg.host_major != PROTOCOL_VERSION:
            log.warning("host speaks protocol %d.%d, device %d", msg.host_major, msg.host_minor, PROTOCOL_VERSION)
        g = self.geometry
        # a host of minor >= 2 that numbers its requests fetches the angles in chunks (GET_ANGLES):
        # its INFO stays small; any other host gets them here, as before
        angles = g.angles[:0] if msg.host_minor >= 2 and msg.request_id else g.angles
        self._reply(m.Info(PROTOCOL_VERSION, m.PROTOCOL_MINOR, self.config.software_version,
                           self.config.serial_number, self.settings.scan_rate_hz, g.range_min_m, g.range_max_m,
                           angles, self.settings.for_host(msg.host_minor), self.config.laser_limit_mw, request_id=msg.request_id,
                           boot_id=self.config.boot_id, n_columns=g.angles.size, angles_crc=self._angles_crc,
                           startup_s=self.config.startup_s, host_timeout_s=self.config.host_timeout_s))

    def _angles(self, frame, msg: m.GetAngles) -> None:
        n = self.geometry.angles.size
        if not (msg.first < n and msg.count >= 1):
            self._nack(frame, m.NackCode.OUT_OF_RANGE, f"angles from column {msg.first} (count {msg.count}) "
                       f"not inside the {n} columns", msg.request_id)
            return
        last = min(n, msg.first + msg.count, msg.first + m.ANGLES_PER_FRAME)
        self._reply(m.Angles(msg.request_id, self.config.boot_id, self._angles_crc, n, msg.first,
                             self.geometry.angles[msg.first:last]))

    def _reply_health(self, frame, msg: m.GetHealth) -> None:
        self._reply(self._health(msg.request_id))

    def _health(self, request_id: int = 0) -> m.Health:
        st = self.source.status()
        errors = st.errors + ((m.ErrorCode.SOURCE_FAILED,) if self._fault else ())
        state = m.DeviceState.FAULT if self._fault else (m.DeviceState.SCANNING if self._scanning else m.DeviceState.IDLE)
        c = self.counters
        return m.Health(state, st.laser_on, st.sync_locked, st.frames_dropped, c.scans_dropped, c.scans_sent,
                        device_clock_us(), tuple(int(e) for e in errors), camera_restarts=st.camera_restarts,
                        comcu_resets=st.comcu_resets, comcu_lost=st.comcu_lost, pipeline_errors=st.pipeline_errors,
                        host_bytes_discarded=c.host.bytes_discarded, host_frames_rejected=c.host_frames_rejected,
                        host_sessions=c.sessions, request_id=request_id, boot_id=self.config.boot_id,
                        host_timeouts=c.host_timeouts)

    def _start(self, frame, msg: m.Start) -> None:
        with self._lock:
            if not self._scanning:
                try:
                    self.source.start()
                except Exception as exc:
                    self._nack(frame, m.NackCode.SOURCE_ERROR, f"source failed to start: {exc}", msg.request_id)
                    return
                self._fault = None
                self._scanning = True
                self._lock.notify_all()
        self._reply(m.Ack(frame.msg_type, frame.seq, msg.request_id))

    def _stop_request(self, frame, msg: m.Stop) -> None:
        self._stop_scanning()
        self._reply(m.Ack(frame.msg_type, frame.seq, msg.request_id))

    def _stop_scanning(self) -> None:
        with self._lock:
            if self._scanning:
                self._scanning = False
                self.source.stop()
            self._scans.clear()  # nothing of before the stop is sent after its ACK

    def _configure(self, frame, msg: m.SetConfig) -> None:
        last = self._last_config
        if msg.request_id and last is not None and last[:2] == (msg.request_id, msg.settings):
            # the host did not hear our answer and asked again: answer again, apply once
            self._reply(dataclasses.replace(last[2], request_seq=frame.seq))
            return
        new = self.settings.merged(msg.settings)
        if msg.settings.ray_times and self._host_minor < 4:
            refusal = (m.NackCode.NOT_SUPPORTED, f"ray_times needs a host of protocol minor >= 4, and this host's "
                       f"GET_INFO said minor {self._host_minor}: it could not read the ray times")
        else:
            if self._host_minor < 4:  # it cannot read them, nor turn them off: the budget without them
                new = dataclasses.replace(new, ray_times=False)
            refusal = settings_refusal(new, self.config, self.geometry.angles.size)
        if refusal is None:
            try:
                self.source.apply(new)
            except ValueError as exc:
                refusal = (m.NackCode.SOURCE_ERROR, f"source refused the settings: {exc}")
        if refusal:
            answer = self._nack(frame, *refusal, msg.request_id)
        else:
            self.settings = new
            answer = m.Ack(frame.msg_type, frame.seq, msg.request_id)
            self._reply(answer)
        self._last_config = (msg.request_id, msg.settings, answer)

    def _nack(self, frame, code: m.NackCode, reason: str, request_id: int = 0) -> m.Nack:
        log.info("refusing request 0x%02x: %s", frame.msg_type, reason)
        self.counters.refused += 1
        nack = m.Nack(frame.msg_type, frame.seq, code, reason, request_id)
        self._reply(nack)
        return nack

    def _reply(self, msg) -> None:
        with self._lock:
            self._control.append(msg)
            self._lock.notify_all()

    # scanner: source -> bounded queue
    def _scan_loop(self) -> None:
        seq = 0
        while not self._stop.is_set():
            with self._lock:
                if not self._scanning:
                    self._lock.wait(0.1)
                    continue
            try:
                scan = self.source.next_scan(0.1)
            except Exception as exc:
                self._source_failed(exc)
                continue
            if scan is None:
                continue
            t_us, interval = m.scan_time_for_host(scan.device_time_us, scan.ray_interval_ns, len(scan.ranges_m),
                                                  self._host_minor)
            msg = m.ScanMessage(seq, t_us, interval, 0, scan.first_index, scan.ranges_m, scan.quality,
                                self.config.boot_id, self._ray_times_us(scan))
            seq += 1
            with self._lock:
                if not self._scanning:
                    continue  # stopped while the source was working: discard, do not count
                if len(self._scans) == self._scans.maxlen:
                    self.counters.scans_dropped += 1
                self._scans.append(msg)  # deque(maxlen) drops the oldest whole scan
                self._lock.notify_all()

    def _ray_times_us(self, scan: SourceScan) -> np.ndarray | None:
        """The scan's ray times for its SCAN if the host asked for them and can read them (minor 4)."""
        if not (self.settings.ray_times and self._host_minor >= 4):
            return None
        if scan.ray_times_ns is None:
            return np.full(len(scan.ranges_m), np.nan)
        return np.asarray(scan.ray_times_ns, dtype=np.float64) / 1000

    def _source_failed(self, exc: Exception) -> None:
        log.error("scan source failed: %s", exc)
        with self._lock:
            self._fault = f"{type(exc).__name__}: {exc}"
            self.counters.source_failures += 1
            if self._scanning:
                self._scanning = False
                try:
                    self.source.stop()
                except Exception as stop_exc:
                    log.error("scan source failed to stop: %s", stop_exc)
            self._control.append(m.Log(logging.ERROR, device_clock_us(), f"scan source failed: {self._fault}"))
            self._lock.notify_all()

    # writer: control first, then scans
    def _write_loop(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self._control:
                    msg, prefix = self._control.popleft(), b"\x00"
                elif self._scans:
                    msg, prefix = self._scans.popleft(), b""
                else:
                    self._lock.wait(0.1)
                    continue
            try:
                wire = prefix + self._encode(msg)
            except ValueError as exc:  # e.g. a source delivered an unencodable range
                self._source_failed(exc)
                continue
            try:
                self.port.write(wire)
            except Exception as exc:
                if not self._stop.is_set():
                    log.warning("link port write failed, stopping: %s", exc)
                self._end()
                break
            if isinstance(msg, m.ScanMessage):
                self.counters.scans_sent += 1

    def _encode(self, msg) -> bytes:
        if isinstance(msg, m.ScanMessage):
            age = max(0, device_clock_us() - msg.device_time_us)
            payload = dataclasses.replace(msg, age_us=age).encode()
        else:
            payload = msg.encode()
        wire = encode_frame(msg.TYPE, self._seq, payload)
        self._seq = (self._seq + 1) & 0xFFFF
        return wire
