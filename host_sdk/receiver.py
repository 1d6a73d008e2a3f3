"""Receiving half of the host SDK, without threads or ports: bytes in, scans and replies out.

LaserPi's reader thread and host_sdk.replay() both feed it, so the live path and the replay path
are the same code (and the fuzz tests exercise exactly what scans() runs).

Only confirmed facts place a scan: the geometry (``info``) is set by whoever asked for it
(``set_info``), never by an INFO that merely arrives. A scan from another boot of the device than
the confirmed INFO's (boot id in the scan, protocol minor 2), or - from an older device without
boot ids - a scan counter that goes backwards, is a device restart: it is counted, and no scan
is placed until an INFO of the new boot is set (``restart_pending``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from protocol import messages as m
from protocol.stream import LinkStats, StreamDecoder
from host_sdk.scan import Scan, StampClock, scan_from_message

log = logging.getLogger(__name__)

#: A jump of the u32 scan counter of at least this many is the counter going backwards.
_SCAN_SEQ_BACKWARDS = 0x80000000


@dataclass
class Stats(LinkStats):
    """LinkStats of the byte stream plus what the host made of it.

    scans: scans delivered to the queue; scans_missing: jumps in the device's scan counter
    (dropped on the device because the link was slow, or lost on the wire);
    scans_dropped: scans dropped unread because the consumer was slower than the sensor (the
    oldest beyond queue_scans, or all but the newest with ``scans(newest_only=True)``);
    scans_without_info: scans that could not be placed (before any INFO, or after a device
    restart until its INFO was asked for; dropped);
    device_restarts: times the device was seen to restart (a new boot id, or a scan counter going
    backwards on a device without boot ids);
    replies_unsolicited: INFO, HEALTH, ACK, NACK or ANGLES nobody asked for (ignored);
    stamp_outliers: scans whose timing (age, device time) disagreed with the others by more than
    StampClock.tolerance_s (stamped from the others, not used for them);
    reconnects: successful reconnections after the port went away.
    """

    scans: int = 0
    scans_missing: int = 0
    scans_dropped: int = 0
    scans_without_info: int = 0
    device_restarts: int = 0
    replies_unsolicited: int = 0
    stamp_outliers: int = 0
    reconnects: int = 0


class Receiver:
    """Turns device bytes into Scan objects and control messages; never raises on bad bytes."""

    def __init__(self, link_rate_bps: float, stats: Stats | None = None):
        self.stats = Stats() if stats is None else stats
        self.decoder = StreamDecoder(stats=self.stats)
        self.clock = StampClock(link_rate_bps)
        self.info: m.Info | None = None
        self.restart_pending = False  # a restart was seen and no INFO of the new boot set yet
        self._restart_boot: int | None = None  # the boot id that restart was seen with
        self._last_scan_seq: int | None = None

    def resync(self) -> None:
        """Forget the partial frame and clock history (after reopening the port); keep stats."""
        self.decoder = StreamDecoder(stats=self.stats)
        self.clock.reset()
        self._last_scan_seq = None

    def set_info(self, info: m.Info) -> None:
        """The geometry scans are placed with, from an INFO that was asked for (complete angles).
        An INFO of another boot than the last one counts as a device restart."""
        if not info.complete:
            raise ValueError("set_info needs an INFO with all its angles")
        self.saw_boot(info.boot_id)
        if self.info is None or info.boot_id != self.info.boot_id:
            self.clock.reset()
            self._last_scan_seq = None
        self.info = info
        self.restart_pending = False

    def saw_boot(self, boot_id: int | None) -> bool:
        """Note a boot id seen in a confirmed reply or a scan; True if it is a restart not yet
        answered by set_info (counted once per new boot)."""
        known = None if self.info is None else self.info.boot_id
        if boot_id is None or known is None or boot_id == known:
            return False
        if boot_id != self._restart_boot:
            self._restart_boot = boot_id
            self.stats.device_restarts += 1
            log.warning("the device restarted (boot id %08x, was %08x)", boot_id, known)
        self.restart_pending = True
        return True

    def feed(self, data: bytes, t_read: float) -> list:
        """Everything decodable in ``data`` (read at host monotonic time t_read): Scan objects
        and control messages (Info, Health, Ack, Nack, Angles, Log) in arrival order."""
        out = []
        for rec in self.decoder.feed(data):
            try:
                msg = m.decode_message(rec.frame.msg_type, rec.frame.payload)
            except m.MessageError as exc:
                self.stats.decode_errors += 1
                log.debug("dropped frame of type 0x%02x: %s", rec.frame.msg_type, exc)
                continue
            if isinstance(msg, m.ScanMessage):
                scan = self._scan(msg, rec, t_read)
                if scan is not None:
                    out.append(scan)
                continue
            if isinstance(msg, m.Log):
                log.log(msg.level, "device: %s", msg.text)
            out.append(msg)
        return out

    def _scan(self, msg: m.ScanMessage, rec, t_read: float) -> Scan | None:
        if self.info is None or self.saw_boot(msg.boot_id) or self.restart_pending or self._went_back(msg):
            self.stats.scans_without_info += 1
            return None
        outliers = self.clock.outliers
        stamp = self.clock.stamp(t_read, rec.tail, rec.wire_len, msg.age_us, msg.device_time_us)
        self.stats.stamp_outliers += self.clock.outliers - outliers
        try:
            scan = scan_from_message(msg, self.info, stamp)
        except ValueError as exc:
            self.stats.decode_errors += 1
            log.debug("dropped scan %d: %s", msg.scan_seq, exc)
            return None
        if self._last_scan_seq is not None:
            self.stats.scans_missing += (msg.scan_seq - self._last_scan_seq - 1) & 0xFFFFFFFF
        self._last_scan_seq = msg.scan_seq
        self.stats.scans += 1
        return scan

    def _went_back(self, msg: m.ScanMessage) -> bool:
        """A scan counter going backwards: on a device without boot ids, its restart; on one with
        them, a new link session of the same device process (the counter starts again at 0)."""
        if self._last_scan_seq is None:
            return False
        last = self._last_scan_seq
        if (msg.scan_seq - last - 1) & 0xFFFFFFFF < _SCAN_SEQ_BACKWARDS:
            return False
        self._last_scan_seq = None
        if msg.boot_id is not None:  # same process, same clock: nothing to forget
            return False
        self.clock.reset()
        self.stats.device_restarts += 1
        self.restart_pending = True
        log.warning("the device's scan counter went back from %d to %d: it restarted", last, msg.scan_seq)
        return True


class InfoAssembler:
    """An INFO and the ANGLES chunks of the same geometry (same boot id and angles_crc) -> the
    complete INFO. LaserPi feeds it the chunks it asked for; a replay of a recording, which cannot
    ask, feeds it every INFO and ANGLES it finds."""

    def __init__(self, info: m.Info):
        self.info = info
        self._angles = np.zeros(info.n_columns or 0, np.float32)
        self._have = np.zeros(self._angles.size, bool)

    def missing(self) -> int | None:
        """First column not received yet, None when complete."""
        if self.info.complete:
            return None
        todo = np.flatnonzero(~self._have)
        return int(todo[0]) if todo.size else None

    def add(self, chunk: m.Angles) -> bool:
        """Place ``chunk`` if it belongs to this INFO's geometry; False if it does not."""
        i = self.info
        if (chunk.boot_id, chunk.angles_crc, chunk.n_columns) != (i.boot_id, i.angles_crc, i.n_columns):
            return False
        self._angles[chunk.first:chunk.first + chunk.angles.size] = chunk.angles
        self._have[chunk.first:chunk.first + chunk.angles.size] = True
        return True

    def complete(self) -> m.Info | None:
        """The INFO with all its angles, once every chunk arrived and they match angles_crc."""
        if self.info.complete:
            return self.info
        if not self._have.all() or m.angles_crc(self._angles) != self.info.angles_crc:
            return None
        return replace(self.info, angles=self._angles.copy())
