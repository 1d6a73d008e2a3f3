"""LaserPi: one sensor on one serial port. ``with LaserPi("/dev/laserpi") as s: for scan in s.scans(): ...``

Opening clears whatever state an earlier, unclean session left behind: the input buffer is
flushed, STOP is sent (the device may still be streaming), the partial first frame is discarded
and INFO is requested again (three tries), then the scan geometry in chunks (GET_ANGLES, each no
larger than a fifth of a scan) from a device of protocol minor >= 2.

Requests. Every request carries an id (protocol minor 2) and only a reply with that id answers
it (from an older device: a reply of the right type, ACK/NACK by the request's frame sequence
number); anything else is counted (``stats.replies_unsolicited``) and dropped - one reply slot,
nothing grows. A request is sent again every ``timeout_s / 4`` until its reply comes or
``timeout_s`` has passed: all requests may be repeated (GET_* and START/STOP change nothing the
second time; the device applies a SET_CONFIG repeated with the same id once).

A reader thread owns the port: it feeds bytes to a Receiver (host_sdk/receiver.py), puts scans on
a bounded queue, hands the waiting request its reply and, while the port is open, sends a
HEARTBEAT every second (more often if the device's host_timeout_s is short) so that the device
knows the host listens: a host that dies without close() has the device stop its laser after
host_timeout_s (SPEC.md "Host liveness"). When the consumer is slower than the sensor, the queue
keeps the newest ``queue_scans`` scans and drops the oldest, counting them in
``stats.scans_dropped``.

How old a yielded scan can be: ``scans()`` yields from the queue, so a consumer that falls behind
gets scans up to ``queue_scans`` scan periods old (16 x 0.1 s = 1.6 s at 10 Hz) plus the link
delay; ``scans(newest_only=True)`` drops all but the newest (counted in scans_dropped), so a
yielded scan is at most one scan period plus the link delay (the frame's time on the wire and the
device's age_us; 0.11 s at 10 Hz on a 921600-baud UART) older than the moment it is yielded.

Start-up. After START a device may take ``startup_s`` (its INFO says, protocol minor 2; else
DEFAULT_STARTUP_S) before its first scan; scans() waits that long plus ``timeout_s`` for it.
Afterwards a gap longer than ``timeout_s`` raises DeviceTimeout, whose message says what the
link saw meanwhile: nothing, only garbage, or frames without scans.

Restarts. A scan or HEALTH with another boot id than the INFO's (or, from a device without boot
ids, a scan counter going backwards) means the device restarted: the SDK counts it
(``stats.device_restarts``), asks for INFO again and restarts streaming before it yields another
scan. An INFO the SDK did not ask for changes nothing.

If the port goes away (unplugged cable, device restarted) and ``reconnect`` is on, the reader
reopens it with exponential back-off (0.1 s doubling to 2 s) for up to ``reconnect_timeout_s``;
scans() then asks for INFO again and restarts streaming if it was on, and simply waits meanwhile.
Otherwise, or when the back-off gives up, the next call raises DisconnectedError.

Every instance has its own port, thread, queue and counters: several sensors in one process
need nothing special (one LaserPi per port, one thread each if you like).
"""

from __future__ import annotations

import collections
import errno
import logging
import math
import random
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np
import serial

from host_sdk.errors import (CommandRefused, DeviceTimeout, DisconnectedError, IncompatibleDevice, LaserPiError,
                             PortError)
from host_sdk.diagnostics import DiagnosticStatus, device_status, link_status, scan_status
from host_sdk.receiver import InfoAssembler, Receiver, Stats
from host_sdk.scan import Crop, Scan
from protocol import messages as m
from protocol.framing import PROTOCOL_VERSION, encode_frame

log = logging.getLogger(__name__)

# pyserial finds URL handlers as <package>.protocol_<scheme>: this makes "sim://" known.
if "host_sdk" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("host_sdk")

DEFAULT_BAUDRATE = 921600
_READ_TIMEOUT_S = 0.05
#: Start-up allowance for a device that does not state its own (protocol minor < 2): from START
#: to the first scan a real sensor starts its camera and locks its laser to it.
DEFAULT_STARTUP_S = 5.0
#: Longest time between two HEARTBEATs of the reader thread.
HEARTBEAT_S = 1.0


def _open_port(port: str, baudrate: int) -> serial.SerialBase:
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=_READ_TIMEOUT_S, write_timeout=2.0,
                                     exclusive=True)
    except serial.SerialException as exc:
        code = getattr(exc, "errno", None)
        hint = {errno.EACCES: " - add your user to the 'dialout' group and log in again",
                errno.ENOENT: " - is the sensor plugged in? (ls /dev/serial/by-id/)",
                errno.EBUSY: " - another program has the port open",
                errno.EAGAIN: " - another program has the port open"}.get(code, "")
        raise PortError(f"cannot open {port}: {exc}{hint}") from exc
    except ValueError as exc:
        raise PortError(f"cannot open {port}: {exc}") from exc


@dataclass
class _Pending:
    """The one request waiting for its reply."""

    msg_type: int
    request_id: int
    reply_type: type
    frame_seqs: set = field(default_factory=set)  # every attempt's frame sequence number
    reply: object = None

    def answered_by(self, msg, ids_required: bool) -> bool:
        if not isinstance(msg, (self.reply_type, m.Nack)):
            return False
        rid = getattr(msg, "request_id", None)
        if rid:
            return rid == self.request_id
        if ids_required:  # the device numbers its replies: one without a number answers nothing
            return False
        if isinstance(msg, (m.Ack, m.Nack)):  # an older device: by the request's frame seq
            return msg.request_type == self.msg_type and msg.request_seq in self.frame_seqs
        return True


@dataclass(frozen=True)
class _LinkMark:
    """Counters at the start of a wait, to say what the link saw meanwhile."""

    bytes_received: int
    frames_ok: int
    scans_without_info: int

    @classmethod
    def of(cls, stats: Stats) -> _LinkMark:
        return cls(stats.bytes_received, stats.frames_ok, stats.scans_without_info)


class LaserPi:
    """A LaserPi sensor on ``port`` (a device path such as /dev/ttyUSB0 or COM3, or a pyserial
    URL such as sim://wall?distance=2.0).

    timeout_s: how long a request may take, retries included, and scans() waits for the next
    scan once the first has come (the first may take the start-up allowance longer).
    queue_scans: scans kept for a slow consumer (oldest dropped beyond that).
    link_rate_bps: real bits per second on the wire, for time stamps (default: the baud rate;
    set it for USB CDC, where the baud rate is nominal).
    tap: called as tap(t_ns, data) from the reader thread with every chunk read, before decoding
    (``laserpi record`` uses it); t_ns is time.monotonic_ns() of the read.
    """

    def __init__(self, port: str, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = 1.0, *,
                 queue_scans: int = 16, reconnect: bool = False, reconnect_timeout_s: float = 30.0,
                 link_rate_bps: float | None = None, tap=None):
        if queue_scans < 1:
            raise ValueError("queue_scans must be at least 1")
        self.port_name = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.reconnect = reconnect
        self.reconnect_timeout_s = reconnect_timeout_s
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self._retry_s = max(0.1, timeout_s / 4)  # a request is sent again this often
        self._receiver = Receiver(link_rate_bps or baudrate)
        self._rx_lock = threading.Lock()  # the Receiver: fed by the reader, its INFO set by requests
        self._tap = tap
        self._cond = threading.Condition()
        self._scans: collections.deque[Scan] = collections.deque(maxlen=queue_scans)
        self._pending: _Pending | None = None
        self._next_id = random.randrange(1, 0x10000)  # a new session does not reuse the last one's ids
        self._request_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._seq = 0
        self._streaming = False
        self._started_at: float | None = None  # our START, until its first scan arrived
        self._last_scan_at: float | None = None
        self._needs_info = False  # the port was reopened: ask INFO (and START) before more scans
        self._next_beat = 0.0
        self._diag_before: dict | None = None
        self._error: Exception | None = None
        self._closing = threading.Event()
        self._reconnecting = False
        self._serial = _open_port(port, baudrate)
        self._reader = threading.Thread(target=self._read_loop, name=f"laserpi-reader {port}", daemon=True)
        self._reader.start()
        try:
            self._handshake()
        except BaseException:
            self.close()
            raise

    # --- public API -------------------------------------------------------------------------
    @property
    def stats(self) -> Stats:
        """Live counters (host_sdk.receiver.Stats); ``stats.as_dict()`` for a snapshot."""
        return self._receiver.stats

    def info(self, refresh: bool = False) -> m.Info:
        """Versions, serial number, scan geometry (angles), range limits, current settings, and
        from a device of protocol minor >= 2 its boot id, start-up time and host timeout."""
        if refresh or self._receiver.info is None:
            return self._fetch_info()
        return self._receiver.info

    def health(self) -> m.Health:
        """State, laser, sync lock, dropped frames/scans, active error codes (ErrorCode) and fault
        counters (camera restarts, co-MCU resets and losses, pipeline errors, host bytes discarded and
        frames rejected, host link sessions; None from a device of protocol minor 0; boot id and
        host timeouts from minor 2), fresh from the device. Fields: protocol/SPEC.md "HEALTH".
        A boot id other than the INFO's is a device restart (see the module docstring)."""
        health = self._request(m.GetHealth(), m.Health)
        with self._rx_lock:
            self._receiver.saw_boot(health.boot_id)
        return health

    def start(self) -> None:
        """Start streaming. The device answers once its camera and laser are started: this may
        take its start-up time (INFO startup_s) on top of timeout_s."""
        self._request(m.Start(), m.Ack, timeout_s=self.timeout_s + self._startup_s())
        self._streaming = True
        self._started_at = time.monotonic()

    def stop(self) -> None:
        """Stop streaming and drop queued scans; no scan from before the stop is yielded after."""
        self._request(m.Stop(), m.Ack)
        self._streaming = False
        self._started_at = None
        with self._cond:
            self._scans.clear()

    def configure(self, **settings) -> m.ScanSettings:
        """Change settings (names of protocol.messages.ScanSettings); all are applied or none.

        Returns the settings the device confirms. Raises CommandRefused with the device's reason
        (e.g. laser power above the Class 1 limit) if it refused them, DeviceTimeout if it did not
        answer and its settings show they were not applied (or it cannot be asked); never once the
        device has applied them. ``ray_times=True`` (each Scan's ray_times) needs a device of
        protocol minor >= 4; an older one is refused here (NOT_SUPPORTED), before anything is sent.
        """
        unknown = set(settings) - set(m.ScanSettings.FIELDS)
        if unknown:
            raise ValueError(f"unknown settings {sorted(unknown)}; known: {', '.join(m.ScanSettings.FIELDS)}")
        update = m.ScanSettings(**settings)
        if update.ray_times is not None and (minor := self.info().protocol_minor) < 4:
            raise CommandRefused("SetConfig", m.NackCode.NOT_SUPPORTED, f"ray_times needs a device of protocol "
                                 f"minor >= 4; {self.port_name} speaks {PROTOCOL_VERSION}.{minor}")
        try:
            self._request(m.SetConfig(update), m.Ack)
        except DeviceTimeout as exc:
            try:
                now = self._fetch_info().settings
            except DeviceTimeout:
                raise DeviceTimeout(f"no answer to SET_CONFIG or to GET_INFO after it from {self.port_name} "
                                    f"within {self.timeout_s} s each: whether the settings were applied is "
                                    "not known") from exc
            if _applied(update, now):
                return now  # the device applied them; only its answer was lost
            raise DeviceTimeout(f"no answer to SET_CONFIG from {self.port_name} within {self.timeout_s} s, "
                                "and the device's settings show it did not apply them") from exc
        try:
            return self._fetch_info().settings
        except LaserPiError:  # acknowledged: the device applied exactly this update
            return self._receiver.info.settings.merged(update)

    def scans(self, newest_only: bool = False, *, angle_min: float = -math.inf, angle_max: float = math.inf,
              range_min: float = 0.0, range_max: float = math.inf) -> Iterator[Scan]:
        """Yield scans as they come, starting the sensor if needed.

        newest_only: yield only the newest scan that arrived, dropping older unread ones
        (counted in stats.scans_dropped) - for a consumer that wants the present, not a backlog.
        angle_min .. range_max: crop and filter each scan on the host (host_sdk.scan.Crop, with
        urg_node's and rplidar_ros's conventions). How old a yielded scan can be: module docstring.

        Waits the device's start-up allowance for the first scan after START, then raises
        DeviceTimeout if no scan arrives within timeout_s (saying what the link saw), and
        DisconnectedError if the port goes away (after reconnecting gives up, if on). Never raises
        on bad bytes: those are dropped and counted in ``stats``.
        """
        crop = Crop(angle_min, angle_max, range_min, range_max)
        if not self._streaming:
            self.start()
        while True:
            scan = self._next_scan(newest_only)
            yield scan if crop == Crop() else crop.apply(scan)

    def diagnostics(self) -> list[DiagnosticStatus]:
        """The sensor's state as diagnostic_msgs/DiagnosticStatus entries (name, level, message,
        {key: value}): the device's HEALTH (asked now; STALE if it does not answer), the link's
        counters and the scans' (judged by their growth since the previous call).
        host_sdk/diagnostics.py says how each level is chosen."""
        info = self._receiver.info
        hardware_id = info.serial_number if info is not None else self.port_name
        try:
            health, failure = self.health(), ""
        except LaserPiError as exc:
            health, failure = None, str(exc)
        now, before = self.stats.as_dict(), self._diag_before
        self._diag_before = now
        age = None if self._last_scan_at is None else time.monotonic() - self._last_scan_at
        return [device_status(health, hardware_id, failure), link_status(now, before, hardware_id),
                scan_status(now, before, hardware_id, streaming=self._streaming, scan_age_s=age,
                            timeout_s=self.timeout_s)]

    def close(self) -> None:
        """Stop the device (best effort) and release the port; safe to call twice."""
        if self._closing.is_set():
            return
        if self._error is None and self._streaming:
            try:
                self._send(m.Stop())
            except Exception as exc:  # closing anyway
                log.debug("stop on close failed: %s", exc)
        self._closing.set()
        if self._reader.is_alive() and self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        try:
            self._serial.close()
        except Exception as exc:
            log.debug("closing port failed: %s", exc)
        if self._error is None:  # wake any thread still waiting in scans() or a request
            self._fail(PortError(f"{self.port_name} was closed"))

    def __enter__(self) -> LaserPi:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"LaserPi({self.port_name!r})"

    # --- scans ------------------------------------------------------------------------------
    def _next_scan(self, newest_only: bool) -> Scan:
        waited_from, mark, probed = time.monotonic(), _LinkMark.of(self.stats), False
        while True:
            if self._needs_info or self._receiver.restart_pending:
                self._resume()
            with self._cond:
                if self._scans:
                    if newest_only and len(self._scans) > 1:
                        self.stats.scans_dropped += len(self._scans) - 1
                        newest = self._scans.pop()
                        self._scans.clear()
                        return newest
                    return self._scans.popleft()
                self._raise_if_failed()
                now = time.monotonic()
                if self._reconnecting:
                    waited_from = now
                left = self._scan_deadline(waited_from) - now
                if left > 0:
                    self._cond.wait(min(0.1, left))
                    continue
            if not probed:  # before giving up: did the device restart or stop? (then go on)
                probed = True
                if self._probe():
                    waited_from, mark = time.monotonic(), _LinkMark.of(self.stats)
                    continue
            raise DeviceTimeout(self._timeout_message(mark, time.monotonic() - waited_from))

    def _scan_deadline(self, waited_from: float) -> float:
        if self._started_at is not None:  # no scan since our START: the start-up allowance too
            return max(waited_from, self._started_at + self._startup_s()) + self.timeout_s
        return waited_from + self.timeout_s

    def _startup_s(self) -> float:
        """How long the device may take from START to its first scan: its own word (INFO, minor
        2) or DEFAULT_STARTUP_S."""
        info = self._receiver.info
        return info.startup_s if info is not None and info.startup_s is not None else DEFAULT_STARTUP_S

    def _resume(self) -> None:
        """After a restart of the device or a reopened port: INFO again, then START again if we
        were streaming; the start-up allowance applies again. A device still starting may not
        answer yet: then we try again on the next pass, within the allowance counted from the
        first try."""
        if self._started_at is None:
            self._started_at = time.monotonic()
        try:
            self._fetch_info()
            with self._cond:
                self._scans.clear()
            self._needs_info = False
            if self._streaming:
                self.start()
        except DeviceTimeout as exc:
            log.info("%s: device not answering after a restart yet: %s", self.port_name, exc)

    def _probe(self) -> bool:
        """No scan within the timeout while streaming: ask HEALTH. True if there is reason to wait
        again (the device restarted, or stopped - e.g. it did not hear us - and was started again)."""
        if not self._streaming:
            return False
        try:
            health = self.health()
        except LaserPiError:
            return False
        if self._receiver.restart_pending:
            return True
        if health.state == m.DeviceState.IDLE:
            log.warning("%s: the device had stopped streaming; starting it again", self.port_name)
            self.start()
            return True
        return False

    def _timeout_message(self, mark: _LinkMark, waited_s: float) -> str:
        s = self.stats
        got, frames = s.bytes_received - mark.bytes_received, s.frames_ok - mark.frames_ok
        if not got:
            what = "nothing arrived"
        elif not frames:
            what = (f"only garbage arrived: {got} bytes, no intact frame (totals: {s.crc_errors} CRC errors, "
                    f"{s.decode_errors} undecodable, {s.zero_bytes} zero bytes in {s.zero_runs} long runs)"
                    " - wrong baud rate or a bad cable?")
        else:
            unplaced = s.scans_without_info - mark.scans_without_info
            what = f"{frames} intact frames arrived but no scan" + (
                f" that could be placed ({unplaced} without a confirmed INFO)" if unplaced else "")
        return f"no scan from {self.port_name} within {waited_s:.1f} s: {what}"

    # --- requests ---------------------------------------------------------------------------
    def _handshake(self) -> None:
        self._serial.reset_input_buffer()
        try:
            self._request(m.Stop(), m.Ack)  # an earlier session may have left it streaming
        except DeviceTimeout as exc:
            log.debug("no answer to STOP on opening: %s", exc)  # GET_INFO below says what is wrong
        last: Exception | None = None
        for _ in range(3):
            try:
                self._fetch_info()
                break
            except DeviceTimeout as exc:
                last = exc
        else:
            seen = self.stats.version_seen
            if seen is not None and seen != PROTOCOL_VERSION:
                raise IncompatibleDevice(f"{self.port_name} speaks protocol version {seen}; this SDK speaks "
                                         f"{PROTOCOL_VERSION} - update the one that is older") from last
            raise DeviceTimeout(f"no answer to GET_INFO from {self.port_name} (is it a LaserPi, at "
                                f"{self.baudrate} baud?): {last}") from last
        with self._cond:  # scans of an earlier session arrived before the STOP took effect
            self._scans.clear()

    def _fetch_info(self) -> m.Info:
        """Ask INFO and, if it came without its angles, the angles in chunks; the result is what
        scans are placed with from now on."""
        info = self._request(m.GetInfo(), m.Info)
        if info.protocol_major != PROTOCOL_VERSION:
            raise IncompatibleDevice(f"device protocol {info.protocol_major}.{info.protocol_minor}, "
                                     f"SDK {PROTOCOL_VERSION}.{m.PROTOCOL_MINOR}")
        known = self._receiver.info
        if not info.complete:
            if known is not None and (known.boot_id, known.angles_crc) == (info.boot_id, info.angles_crc):
                info = replace(info, angles=known.angles)
            else:
                info = self._fetch_angles(info)
        with self._rx_lock:
            self._receiver.set_info(info)
        return info

    def _fetch_angles(self, info: m.Info) -> m.Info:
        chunks = InfoAssembler(info)
        while (first := chunks.missing()) is not None:
            chunk = self._request(m.GetAngles(first, m.ANGLES_PER_FRAME), m.Angles)
            if chunk.first != first or not chunks.add(chunk):
                raise DeviceTimeout(f"{self.port_name}: the scan geometry changed while it was read "
                                    "(did the device restart?)")
        complete = chunks.complete()
        if complete is None:
            raise DeviceTimeout(f"{self.port_name}: the scan geometry read does not match its angles_crc")
        return complete

    def _send(self, msg, pending: _Pending | None = None) -> int:
        with self._write_lock:
            seq = self._seq
            self._seq = (seq + 1) & 0xFFFF
            if pending is not None:
                with self._cond:
                    pending.frame_seqs.add(seq)
            # the leading 0x00 ends whatever partial frame the device may be holding
            self._serial.write(b"\x00" + encode_frame(msg.TYPE, seq, msg.encode()))
        return seq

    def _request(self, msg, reply_type: type, timeout_s: float | None = None):
        """Send ``msg`` with a new request id, again every _retry_s, until its reply arrives or
        ``timeout_s`` (default self.timeout_s) has passed (DeviceTimeout); a NACK raises
        CommandRefused."""
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        with self._request_lock:
            with self._cond:
                # while the reader reconnects, wait for it rather than fail the write
                give_up = time.monotonic() + self.reconnect_timeout_s
                while self._reconnecting and self._error is None and time.monotonic() < give_up:
                    self._cond.wait(0.1)
                self._raise_if_failed()
                request_id, self._next_id = self._next_id, self._next_id % 0xFFFF + 1
                pending = self._pending = _Pending(msg.TYPE, request_id, reply_type)
            msg = replace(msg, request_id=request_id)
            deadline = time.monotonic() + timeout_s
            try:
                while True:
                    try:
                        self._send(msg, pending)
                    except (serial.SerialException, OSError) as exc:
                        raise DisconnectedError(f"{self.port_name}: write failed: {exc}") from exc
                    with self._cond:
                        resend = min(deadline, time.monotonic() + self._retry_s)
                        while pending.reply is None and self._error is None:
                            left = resend - time.monotonic()
                            if left <= 0:
                                break
                            self._cond.wait(left)
                        reply = pending.reply
                        if reply is None:
                            self._raise_if_failed()
                    if isinstance(reply, m.Nack):
                        raise CommandRefused(type(msg).__name__, reply.code, reply.reason)
                    if reply is not None:
                        return reply
                    if time.monotonic() >= deadline:
                        raise DeviceTimeout(f"no reply to {type(msg).__name__} from {self.port_name} within "
                                            f"{timeout_s:g} s ({len(pending.frame_seqs)} tries)")
            finally:
                with self._cond:
                    self._pending = None

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise self._error

    # --- reader thread ----------------------------------------------------------------------
    def _read_loop(self) -> None:
        while not self._closing.is_set():
            try:
                ser = self._serial
                data = ser.read(max(1, min(ser.in_waiting, 65536)))
                t_ns = time.monotonic_ns()  # first: the arrival time stamps the scans
                self._heartbeat()
            except Exception as exc:  # pyserial raises SerialException/OSError/TypeError on unplug
                if self._closing.is_set():
                    return
                if not self._recover(exc):
                    return
                continue
            if not data:
                continue
            try:
                if self._tap is not None:
                    self._tap(t_ns, data)
                with self._rx_lock:
                    items = self._receiver.feed(data, t_ns * 1e-9)
                self._dispatch(items)
            except Exception as exc:  # a bug or a failing tap: say so instead of going silent
                log.exception("%s: reader failed", self.port_name)
                self._fail(LaserPiError(f"{self.port_name}: reader failed: {exc!r}"))
                return

    def _heartbeat(self) -> None:
        """Tell a device of minor >= 2 that we listen (SPEC.md "Host liveness")."""
        info = self._receiver.info
        now = time.monotonic()
        if info is None or info.protocol_minor < 2 or now < self._next_beat:
            return
        self._next_beat = now + min(HEARTBEAT_S, (info.host_timeout_s or HEARTBEAT_S * 4) / 4)
        self._send(m.Heartbeat())

    def _dispatch(self, items: list) -> None:
        info = self._receiver.info
        ids_required = info is not None and info.protocol_minor >= 2
        with self._cond:
            for item in items:
                if isinstance(item, Scan):
                    if len(self._scans) == self._scans.maxlen:
                        self.stats.scans_dropped += 1
                    self._scans.append(item)
                    self._started_at = None
                    self._last_scan_at = time.monotonic()
                elif isinstance(item, m.Log):
                    continue
                elif self._pending is not None and self._pending.reply is None and \
                        self._pending.answered_by(item, ids_required):
                    self._pending.reply = item
                else:
                    self.stats.replies_unsolicited += 1
            self._cond.notify_all()

    def _recover(self, exc: Exception) -> bool:
        """Reopen the port after ``exc``; False (and the error recorded) if not possible."""
        log.warning("%s: port lost: %s", self.port_name, exc)
        try:
            self._serial.close()
        except Exception:
            pass
        if not self.reconnect:
            self._fail(DisconnectedError(f"{self.port_name} disconnected: {exc}"))
            return False
        self._reconnecting = True
        delay, give_up = 0.1, time.monotonic() + self.reconnect_timeout_s
        while not self._closing.is_set() and time.monotonic() < give_up:
            time.sleep(delay)
            delay = min(2 * delay, 2.0)
            try:
                self._serial = _open_port(self.port_name, self.baudrate)
                self._serial.reset_input_buffer()
            except (PortError, serial.SerialException, OSError) as retry_exc:
                log.info("%s: reconnect failed: %s", self.port_name, retry_exc)
                continue
            with self._rx_lock:
                self._receiver.resync()
            self.stats.reconnects += 1
            with self._cond:
                self._needs_info = True  # the device may have restarted: scans() asks INFO, START
                self._reconnecting = False
                self._cond.notify_all()
            log.warning("%s: reconnected", self.port_name)
            return True
        self._reconnecting = False
        self._fail(DisconnectedError(f"{self.port_name} disconnected and did not come back within "
                                     f"{self.reconnect_timeout_s} s: {exc}"))
        return False

    def _fail(self, error: Exception) -> None:
        with self._cond:
            self._error = error
            self._cond.notify_all()


def _applied(update: m.ScanSettings, settings: m.ScanSettings) -> bool:
    """Whether ``settings`` (as the device reports them) hold every field ``update`` sets, as
    the wire carries it (float32)."""
    return all(getattr(settings, n) == type(getattr(settings, n))(np.float32(v)) if isinstance(v, float)
               else getattr(settings, n) == v for n, v in update.as_dict().items())
