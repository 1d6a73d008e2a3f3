"""Device end of the link: settings checks, request handling, bounded scan queue, source faults."""

import time

import numpy as np
import pytest

from protocol import messages as m
from protocol.framing import encode_frame
from protocol.mock_wall import AnalyticWallSource, default_settings, wall_ranges
from protocol.ports import pipe_pair
from protocol.server import DeviceConfig, LinkServer, ScanGeometry, SourceScan, SourceStatus, settings_refusal
from protocol.stream import StreamDecoder

N = 32


def config(**kw):
    return DeviceConfig(laser_limit_mw=5.0, settings=default_settings(N), **kw)


@pytest.mark.parametrize("change, code, words", [
    (dict(laser_power_mw=5.01), m.NackCode.EYE_SAFETY, "Class 1 limit of 5 mW"),
    (dict(laser_power_mw=-1.0), m.NackCode.OUT_OF_RANGE, "negative"),
    (dict(scan_rate_hz=100.0), m.NackCode.OUT_OF_RANGE, "scan_rate_hz 100"),
    (dict(scan_rate_hz=20.0, exposure_us=30_000), m.NackCode.OUT_OF_RANGE, "longer than a frame"),
    (dict(roi_first=30, roi_count=3), m.NackCode.OUT_OF_RANGE, "region of interest"),
    (dict(roi_count=0), m.NackCode.OUT_OF_RANGE, "region of interest"),
    (dict(median_window=4), m.NackCode.OUT_OF_RANGE, "odd"),
])
def test_settings_refusal_names_the_setting(change, code, words):
    s = default_settings(N).merged(m.ScanSettings(**change))
    got = settings_refusal(s, config(), N)
    assert got is not None and got[0] == code and words in got[1]


def test_power_on_settings_are_acceptable():
    assert settings_refusal(default_settings(N), config(), N) is None


class Host:
    """The host side of a pipe, speaking raw frames."""

    def __init__(self, end):
        self.end, self.dec, self.seq = end, StreamDecoder(), 0

    def send(self, msg):
        self.seq += 1
        self.end.write(b"\x00" + encode_frame(msg.TYPE, self.seq, msg.encode()))
        return self.seq

    def receive(self, until, timeout=2.0):
        out, deadline = [], time.monotonic() + timeout
        while time.monotonic() < deadline:
            for rec in self.dec.feed(self.end.read(4096)):
                out.append(m.decode_message(rec.frame.msg_type, rec.frame.payload))
                if until(out):
                    return out
        raise AssertionError(f"timed out; got {[type(x).__name__ for x in out]}")


@pytest.fixture
def link():
    host_end, dev_end = pipe_pair()
    source = AnalyticWallSource(1.0, n_points=N, dropout=0.0, noise_floor_m=0.0, noise_rel_per_m=0.0)
    with LinkServer(dev_end, source, config()) as server:
        yield Host(host_end), server


def test_info_then_config_ack_and_nack(link):
    host, _ = link
    host.send(m.GetInfo())
    info = host.receive(lambda o: isinstance(o[-1], m.Info))[-1]
    assert info.angles.size == N and info.laser_limit_mw == 5.0 and info.settings == default_settings(N)
    seq = host.send(m.SetConfig(m.ScanSettings(laser_power_mw=7.0)))
    nack = host.receive(lambda o: isinstance(o[-1], m.Nack))[-1]
    assert (nack.request_seq, nack.code) == (seq, m.NackCode.EYE_SAFETY)
    seq = host.send(m.SetConfig(m.ScanSettings(laser_power_mw=2.0, roi_first=4, roi_count=8)))
    ack = host.receive(lambda o: isinstance(o[-1], m.Ack))[-1]
    assert ack.request_seq == seq
    host.send(m.GetInfo())
    info = host.receive(lambda o: isinstance(o[-1], m.Info))[-1]
    assert info.settings.laser_power_mw == 2.0 and info.settings.roi_count == 8


def test_refused_config_changes_nothing(link):
    host, server = link
    before = server.settings
    host.send(m.SetConfig(m.ScanSettings(scan_rate_hz=20.0, laser_power_mw=50.0)))
    host.receive(lambda o: isinstance(o[-1], m.Nack))
    assert server.settings == before


def test_unknown_and_malformed_requests_are_nacked(link):
    host, _ = link
    host.end.write(b"\x00" + encode_frame(0x3A, 1, b""))
    host.end.write(encode_frame(m.MsgType.SET_CONFIG, 2, b"\x01"))
    host.end.write(encode_frame(m.MsgType.SCAN, 3, b""))  # device->host message sent to the device
    nacks = host.receive(lambda o: sum(isinstance(x, m.Nack) for x in o) == 3)
    assert [n.code for n in nacks] == [m.NackCode.UNKNOWN_MESSAGE, m.NackCode.BAD_PAYLOAD, m.NackCode.BAD_PAYLOAD]


def test_scans_match_the_wall_and_stop_means_stop(link):
    host, server = link
    host.send(m.Start())
    got = host.receive(lambda o: sum(isinstance(x, m.ScanMessage) for x in o) >= 2)
    scan = [x for x in got if isinstance(x, m.ScanMessage)][-1]
    truth = wall_ranges(server.geometry.angles, 1.0)
    np.testing.assert_allclose(scan.ranges_m, truth, atol=m.RANGE_UNIT_M)
    seq = host.send(m.Stop())
    got = host.receive(lambda o: any(isinstance(x, m.Ack) and x.request_seq == seq for x in o))
    time.sleep(0.3)
    after = host.dec.feed(host.end.read(65536))
    assert not any(r.frame.msg_type == m.MsgType.SCAN for r in after)


class FastSource:
    """A source that has a scan ready at once, every time: a link can never keep up."""

    def __init__(self, fail_after=None):
        self.n, self.fail_after = 0, fail_after

    def geometry(self):
        return ScanGeometry(np.linspace(0.5, -0.5, 400, dtype=np.float32), 0.1, 3.0)

    def apply(self, settings):
        pass

    def start(self):
        pass

    def stop(self):
        pass

    def status(self):
        return SourceStatus(laser_on=True)

    def next_scan(self, timeout_s):
        self.n += 1
        if self.fail_after is not None and self.n > self.fail_after:
            raise RuntimeError("camera timeout")
        time.sleep(0.001)
        return SourceScan(self.n, np.full(400, 1.5, np.float32), np.full(400, 9, np.uint8))


def test_slow_link_drops_whole_scans_and_counts_them():
    host_end, dev_end = pipe_pair(capacity=4096)  # the host does not read: the pipe fills
    cfg = DeviceConfig(laser_limit_mw=5.0, settings=default_settings(400), queue_scans=3)
    with LinkServer(dev_end, FastSource(), cfg) as server:
        host = Host(host_end)
        host.send(m.Start())
        time.sleep(0.5)
        assert server.counters.scans_dropped > 10
        assert len(server._scans) <= 3
        # everything that did arrive is whole: every SCAN frame decodes to 400 points
        host.send(m.Stop())
        got = host.receive(lambda o: any(isinstance(x, m.Ack) and x.request_type == m.MsgType.STOP for x in o))
        scans = [x for x in got if isinstance(x, m.ScanMessage)]
        assert scans and all(s.ranges_m.size == 400 for s in scans)
        assert host.dec.stats.crc_errors == host.dec.stats.decode_errors == 0


def test_source_failure_is_reported_not_fatal():
    host_end, dev_end = pipe_pair()
    cfg = DeviceConfig(laser_limit_mw=5.0, settings=default_settings(400))
    with LinkServer(dev_end, FastSource(fail_after=3), cfg):
        host = Host(host_end)
        host.send(m.Start())
        logs = host.receive(lambda o: any(isinstance(x, m.Log) for x in o))
        assert "camera timeout" in [x for x in logs if isinstance(x, m.Log)][0].text
        host.send(m.GetHealth())
        health = host.receive(lambda o: isinstance(o[-1], m.Health))[-1]
        assert health.state == m.DeviceState.FAULT and m.ErrorCode.SOURCE_FAILED in health.errors


def test_server_stops_when_the_port_goes_away():
    host_end, dev_end = pipe_pair()
    server = LinkServer(dev_end, AnalyticWallSource(n_points=N), config()).start()
    host_end.close()
    deadline = time.monotonic() + 2
    while not server.stopped and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.stopped
    server.close()
    assert not any(t.is_alive() for t in server._threads)


def test_config_without_every_field_is_refused():
    with pytest.raises(ValueError, match="missing"):
        DeviceConfig(laser_limit_mw=1.0, settings=m.ScanSettings(scan_rate_hz=10.0))


def test_power_on_settings_above_the_limit_are_refused():
    with pytest.raises(ValueError, match="Class 1"):
        LinkServer(None, AnalyticWallSource(n_points=N), DeviceConfig(laser_limit_mw=1.0, settings=default_settings(N)))


@pytest.mark.parametrize("limit", [float("nan"), float("inf"), 0.0, -1.0])
def test_a_limit_that_would_let_every_power_through_is_refused(limit):
    """The EYE_SAFETY check is power > limit: a NaN limit made it False for every power."""
    with pytest.raises(ValueError, match="laser_limit_mw must be a finite power > 0 mW"):
        DeviceConfig(laser_limit_mw=limit, settings=default_settings(N, 0.0))


class LatestFirstSource(FastSource):
    """Scans whose rays were measured latest first: a negative ray interval."""

    def next_scan(self, timeout_s):
        time.sleep(0.01)
        return SourceScan(1_000_000, np.full(400, 1.5, np.float32), np.full(400, 9, np.uint8), ray_interval_ns=-2_000)


@pytest.mark.parametrize("host_minor, want", [
    (3, (1_000_000, -2_000)),                             # as measured
    (2, (1_000_000 - 399 * 2_000 // 2 // 1000, 0)),       # its middle time, no step: read unsigned there
])
def test_a_negative_ray_interval_goes_only_to_a_host_that_reads_it_signed(host_minor, want):
    host_end, dev_end = pipe_pair()
    cfg = DeviceConfig(laser_limit_mw=5.0, settings=default_settings(400))
    with LinkServer(dev_end, LatestFirstSource(), cfg):
        host = Host(host_end)
        host.send(m.GetInfo(1, host_minor))
        host.receive(lambda o: isinstance(o[-1], m.Info))
        host.send(m.Start())
        scan = host.receive(lambda o: isinstance(o[-1], m.ScanMessage))[-1]
        assert (scan.device_time_us, scan.ray_interval_ns) == want


def test_scan_time_for_host_leaves_what_every_host_reads_alone():
    assert m.scan_time_for_host(5_000, 1_500, 100, 0) == (5_000, 1_500)
    assert m.scan_time_for_host(5_000, -1_500, 100, 3) == (5_000, -1_500)
    assert m.scan_time_for_host(5_000, -2_000, 101, 2) == (5_000 - 100, 0)  # the middle ray (50) is 100 us earlier


# --- ray times (protocol minor 4) --------------------------------------------------------------
RAYS = np.arange(400)
#: a scan's rays measured out of order in time (the rows of a depth jump), some without a time
RAY_TIMES_NS = np.where(RAYS % 9 == 4, np.nan, 1e9 + 1000.0 * ((RAYS * 37) % 2000) + 0.3 * RAYS)


class TimedSource(FastSource):
    """Scans whose rays have their own times, off the line through them."""

    def next_scan(self, timeout_s):
        time.sleep(0.01)
        return SourceScan(1_000_000, np.full(400, 1.5, np.float32), np.full(400, 9, np.uint8),
                          ray_interval_ns=2_000, ray_times_ns=RAY_TIMES_NS)


def _timed_link(**kw):
    host_end, dev_end = pipe_pair()
    return Host(host_end), LinkServer(dev_end, TimedSource(), DeviceConfig(laser_limit_mw=5.0,
                                                                            settings=default_settings(400), **kw))


def _scan_payloads(host, count=2):
    """The next ``count`` SCAN payloads as they arrived (raw, to see what an older host reads)."""
    out, deadline = [], time.monotonic() + 2.0
    while len(out) < count and time.monotonic() < deadline:
        out += [r.frame.payload for r in host.dec.feed(host.end.read(65536)) if r.frame.msg_type == m.MsgType.SCAN]
    assert len(out) >= count
    return out


def test_ray_times_go_to_a_host_of_minor_4_that_asked_and_to_no_other():
    host, server = _timed_link()
    with server:
        host.send(m.GetInfo(1, 4, request_id=1))
        assert host.receive(lambda o: isinstance(o[-1], m.Info))[-1].settings.ray_times is False
        host.send(m.SetConfig(m.ScanSettings(ray_times=True), request_id=2))
        assert isinstance(host.receive(lambda o: isinstance(o[-1], (m.Ack, m.Nack)))[-1], m.Ack)
        host.send(m.GetInfo(1, 4, request_id=3))
        assert host.receive(lambda o: isinstance(o[-1], m.Info))[-1].settings.ray_times is True
        host.send(m.Start(request_id=4))
        scan = m.ScanMessage.decode(_scan_payloads(host)[-1])
        assert np.array_equal(np.isnan(scan.ray_times_us), np.isnan(RAY_TIMES_NS))
        ok = ~np.isnan(RAY_TIMES_NS)
        assert np.abs(scan.ray_times_us[ok] - RAY_TIMES_NS[ok] / 1000).max() <= 0.5  # to the µs
        # the same link now asked by a host of minor 3: neither INFO nor SCAN carries a byte of it
        host.send(m.GetInfo(1, 3, request_id=5))
        info = [x for x in host.receive(lambda o: isinstance(o[-1], m.Info)) if isinstance(x, m.Info)][-1]
        assert info.settings.ray_times is None and server.settings.ray_times is True
        time.sleep(0.1)
        host.end.read(1 << 20)  # scans queued before the GET_INFO
        host.dec = StreamDecoder()
        payload = _scan_payloads(host, 3)[-1]
        assert len(payload) == m.SCAN_HEADER_SIZE + 3 * 400 + m.SCAN_TRAILER_SIZE
        assert m.ScanMessage.decode(payload).ray_times_us is None


@pytest.mark.parametrize("host_minor", [None, 3])  # None: the host never sent GET_INFO
def test_a_host_that_did_not_say_minor_4_cannot_turn_ray_times_on(host_minor):
    host, server = _timed_link()
    with server:
        if host_minor is not None:
            host.send(m.GetInfo(1, host_minor, request_id=1))
            host.receive(lambda o: isinstance(o[-1], m.Info))
        host.send(m.SetConfig(m.ScanSettings(ray_times=True), request_id=2))
        nack = host.receive(lambda o: isinstance(o[-1], (m.Ack, m.Nack)))[-1]
        assert isinstance(nack, m.Nack) and nack.code == m.NackCode.NOT_SUPPORTED
        assert "ray_times needs a host of protocol minor >= 4" in nack.reason
        assert f"said minor {host_minor or 0}" in nack.reason
        assert server.settings.ray_times is False
        host.send(m.SetConfig(m.ScanSettings(ray_times=False), request_id=3))  # off is always possible
        assert isinstance(host.receive(lambda o: isinstance(o[-1], (m.Ack, m.Nack)))[-1], m.Ack)
        host.send(m.Start(request_id=4))
        assert m.ScanMessage.decode(_scan_payloads(host)[-1]).ray_times_us is None


def test_a_host_of_minor_3_is_not_refused_for_ray_times_another_host_left_on():
    # 400 points at 250 kbit/s: 10 scans/s fit with ray times, 15 only without them
    host, server = _timed_link(link_rate_bps=250_000)
    with server:
        host.send(m.GetInfo(1, 4, request_id=1))
        host.receive(lambda o: isinstance(o[-1], m.Info))
        host.send(m.SetConfig(m.ScanSettings(ray_times=True), request_id=2))
        assert isinstance(host.receive(lambda o: isinstance(o[-1], (m.Ack, m.Nack)))[-1], m.Ack)
        host.send(m.GetInfo(1, 3, request_id=3))  # another host, which knows nothing of ray times
        host.receive(lambda o: isinstance(o[-1], m.Info))
        host.send(m.SetConfig(m.ScanSettings(scan_rate_hz=15.0), request_id=4))
        answer = host.receive(lambda o: isinstance(o[-1], (m.Ack, m.Nack)))[-1]
        assert isinstance(answer, m.Ack), answer
        assert server.settings.ray_times is False and server.settings.scan_rate_hz == 15.0


def test_a_source_without_ray_times_sends_every_ray_on_the_line():
    host_end, dev_end = pipe_pair()
    with LinkServer(dev_end, LatestFirstSource(), DeviceConfig(laser_limit_mw=5.0, settings=default_settings(400))):
        host = Host(host_end)
        host.send(m.GetInfo(1, 4, request_id=1))
        host.receive(lambda o: isinstance(o[-1], m.Info))
        host.send(m.SetConfig(m.ScanSettings(ray_times=True), request_id=2))
        host.receive(lambda o: isinstance(o[-1], m.Ack))
        host.send(m.Start(request_id=3))
        assert np.isnan(m.ScanMessage.decode(_scan_payloads(host)[-1]).ray_times_us).all()


def test_the_device_refuses_ray_times_that_do_not_fit_its_link_by_name():
    uart = DeviceConfig(laser_limit_mw=5.0, settings=default_settings(1640), link_rate_bps=921600)
    with_times = default_settings(1640).merged(m.ScanSettings(ray_times=True))
    assert settings_refusal(with_times, uart, 1640) is None  # 10 scans/s fit
    for rate in (15.0, 20.0):
        code, reason = settings_refusal(with_times.merged(m.ScanSettings(scan_rate_hz=rate)), uart, 1640)
        assert code == m.NackCode.OUT_OF_RANGE and "1640 points with ray times (ray_times)" in reason
    assert settings_refusal(default_settings(1640).merged(m.ScanSettings(scan_rate_hz=15.0)), uart, 1640) is None
    with pytest.raises(ValueError, match="power-on settings .* with ray times"):
        DeviceConfig(laser_limit_mw=5.0, settings=with_times.merged(m.ScanSettings(scan_rate_hz=15.0)),
                     link_rate_bps=921600)
