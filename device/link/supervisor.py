"""The device end of the host link, kept open: the protocol's link server (protocol/server.py)
serving the sensor's scan source over the host port, opened again when the host side fails.

``LinkSupervisor`` runs the link server over a port and opens it again when the host side fails
(a USB gadget port that vanishes when the host is unplugged); host garbage and scans dropped on
a slow link are counted by the link server into one LinkCounters for all sessions, so HEALTH
(and ``ProcessHealth``, for logs and ``serve --stats-file``) report totals since the process started.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

from device.scan.source import SourceCounters
from protocol import messages as m
from protocol.server import DeviceConfig, LinkCounters, LinkServer

log = logging.getLogger(__name__)


# --- health ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProcessHealth:
    """Everything the process knows about its own health, for logs, tests and the soak run."""

    scanning: bool
    laser_on: bool
    sync_locked: bool
    errors: tuple[int, ...]
    source: SourceCounters
    scans_sent: int = 0
    scans_dropped: int = 0  # whole scans dropped because the host link was slow
    host_bytes_discarded: int = 0  # host bytes that were not part of an intact frame
    host_frames_rejected: int = 0  # CRC, decode and oversize errors from the host
    host_sessions: int = 0  # times the link was (re)opened

    def line(self) -> str:
        s = self.source
        errs = ",".join(m.ErrorCode(e).name if e in m.ErrorCode._value2member_map_ else str(e) for e in self.errors)
        return (f"scanning={self.scanning} laser={'on' if self.laser_on else 'off'} locked={self.sync_locked} "
                f"errors=[{errs}] frames={s.frames} dropped_frames={s.frames_dropped} scans={s.scans_made} "
                f"sent={self.scans_sent} dropped_scans={self.scans_dropped} camera_restarts={s.camera_restarts} "
                f"comcu_lost={s.comcu_lost} comcu_resets={s.comcu_resets} pipeline_errors={s.pipeline_errors} "
                f"host_bytes_discarded={self.host_bytes_discarded} host_frames_rejected={self.host_frames_rejected} "
                f"host_sessions={self.host_sessions}")


# --- the link, reopened when the host side fails -----------------------------------------------
class LinkSupervisor:
    """Serve ``source`` (a ScanSource, usually a SensorSource) to a host over ports from
    ``open_port`` until ``stop`` is set.

    A link server whose port fails (host unplugged from a USB gadget port, serial error) ends its
    session; the supervisor opens the port again with back-off and serves a new session with
    the same source, so the sensor keeps running. On exit the source is stopped (laser off).
    """

    def __init__(self, open_port: Callable[[], object], source, config: DeviceConfig, *,
                 health_log_s: float = 10.0, reopen_backoff_s: tuple[float, float] = (0.1, 2.0),
                 on_health: Callable[[ProcessHealth], None] | None = None):
        """on_health: called with the health at every health log line and once at the end."""
        self.open_port = open_port
        self.source = source
        self.config = config
        self.health_log_s = health_log_s
        self.on_health = on_health
        self.reopen_backoff_s = reopen_backoff_s
        self.server: LinkServer | None = None
        self.counters = LinkCounters()  # shared by every session: HEALTH reports process totals

    @property
    def sessions(self) -> int:
        return self.counters.sessions

    def health(self) -> ProcessHealth:
        c = self.counters
        st = self.source.status()
        return ProcessHealth(
            scanning=bool(self.server and self.server._scanning), laser_on=st.laser_on, sync_locked=st.sync_locked,
            errors=st.errors, source=SourceCounters(**vars(getattr(self.source, "counters", SourceCounters()))),
            scans_sent=c.scans_sent, scans_dropped=c.scans_dropped, host_bytes_discarded=c.host.bytes_discarded,
            host_frames_rejected=c.host_frames_rejected, host_sessions=c.sessions)

    def run(self, stop: threading.Event) -> None:
        """Serve until ``stop`` is set. Between health reports this thread sleeps until ``stop``
        is set or the session ends (the server's ``on_stop``), not polling: each timed wake-up of
        a thread cost ~0.1 ms of CPU on the machine of BENCHMARKS.md "Device process", and a
        10 Hz poll was ~0.1 ms a scan at 10 scans/s. ``stop`` reaches that sleep through a thread
        that waits for it without a timeout (it never wakes before)."""
        backoff = self.reopen_backoff_s[0]
        next_log = time.monotonic() + self.health_log_s
        wake = threading.Event()
        threading.Thread(target=lambda: (stop.wait(), wake.set()), name="link-stop", daemon=True).start()
        try:
            while not stop.is_set():
                try:
                    port = self.open_port()
                except OSError as exc:
                    log.warning("cannot open the host port (%s); again in %.1f s", exc, backoff)
                    stop.wait(backoff)
                    backoff = min(2 * backoff, self.reopen_backoff_s[1])
                    continue
                backoff = self.reopen_backoff_s[0]
                self.server = LinkServer(port, self.source, self.config, self.counters, on_stop=wake.set).start()
                log.info("host link session %d open", self.sessions)
                while not stop.is_set() and not self.server.stopped:
                    wake.wait(min(max(0.0, next_log - time.monotonic()), threading.TIMEOUT_MAX))
                    # cleared after each wake-up, not once a session: a thread of an earlier session
                    # that outlived its close() (a write blocked on a host that stopped reading) may
                    # still call its on_stop; both conditions are set before wake is, and checked again
                    wake.clear()
                    if time.monotonic() >= next_log:
                        self._report(self.health(), "health")
                        next_log = time.monotonic() + self.health_log_s
                self.server.close()
                self.server = None
                closer = getattr(port, "close", None)
                if closer is not None:
                    try:
                        closer()
                    except OSError:
                        pass
                if not stop.is_set():
                    log.warning("host link session %d ended; reopening", self.sessions)
        finally:
            self.source.stop()
            self._report(self.health(), "device process stopped, laser off")

    def _report(self, health: ProcessHealth, what: str) -> None:
        log.info("%s; %s", what, health.line())
        if self.on_health is not None:
            self.on_health(health)
