"""Receiving half of the host SDK, without threads or ports: bytes in, scans and replies out.

LaserPi's reader thread and host_sdk.replay() both feed it, so the live path and the replay path
are the same code (and the fuzz tests exercise exactly what scans() runs).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from protocol import messages as m
from protocol.stream import LinkStats, StreamDecoder
from host_sdk.scan import Scan, StampClock, scan_from_message

log = logging.getLogger(__name__)


@dataclass
class Stats(LinkStats):
    """LinkStats of the byte stream plus what the host made of it.

    scans: scans delivered to the queue; scans_missing: jumps in the device's scan counter
    (dropped on the device because the link was slow, or lost on the wire);
    scans_dropped: oldest scans dropped because the consumer was slower than the sensor;
    scans_without_info: scans that arrived before any INFO (no angles; dropped);
    reconnects: successful reconnections after the port went away.
    """

    scans: int = 0
    scans_missing: int = 0
    scans_dropped: int = 0
    scans_without_info: int = 0
    reconnects: int = 0


class Receiver:
    """Turns device bytes into Scan objects and control messages; never raises on bad bytes."""

    def __init__(self, link_rate_bps: float, stats: Stats | None = None):
        self.stats = Stats() if stats is None else stats
        self.decoder = StreamDecoder(stats=self.stats)
        self.clock = StampClock(link_rate_bps)
        self.info: m.Info | None = None
        self._last_scan_seq: int | None = None

    def resync(self) -> None:
        """Forget the partial frame and clock history (after reopening the port); keep stats."""
        self.decoder = StreamDecoder(stats=self.stats)
        self.clock.reset()
        self._last_scan_seq = None

    def feed(self, data: bytes, t_read: float) -> list:
        """Everything decodable in ``data`` (read at host monotonic time t_read): Scan objects
        and control messages (Info, Health, Ack, Nack, Log) in arrival order."""
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
            if isinstance(msg, m.Info):
                self.info = msg
            elif isinstance(msg, m.Log):
                log.log(msg.level, "device: %s", msg.text)
            out.append(msg)
        return out

    def _scan(self, msg: m.ScanMessage, rec, t_read: float) -> Scan | None:
        if self.info is None:
            self.stats.scans_without_info += 1
            return None
        stamp = self.clock.stamp(t_read, rec.tail, rec.wire_len, msg.age_us, msg.device_time_us)
        try:
            scan = scan_from_message(msg, self.info, stamp)
        except ValueError as exc:
            self.stats.decode_errors += 1
            log.debug("dropped scan %d: %s", msg.scan_seq, exc)
            return None
        if self._last_scan_seq is not None:
            gap = (msg.scan_seq - self._last_scan_seq - 1) & 0xFFFFFFFF
            if gap < 0x80000000:  # a restart of the counter is not a gap
                self.stats.scans_missing += gap
        self._last_scan_seq = msg.scan_seq
        self.stats.scans += 1
        return scan
