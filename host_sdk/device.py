"""LaserPi: one sensor on one serial port. ``with LaserPi("/dev/laserpi") as s: for scan in s.scans(): ...``

Opening clears whatever state an earlier, unclean session left behind: the input buffer is
flushed, STOP is sent (the device may still be streaming), the partial first frame is discarded
and INFO is requested again (three tries).

A reader thread owns the port: it feeds bytes to a Receiver (host_sdk/receiver.py), puts scans on
a bounded queue and hands replies to the waiting request. When the consumer is slower than the
sensor, the queue keeps the newest ``queue_scans`` scans and drops the oldest, counting them in
``stats.scans_dropped``: memory stays bounded and ``scans()`` always yields fresh data.

If the port goes away (unplugged cable, device restarted) and ``reconnect`` is on, the reader
reopens it with exponential back-off (0.1 s doubling to 2 s) for up to ``reconnect_timeout_s``,
then repeats the opening handshake and restarts streaming if it was on; ``scans()`` simply waits
meanwhile. Otherwise, or when the back-off gives up, the next call raises DisconnectedError.

Every instance has its own port, thread, queue and counters: several sensors in one process
need nothing special (one LaserPi per port, one thread each if you like).
"""

from __future__ import annotations

import collections
import errno
import logging
import threading
import time
from typing import Iterator

import serial

from host_sdk.errors import (CommandRefused, DeviceTimeout, DisconnectedError, IncompatibleDevice, LaserPiError,
                             PortError)
from host_sdk.receiver import Receiver, Stats
from host_sdk.scan import Scan
from protocol import messages as m
from protocol.framing import PROTOCOL_VERSION, encode_frame

log = logging.getLogger(__name__)

# pyserial finds URL handlers as <package>.protocol_<scheme>: this makes "sim://" known.
if "host_sdk" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("host_sdk")

DEFAULT_BAUDRATE = 921600
_READ_TIMEOUT_S = 0.05


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


class LaserPi:
    """A LaserPi sensor on ``port`` (a device path such as /dev/ttyUSB0 or COM3, or a pyserial
    URL such as sim://wall?distance=2.0).

    timeout_s: how long a request waits for its reply, and scans() for the next scan.
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
        self._receiver = Receiver(link_rate_bps or baudrate)
        self._tap = tap
        self._cond = threading.Condition()
        self._scans: collections.deque[Scan] = collections.deque(maxlen=queue_scans)
        self._replies: list = []
        self._request_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._seq = 0
        self._streaming = False
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
        """Versions, serial number, scan geometry (angles), range limits, current settings."""
        if refresh or self._receiver.info is None:
            self._request(m.GetInfo(), m.Info)
        return self._receiver.info

    def health(self) -> m.Health:
        """State, laser, sync lock, dropped frames/scans, active error codes (ErrorCode) and fault
        counters (camera restarts, co-MCU resets and losses, pipeline errors, host bytes discarded and
        frames rejected, host link sessions; None from a device of protocol minor 0), fresh from
        the device. Fields: protocol/SPEC.md "HEALTH"."""
        return self._request(m.GetHealth(), m.Health)

    def start(self) -> None:
        self._request(m.Start(), m.Ack)
        self._streaming = True

    def stop(self) -> None:
        """Stop streaming and drop queued scans; no scan from before the stop is yielded after."""
        self._request(m.Stop(), m.Ack)
        self._streaming = False
        with self._cond:
            self._scans.clear()

    def configure(self, **settings) -> m.ScanSettings:
        """Change settings (names of protocol.messages.ScanSettings); all are applied or none.

        Raises CommandRefused with the device's reason (e.g. laser power above the Class 1
        limit); returns the device's settings afterwards.
        """
        unknown = set(settings) - set(m.ScanSettings.FIELDS)
        if unknown:
            raise ValueError(f"unknown settings {sorted(unknown)}; known: {', '.join(m.ScanSettings.FIELDS)}")
        self._request(m.SetConfig(m.ScanSettings(**settings)), m.Ack)
        return self.info(refresh=True).settings

    def scans(self) -> Iterator[Scan]:
        """Yield scans as they come, starting the sensor if needed.

        Raises DeviceTimeout if no scan arrives within timeout_s, DisconnectedError if the port
        goes away (after reconnecting gives up, if on). Never raises on bad bytes: those are
        dropped and counted in ``stats``.
        """
        if not self._streaming:
            self.start()
        while True:
            with self._cond:
                deadline = time.monotonic() + self.timeout_s
                while not self._scans and self._error is None:
                    left = deadline - time.monotonic()
                    if self._reconnecting:
                        deadline = time.monotonic() + self.timeout_s
                    elif left <= 0:
                        raise DeviceTimeout(f"no scan from {self.port_name} within {self.timeout_s} s")
                    self._cond.wait(min(0.1, max(left, 0.01)))
                if not self._scans:
                    raise self._error
                scan = self._scans.popleft()
            yield scan

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

    # --- requests ---------------------------------------------------------------------------
    def _handshake(self) -> None:
        self._serial.reset_input_buffer()
        self._send(m.Stop())  # an earlier session may have left it streaming
        last: Exception | None = None
        for _ in range(3):
            try:
                info = self._request(m.GetInfo(), m.Info)
                break
            except DeviceTimeout as exc:
                last = exc
        else:
            seen = self.stats.version_seen
            if seen is not None and seen != PROTOCOL_VERSION:
                raise IncompatibleDevice(f"{self.port_name} speaks protocol version {seen}; this SDK speaks "
                                         f"{PROTOCOL_VERSION} - update the one that is older") from last
            raise DeviceTimeout(f"no answer to GET_INFO from {self.port_name} (is it a LaserPi, at "
                                f"{self.baudrate} baud?)") from last
        if info.protocol_major != PROTOCOL_VERSION:
            raise IncompatibleDevice(f"device protocol {info.protocol_major}.{info.protocol_minor}, "
                                     f"SDK {PROTOCOL_VERSION}.{m.PROTOCOL_MINOR}")
        with self._cond:  # scans of an earlier session arrived before the STOP took effect
            self._scans.clear()

    def _send(self, msg) -> int:
        with self._write_lock:
            seq = self._seq
            self._seq = (seq + 1) & 0xFFFF
            # the leading 0x00 ends whatever partial frame the device may be holding
            self._serial.write(b"\x00" + encode_frame(msg.TYPE, seq, msg.encode()))
        return seq

    def _request(self, msg, reply_type: type):
        with self._request_lock:
            with self._cond:
                # while the reader reconnects, wait for it rather than fail the write
                give_up = time.monotonic() + self.reconnect_timeout_s
                while self._reconnecting and self._error is None and time.monotonic() < give_up:
                    self._cond.wait(0.1)
                self._raise_if_failed()
                self._replies.clear()
            try:
                seq = self._send(msg)
            except (serial.SerialException, OSError) as exc:
                raise DisconnectedError(f"{self.port_name}: write failed: {exc}") from exc
            deadline = time.monotonic() + self.timeout_s
            with self._cond:
                while True:
                    for reply in self._replies:
                        if isinstance(reply, (m.Ack, m.Nack)) and reply.request_seq != seq:
                            continue
                        if isinstance(reply, m.Nack):
                            raise CommandRefused(type(msg).__name__, reply.code, reply.reason)
                        if isinstance(reply, reply_type):
                            return reply
                    self._raise_if_failed()
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise DeviceTimeout(f"no reply to {type(msg).__name__} from {self.port_name} "
                                            f"within {self.timeout_s} s")
                    self._cond.wait(left)

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise self._error

    # --- reader thread ----------------------------------------------------------------------
    def _read_loop(self) -> None:
        while not self._closing.is_set():
            try:
                ser = self._serial
                data = ser.read(max(1, min(ser.in_waiting, 65536)))
            except Exception as exc:  # pyserial raises SerialException/OSError/TypeError on unplug
                if self._closing.is_set():
                    return
                if not self._recover(exc):
                    return
                continue
            if not data:
                continue
            t_ns = time.monotonic_ns()
            try:
                if self._tap is not None:
                    self._tap(t_ns, data)
                self._dispatch(self._receiver.feed(data, t_ns * 1e-9))
            except Exception as exc:  # a bug or a failing tap: say so instead of going silent
                log.exception("%s: reader failed", self.port_name)
                self._fail(LaserPiError(f"{self.port_name}: reader failed: {exc!r}"))
                return

    def _dispatch(self, items: list) -> None:
        with self._cond:
            for item in items:
                if isinstance(item, Scan):
                    if len(self._scans) == self._scans.maxlen:
                        self.stats.scans_dropped += 1
                    self._scans.append(item)
                elif not isinstance(item, m.Log):
                    self._replies.append(item)
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
                self._receiver.resync()
                self._send(m.Stop())
                self._send(m.GetInfo())
                if self._streaming:
                    self._send(m.Start())
            except (PortError, serial.SerialException, OSError) as retry_exc:
                log.info("%s: reconnect failed: %s", self.port_name, retry_exc)
                continue
            self.stats.reconnects += 1
            with self._cond:
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
