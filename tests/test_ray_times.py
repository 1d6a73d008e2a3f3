"""Each ray's own time end to end (issue 16, protocol minor 4): the rows of a simulated lit frame
-> the device's pipeline and scan source -> the real LinkServer on a pty -> LaserPi ->
Scan.ray_times, against column_times_ns of that lit frame; the SDK's mock device, an older device,
and record and replay."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import host_sdk
from device.camera.frame import Frame
from device.scan.timing import column_times_ns
from host_sdk.errors import CommandRefused
from host_sdk.replay_link import ReplayServer
from protocol import messages as m
from protocol.framing import decode_frame, encode_frame
from protocol.ports import PacedPort, PtyLink
from protocol.server import DeviceConfig, LinkServer, ScanGeometry
from tests.link_rig import Rig

POINTS = 400
FRAME_US = 50_000.0
EXPOSURE_US = 9_200.0


class FrameLoop:
    """Camera: a simulated scene's unlit, lit, unlit frames again and again, one every FRAME_US,
    stamped with the device clock when they are captured (odd seq: lit)."""

    def __init__(self, pair, line_ns: float):
        self.pair, self.line_ns = pair, line_ns
        self.seq, self.next_at = 0, 0.0

    def start(self) -> None:
        self.seq, self.next_at = 0, time.monotonic()

    def stop(self) -> None:
        pass

    def capture(self, timeout_s: float) -> Frame | None:
        wait = self.next_at - time.monotonic()
        if wait > timeout_s:
            time.sleep(timeout_s)
            return None
        time.sleep(max(wait, 0.0))
        self.next_at += FRAME_US * 1e-6
        self.seq += 1
        image = (self.pair.lit if self.seq % 2 else (self.pair.unlit if self.seq % 4 else self.pair.unlit_before)).image
        return Frame(image, self.seq, time.monotonic_ns(), EXPOSURE_US, FRAME_US, self.line_ns, readout_offset_rows=155)


class OddFramesLit:
    """Laser: locked, lights every odd frame."""

    locked = True

    def start(self, frame: Frame) -> None:
        return None

    def stop(self) -> None:
        pass

    def frame_lit(self, frame: Frame) -> bool:
        return frame.seq % 2 == 1


class Recorded:
    """The vision pipeline, keeping each lit frame and its measurements."""

    def __init__(self, pipeline):
        self.pipeline, self.geometry = pipeline, pipeline.geometry
        self.seen: list[tuple] = []

    def process(self, lit, unlit, other_unlit=None):
        meas = self.pipeline.process(lit, unlit, other_unlit=other_unlit)
        self.seen.append((lit, meas))
        return meas


@pytest.fixture(scope="module")
def device(tmp_path_factory):
    """The device's own scan source on a simulated office (depth jumps: rays far off their line)
    behind the real LinkServer on a pty at 921600 baud."""
    from device.config import load_preset
    from device.scan.pipeline import ScanPipeline
    from device.scan.source import SensorSource
    from device.vision.evaluation import simulated_pairs
    from device.vision.pipelines import make_pipeline

    cfg = load_preset("thesis-calibrated")
    op = cfg.operating_point
    pair = simulated_pairs(cfg, "office", 1, neighbours=True)[0]
    recorded = Recorded(make_pipeline("fast-com", cfg, op.min_m, op.max_m))
    scan = ScanPipeline(recorded, POINTS)
    geometry = ScanGeometry(scan.angles.astype(np.float32), op.min_m, op.max_m)
    source = SensorSource(FrameLoop(pair, cfg.window.mode.line_time_ns), OddFramesLit(), scan, geometry)
    settings = m.ScanSettings(scan_rate_hz=10.0, exposure_us=int(EXPOSURE_US), roi_first=0, roi_count=POINTS,
                              median_window=1, min_quality=0, laser_power_mw=1.0, ray_times=False)
    link = tmp_path_factory.mktemp("pty") / "laserpi"
    pty = PtyLink(link)
    server = LinkServer(PacedPort(pty.port, 921600), source,
                        DeviceConfig(laser_limit_mw=5.0, settings=settings, link_rate_bps=921600)).start()
    yield str(link), recorded
    server.close()
    pty.close()


def expected_ray_times_s(scan, recorded: Recorded) -> np.ndarray:
    """What each ray's time must be: the mid-exposure of the row its line was found in, in the
    lit frame the scan was made of (device/scan/timing.py), taken from the measured column
    nearest to the ray's bearing (a ray's range comes from the measured columns either side of
    it); a ray without a return is on the scan's line. Every ray with a return has a time."""
    lit, meas = min(recorded.seen, key=lambda s: abs(s[0].sensor_timestamp_ns * 1e-9 - scan.device_time))
    angle = np.asarray(meas.angle, dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(angle) & np.isfinite(meas.range))
    nearest = ok[np.argmin(np.abs(angle[ok][None, :] - scan.angles[:, None].astype(np.float64)), axis=1)]
    times = column_times_ns(lit, np.asarray(meas.row, dtype=np.float64)[nearest]) * 1e-9
    assert np.isfinite(times[np.isfinite(scan.ranges)]).all()
    line = scan.device_time + np.arange(scan.ranges.size) * scan.time_increment
    return np.where(np.isfinite(scan.ranges), times, line)


def test_each_rays_time_reaches_the_host_exactly_from_the_rows_of_the_lit_frame(device):
    link, recorded = device
    with host_sdk.LaserPi(link, timeout_s=3.0) as sensor:
        assert sensor.info().settings.ray_times is False
        assert sensor.configure(ray_times=True).ray_times is True
        scans = []
        for scan in sensor.scans():
            scans.append(scan)
            if len(scans) == 3:
                break
        sensor.stop()
        sensor.configure(roi_first=100, roi_count=200)  # the host's region of interest: its rays' own times
        for roi in sensor.scans():
            break
        sensor.stop()
        assert sensor.configure(ray_times=False).ray_times is False
        for plain in sensor.scans():
            break
    residual = 0.0
    for scan in scans + [roi]:
        want = expected_ray_times_s(scan, recorded)
        assert scan.ray_times.dtype == np.float64 and scan.ray_times.shape == scan.ranges.shape
        assert np.abs(scan.ray_times - want).max() <= 0.6e-6  # whole µs on the wire
        assert np.isfinite(scan.ranges).sum() > POINTS / 4
        line = scan.device_time + np.arange(scan.ranges.size) * scan.time_increment
        residual = max(residual, float(np.abs(scan.ray_times - line)[np.isfinite(scan.ranges)].max()))
    assert roi.angles.size == 200 and np.array_equal(roi.angles, scans[0].angles[100:300])
    # the line is off by much more than the µs the times carry: they are each ray's own
    assert residual > 200e-6
    assert plain.ray_times is None


def test_the_sdks_mock_device_sends_ray_times_and_crop_keeps_them(tmp_path):
    with Rig("sim", tmp_path, points=64) as rig, rig.open() as sensor:
        for scan in sensor.scans():
            break
        assert scan.ray_times is None  # off at power-on
        sensor.stop()
        sensor.configure(ray_times=True)
        for scan in sensor.scans():
            break
        # a wall seen squarely lies in one row: every ray at the scan's time, as the line says
        assert np.array_equal(scan.ray_times, np.full(64, scan.device_time))
        cropped = scan.cropped(angle_min=-0.2, angle_max=0.2)
        keep = (scan.angles >= cropped.angles.min()) & (scan.angles <= cropped.angles.max())
        assert cropped.ray_times.size == cropped.angles.size == keep.sum()
        assert np.array_equal(cropped.ray_times, scan.ray_times[keep])


def test_an_older_device_is_not_asked_for_ray_times(tmp_path):
    with Rig("pty", tmp_path, old=True) as rig, rig.open() as sensor:
        assert sensor.info().protocol_minor == 1
        with pytest.raises(CommandRefused, match="ray_times needs a device of protocol minor >= 4") as exc:
            sensor.configure(ray_times=True)
        assert exc.value.code == m.NackCode.NOT_SUPPORTED
        for scan in sensor.scans():
            break
        assert scan.ray_times is None


def test_ray_times_are_recorded_and_replayed(tmp_path):
    from host_sdk.recording import RecordingHeader, RecordingWriter

    path = tmp_path / "times.lpr"
    with Rig("sim", tmp_path, points=64) as rig, RecordingWriter(path, RecordingHeader(921600, 0, 0, "sim")) as rec:
        lock = threading.Lock()

        def tap(t_ns, data):
            with lock:
                rec.write(t_ns, data)

        with rig.open(tap=tap) as sensor:
            sensor.configure(ray_times=True)
            live = []
            for scan in sensor.scans():
                live.append(scan)
                if len(live) == 3:
                    break
    replayed = {s.seq: s for s in host_sdk.replay(path)}
    assert all(s.ray_times is not None for s in replayed.values())
    for scan in live:
        assert np.array_equal(replayed[scan.seq].ray_times, scan.ray_times)
    # served again (laserpi replay --link): a host of minor < 4 gets an INFO it can read
    server = ReplayServer(WrittenPort(), path)
    assert server.info.settings.ray_times is not None  # the recorded INFO, asked by a host of minor 4
    for minor, want in ((4, server.info.settings.ray_times), (3, None)):
        server._answer(decode_frame(encode_frame(m.MsgType.GET_INFO, 1, m.GetInfo(1, minor, 9).encode())[:-1]))
        info = m.Info.decode(decode_frame(server.port.written.pop().strip(b"\x00")).payload)
        assert info.settings.ray_times is want and info.request_id == 9


class WrittenPort:
    def __init__(self):
        self.written = []

    def write(self, data):
        self.written.append(data)
