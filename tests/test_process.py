"""The device process's orchestration and fault handling, against fakes of camera, co-MCU and
pipeline (tests/device_fakes.py). The real parts run end to end in tests/test_serve.py."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from device.link.supervisor import LinkSupervisor
from device.scan.source import SensorSource
from protocol import messages as m
from protocol.framing import encode_frame
from protocol.ports import PacedPort, pipe_pair
from protocol.server import DeviceConfig
from protocol.stream import StreamDecoder
from tests.device_fakes import N_POINTS, WALL_M, FakeCamera, FakeLaser, FakePipeline, FakeRig, fake_geometry


def make_source(rig: FakeRig, **kw) -> tuple[SensorSource, FakeCamera, FakeLaser, FakePipeline]:
    cam, laser, pipe = FakeCamera(rig), FakeLaser(rig), FakePipeline()
    src = SensorSource(cam, laser, pipe, fake_geometry(), stall_timeout_s=0.3, laser_retry_s=0.2, **kw)
    src.apply(settings())
    return src, cam, laser, pipe


def streaming(rig: FakeRig, warmup_s: float) -> tuple[SensorSource, FakeCamera, FakeLaser, FakePipeline]:
    """A started source that has delivered scans for ``warmup_s``."""
    parts = make_source(rig)
    parts[0].start()
    assert scans_for(parts[0], warmup_s)
    return parts


def settings(**kw) -> m.ScanSettings:
    base = dict(scan_rate_hz=20.0, exposure_us=1000, roi_first=0, roi_count=N_POINTS, median_window=1,
                min_quality=0, laser_power_mw=4.0, ray_times=False)
    base.update(kw)
    return m.ScanSettings(**base)


def scans_for(src: SensorSource, seconds: float) -> list:
    out, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        s = src.next_scan(0.1)
        if s is not None:
            out.append(s)
    return out


def test_pairs_lit_and_dark_frames_into_scans():
    rig = FakeRig()
    src, cam, laser, pipe = make_source(rig)
    src.start()
    scans = scans_for(src, 0.6)
    src.stop()
    assert len(scans) >= 8  # 40 fps -> 20 pairs/s, minus the frame the laser starts on
    assert pipe.pairs == len(scans) and src.counters.pipeline_errors == 0
    assert pipe.both >= len(scans) - 1  # every lit frame but the first has the unlit frame before it too
    assert all(s.ranges_m.shape == (N_POINTS,) and np.all(s.ranges_m == WALL_M) for s in scans)
    assert rig.lit_parity is None, "laser must be off after stop"
    assert src.status().errors == ()


def test_camera_stall_of_one_second_is_reported_and_the_stream_resumes():
    rig = FakeRig()
    src, cam, laser, _ = streaming(rig, 0.3)
    rig.stall_until = time.monotonic() + 1.0
    seen_fault = False
    while time.monotonic() < rig.stall_until:
        src.next_scan(0.05)
        st = src.status()
        if m.ErrorCode.CAMERA_FAULT in st.errors:
            seen_fault = True
            assert not st.laser_on and rig.lit_parity is None, "laser must be off while the camera stalls"
    assert seen_fault
    after = scans_for(src, 0.6)
    assert len(after) >= 5
    assert src.counters.camera_stalls >= 1 and src.counters.camera_restarts >= 1 and cam.starts >= 2
    assert m.ErrorCode.CAMERA_FAULT not in src.status().errors and src.status().laser_on
    src.stop()


def test_camera_error_restarts_the_camera():
    rig = FakeRig()
    src, cam, _, _ = streaming(rig, 0.2)
    rig.camera_raise = 1
    assert scans_for(src, 0.8)
    assert src.counters.camera_errors == 1 and src.counters.camera_restarts == 1 and cam.starts == 2
    src.stop()


def test_comcu_reset_mid_stream_turns_laser_off_reports_and_resyncs():
    rig = FakeRig()
    src, _, laser, pipe = streaming(rig, 0.3)
    rig.mcu_reset_pending = True
    deadline = time.monotonic() + 1.0
    while m.ErrorCode.LASER_FAULT not in src.status().errors and time.monotonic() < deadline:
        src.next_scan(0.05)
    st = src.status()
    assert m.ErrorCode.LASER_FAULT in st.errors and m.ErrorCode.SYNC_LOST in st.errors
    assert not st.laser_on and not st.sync_locked
    after = scans_for(src, 0.7)
    assert len(after) >= 5 and src.counters.comcu_resets == 1 and laser.starts == 2
    assert src.status().errors == () and src.counters.pipeline_errors == 0
    src.stop()


def test_comcu_lost_for_a_while_retries_until_it_answers():
    rig = FakeRig()
    src, _, laser, _ = streaming(rig, 0.2)
    rig.mcu_down_until = time.monotonic() + 0.7
    during = scans_for(src, 0.6)
    assert len(during) <= 1  # at most a pair completed before the loss was seen
    assert m.ErrorCode.LASER_FAULT in src.status().errors
    after = scans_for(src, 0.8)
    assert len(after) >= 5
    assert src.counters.comcu_lost == 1 and src.status().laser_on
    src.stop()


def test_roi_min_quality_and_median_are_applied_and_fixed_settings_refused():
    rig = FakeRig()
    src, _, _, _ = make_source(rig)
    src.apply(settings(roi_first=4, roi_count=10, median_window=3))
    with pytest.raises(ValueError, match="scan_rate_hz"):
        src.apply(settings(scan_rate_hz=5.0))
    src.start()
    s = scans_for(src, 0.3)[0]
    assert s.first_index == 4 and s.ranges_m.shape == (10,)
    src.apply(settings(min_quality=250))
    s = scans_for(src, 0.3)[0]
    assert np.isnan(s.ranges_m).all()
    src.stop()
    # min_quality drops weak returns, not REP 117's codes: "too close" (-inf) and "nothing there"
    # (+inf) have no line, so quality 0, and must reach the host as they are
    pipe = src.pipeline

    def with_codes(lit, dark, other_dark):
        rays = pipe(lit, dark, other_dark)
        ranges, quality = rays.ranges.copy(), rays.quality.copy()
        ranges[5], ranges[6], quality[5:7] = -np.inf, np.inf, 0
        return dataclasses.replace(rays, ranges=ranges, quality=quality)

    src.pipeline = with_codes
    src.apply(settings(roi_first=4, roi_count=10, min_quality=250))
    src.start()
    s = scans_for(src, 0.3)[0]
    assert s.ranges_m[1] == -np.inf and s.ranges_m[2] == np.inf and np.isnan(np.delete(s.ranges_m, [1, 2])).all()
    src.stop()


def test_pipeline_exception_skips_the_scan_and_is_counted():
    rig = FakeRig()
    src, _, _, pipe = make_source(rig)
    calls = {"n": 0}

    def flaky(lit, dark, other_dark):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("numerical trouble")
        return pipe(lit, dark, other_dark)

    src.pipeline = flaky
    src.start()
    scans = scans_for(src, 0.5)
    src.stop()
    assert src.counters.pipeline_errors == 1 and len(scans) == calls["n"] - 1


# --- through the link server -------------------------------------------------------------------
class Host:
    """A minimal host on a port: requests and decoded replies (the SDK has its own tests)."""

    def __init__(self, port):
        self.port = port
        self.dec = StreamDecoder(synced=True)
        self.seq = 0
        self.scans: list[m.ScanMessage] = []
        self.replies: list = []
        port.write(b"\x00")  # the device discards everything before its first delimiter

    def send(self, msg) -> None:
        self.port.write(encode_frame(msg.TYPE, self.seq, msg.encode()))
        self.seq += 1

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for rec in self.dec.feed(self.port.read(65536)):
                msg = m.decode_message(rec.frame.msg_type, rec.frame.payload)
                (self.scans if isinstance(msg, m.ScanMessage) else self.replies).append(msg)

    def health(self) -> m.Health:
        self.replies.clear()
        self.send(m.GetHealth())
        for _ in range(20):
            self.pump(0.05)
            got = [r for r in self.replies if isinstance(r, m.Health)]
            if got:
                return got[-1]
        raise AssertionError("no HEALTH reply")


def device_config() -> DeviceConfig:
    return DeviceConfig(laser_limit_mw=5.0, settings=settings(), queue_scans=2)


def run_supervised(open_port, rig: FakeRig):
    src, *_ = make_source(rig)
    sup = LinkSupervisor(open_port, src, device_config())
    stop = threading.Event()
    t = threading.Thread(target=sup.run, args=(stop,), daemon=True)
    t.start()
    return sup, stop, t


def scanning_host(rig: FakeRig) -> tuple[LinkSupervisor, threading.Event, threading.Thread, Host]:
    """A supervised source on an in-memory link, and a host that started it and read for 0.3 s."""
    host_end, dev_end = pipe_pair()
    sup, stop, t = run_supervised(lambda: dev_end, rig)
    host = Host(host_end)
    host.send(m.Start())
    host.pump(0.3)
    return sup, stop, t, host


def first_health_with(host: Host, error: m.ErrorCode, until: float):
    """The first HEALTH reporting ``error`` before time.monotonic() reaches ``until``, else None."""
    while time.monotonic() < until:
        h = host.health()
        if error in h.errors:
            return h
    return None


def health_after_resuming(host: Host, scans_before: int, seconds: float):
    """Reads until 4 more scans came and HEALTH is clear with the laser on (or ``seconds`` pass)."""
    deadline = time.monotonic() + seconds
    h = host.health()
    while time.monotonic() < deadline and (len(host.scans) < scans_before + 4 or h.errors or not h.laser_on):
        host.pump(0.2)
        h = host.health()
    return h


def test_host_garbage_and_half_frames_are_counted_and_scanning_continues():
    rig = FakeRig()
    sup, stop, t, host = scanning_host(rig)
    before = len(host.scans)
    assert before >= 3
    h0 = host.health()
    assert h0.host_bytes_discarded == 0 and h0.host_frames_rejected == 0 and h0.host_sessions == 1
    rng = np.random.default_rng(1)
    half = encode_frame(m.MsgType.GET_INFO, 99, m.GetInfo().encode())[:6]
    host.port.write(rng.integers(1, 256, 300, dtype=np.uint8).tobytes() + b"\x00" + half + b"\x00" + half)
    host.port.write(b"\x00")
    host.pump(0.3)
    health = host.health()
    assert health.state == m.DeviceState.SCANNING and health.laser_on and health.errors == ()
    assert len(host.scans) >= before + 3
    ph = sup.health()
    assert ph.host_bytes_discarded >= 300 and ph.host_frames_rejected >= 2
    # the same counts reach the host in HEALTH: 300 garbage bytes, then two half frames
    assert health.host_bytes_discarded == ph.host_bytes_discarded >= 300 + 2 * len(half)
    assert health.host_frames_rejected == ph.host_frames_rejected >= 3
    assert health.scans_sent > h0.scans_sent and health.host_sessions == 1
    assert all(s.ranges_m.shape == (N_POINTS,) for s in host.scans)
    stop.set()
    t.join(3)
    assert not t.is_alive() and rig.lit_parity is None


def test_health_message_reports_a_camera_stall_while_it_lasts():
    rig = FakeRig()
    sup, stop, t, host = scanning_host(rig)
    h0 = host.health()
    assert h0.camera_restarts == 0 and h0.errors == ()
    rig.stall_until = time.monotonic() + 1.0
    seen = first_health_with(host, m.ErrorCode.CAMERA_FAULT, rig.stall_until)
    assert seen is not None, "HEALTH never reported the stalled camera"
    assert not seen.laser_on
    n = len(host.scans)
    h = health_after_resuming(host, n, 4.0)
    assert len(host.scans) >= n + 4, "the scan stream did not resume"
    assert h.errors == () and h.laser_on and h.state == m.DeviceState.SCANNING
    assert h.camera_restarts >= 1 and h.camera_restarts == sup.health().source.camera_restarts
    assert h.comcu_resets == h.comcu_lost == h.pipeline_errors == 0
    stop.set()
    t.join(3)


def test_health_message_reports_a_comcu_reset_until_the_laser_is_resynchronised():
    rig = FakeRig()
    sup, stop, t, host = scanning_host(rig)
    h0 = host.health()
    assert h0.comcu_resets == 0 and h0.errors == () and h0.laser_on
    rig.mcu_reset_pending = True
    seen = first_health_with(host, m.ErrorCode.LASER_FAULT, time.monotonic() + 2.0)
    assert seen is not None, "HEALTH never reported the co-MCU reset"
    assert m.ErrorCode.SYNC_LOST in seen.errors and not seen.laser_on and not seen.sync_locked
    assert seen.comcu_resets == 1
    n = len(host.scans)
    h = health_after_resuming(host, n, 3.0)
    assert h.errors == () and h.laser_on and h.sync_locked, "the code did not clear after the re-sync"
    assert len(host.scans) >= n + 4, "the scan stream did not resume"
    assert h.comcu_resets == 1 and h.comcu_lost == 0 and h.camera_restarts == 0
    stop.set()
    t.join(3)


def test_health_message_reports_pipeline_failures_and_the_code_clears_after():
    sup, stop, t, host = scanning_host(FakeRig())
    good = sup.source.pipeline
    failing = threading.Event()

    def flaky(lit, dark, other_dark):
        if failing.is_set():
            raise RuntimeError("numerical trouble")
        return good(lit, dark, other_dark)

    sup.source.pipeline = flaky
    failing.set()
    host.pump(0.3)
    h = host.health()
    assert m.ErrorCode.PIPELINE_FAULT in h.errors and h.pipeline_errors >= 2 and h.state == m.DeviceState.SCANNING
    failing.clear()
    n = len(host.scans)
    host.pump(0.3)
    h2 = host.health()
    assert m.ErrorCode.PIPELINE_FAULT not in h2.errors and len(host.scans) >= n + 3
    assert h2.pipeline_errors == sup.health().source.pipeline_errors >= h.pipeline_errors
    stop.set()
    t.join(3)


def test_health_message_reports_a_saturated_camera_while_it_lasts():
    """A pipeline that found columns saturated by bright light (ScanPipeline counts them): error
    SATURATED from its first scan with any until SATURATED_CLEAR_SCANS scans in a row have none;
    scanning goes on."""
    sup, stop, t, host = scanning_host(FakeRig())
    good = sup.source.pipeline
    bright = threading.Event()

    def lamp_in_view(lit, dark, other_dark):
        rays = good(lit, dark, other_dark)
        return dataclasses.replace(rays, saturated_columns=120) if bright.is_set() else rays

    sup.source.pipeline = lamp_in_view
    assert m.ErrorCode.SATURATED not in host.health().errors
    bright.set()
    n = len(host.scans)
    host.pump(0.3)
    h = host.health()
    assert m.ErrorCode.SATURATED in h.errors and h.state == m.DeviceState.SCANNING and len(host.scans) >= n + 3
    bright.clear()
    host.pump(0.1)  # fewer clear scans than SATURATED_CLEAR_SCANS: it holds (no flapping)
    assert m.ErrorCode.SATURATED in host.health().errors
    host.pump(0.5)
    assert m.ErrorCode.SATURATED not in host.health().errors
    stop.set()
    t.join(3)


def test_slow_link_drops_whole_scans_and_counts_them():
    host_end, dev_end = pipe_pair()
    rig = FakeRig(fps=80.0)  # 40 scans/s of ~130 bytes on a 9600-baud link carrying ~7 of them
    sup, stop, t = run_supervised(lambda: PacedPort(dev_end, 9600), rig)
    host = Host(host_end)
    host.send(m.Start())
    host.pump(1.5)
    h = host.health()  # control replies go ahead of queued scans
    stop.set()
    t.join(3)
    ph = sup.health()
    assert ph.scans_dropped > 10
    assert 10 < h.scans_dropped <= ph.scans_dropped and h.scans_sent <= ph.scans_sent
    assert all(s.ranges_m.shape == (N_POINTS,) for s in host.scans)
    seqs = [s.scan_seq for s in host.scans]
    assert seqs == sorted(seqs)
    # every scan made is either sent, dropped on the link, or still in flight at the stop
    assert ph.source.scans_made - ph.scans_sent - ph.scans_dropped <= 3


def reopenable_link() -> tuple[list, object]:
    """The host ends of the in-memory links opened so far, and the supervisor's ``open_port``."""
    opened = []

    def open_port():
        host_end, dev_end = pipe_pair()
        opened.append(host_end)
        return dev_end

    return opened, open_port


def test_a_failing_port_is_reopened_and_a_new_session_served():
    opened, open_port = reopenable_link()
    rig = FakeRig()
    sup, stop, t = run_supervised(open_port, rig)
    time.sleep(0.2)
    first = Host(opened[0])
    first.send(m.Start())
    first.pump(0.3)
    h1 = first.health()
    assert h1.scans_sent >= 3 and h1.host_sessions == 1
    opened[0].close()  # host unplugged: the port raises PortClosed
    deadline = time.monotonic() + 3
    while len(opened) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(opened) >= 2 and sup.sessions >= 2
    host = Host(opened[-1])
    host.send(m.Start())
    host.pump(0.4)
    received = len(host.scans)
    assert received >= 3
    h2 = host.health()  # totals of the process, not of the session: they keep counting
    assert h2.host_sessions == len(opened) >= 2
    assert h2.scans_sent >= h1.scans_sent + received
    stop.set()
    t.join(3)
    assert rig.lit_parity is None


@pytest.fixture
def session_checks(monkeypatch) -> list:
    """One entry for every look at whether a link session has ended (LinkServer.stopped)."""
    from protocol.server import LinkServer

    checks = []
    monkeypatch.setattr(LinkServer, "stopped", property(lambda self: checks.append(1) or self._stop.is_set()))
    return checks


def test_the_supervisor_sleeps_through_a_session_and_wakes_for_its_end_and_for_stop(session_checks):
    # Each timed wake-up of a thread costs CPU (~0.1 ms on the machine of BENCHMARKS.md "Device
    # process"): between health reports the supervisor waits for the session's end or the stop,
    # not polling. Its checks of the session are counted; a 10 Hz poll made ~10 a second.
    opened, open_port = reopenable_link()
    rig = FakeRig()
    sup, stop, t = run_supervised(open_port, rig)
    time.sleep(1.0)
    assert len(opened) == 1 and len(session_checks) <= 2
    opened[0].close()  # the session ends: the supervisor wakes and opens a new one
    deadline = time.monotonic() + 1.0
    while len(opened) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(opened) == 2
    stop.set()
    t.join(1.0)
    assert not t.is_alive()  # the stop woke it (health_log_s is 10 s)


def test_a_thread_that_outlives_its_session_does_not_keep_the_supervisor_awake(session_checks):
    # The first session's writer is stuck in a write (a serial write without a timeout to a host
    # that stopped reading) past close()'s 2 s join, and fails after its port is closed: its
    # on_stop comes during the second session, which must then sleep again, not spin.

    class StuckWriter:
        def __init__(self, port):
            self.port, self.closed = port, threading.Event()

        def read(self, size=4096):
            return self.port.read(size)

        def write(self, data):
            self.closed.wait()
            time.sleep(0.3)
            raise OSError("write on a closed port")

        def close(self):
            self.port.close()
            self.closed.set()

    opened, open_link = reopenable_link()
    sup, stop, t = run_supervised(lambda: StuckWriter(open_link()) if not opened else open_link(), FakeRig())
    time.sleep(0.2)
    Host(opened[0]).send(m.GetInfo())  # the reply's write blocks
    time.sleep(0.3)
    opened[0].close()  # the host is gone: the reader fails, the session ends
    deadline = time.monotonic() + 5
    while len(opened) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(opened) == 2
    time.sleep(0.6)  # the stuck writer's late failure has called the first session's on_stop
    before = len(session_checks)
    time.sleep(0.5)
    assert len(session_checks) - before <= 2
    stop.set()
    t.join(2.0)
    assert not t.is_alive()
