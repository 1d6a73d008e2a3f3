"""Host SDK against the in-process mock device (sim://): API, ground truth, time stamps, failures."""

import threading
import time

import numpy as np
import pytest

import host_sdk
from protocol import messages as m
from protocol.mock_wall import wall_ranges

QUIET = "sim://wall?distance=2.0&noise=0&points=200"


def test_info_health_and_geometry():
    with host_sdk.LaserPi(QUIET) as s:
        info = s.info()
        assert info.protocol_major == 1 and info.angles.size == 200
        assert info.angles[0] > 0 > info.angles[-1]  # column 0 looks left: CCW positive
        h = s.health()
        assert h.state == m.DeviceState.IDLE and not h.laser_on
        s.start()
        assert s.health().state == m.DeviceState.SCANNING


def test_scans_match_ground_truth_without_noise():
    with host_sdk.LaserPi(QUIET) as s:
        scan = next(iter(s.scans()))
    truth = wall_ranges(scan.angles, 2.0)
    truth = np.where(truth > scan.range_max, np.inf, truth)
    fin = np.isfinite(truth)
    assert np.array_equal(np.isposinf(scan.ranges), ~fin)  # REP 117: beyond range_max = +inf
    np.testing.assert_allclose(scan.ranges[fin], truth[fin], atol=m.RANGE_UNIT_M)
    xy = scan.points()
    np.testing.assert_allclose(xy[fin, 0], 2.0, atol=m.RANGE_UNIT_M)  # the wall is x = 2 m
    assert np.isnan(xy[~fin]).all() and xy.shape == (200, 2)


def test_noisy_scans_are_within_the_noise_model():
    with host_sdk.LaserPi("sim://wall?distance=1.5&points=400&seed=3") as s:
        it = s.scans()
        scans = [next(it) for _ in range(3)]
    r = np.concatenate([sc.ranges for sc in scans])
    truth = np.tile(wall_ranges(scans[0].angles, 1.5), 3)
    fin = np.isfinite(r) & np.isfinite(truth)
    sigma = 0.001 + 0.0025 * truth[fin] ** 2
    z = (r[fin] - truth[fin]) / sigma
    assert abs(z.mean()) < 0.2 and 0.8 < z.std() < 1.2
    assert 0 < np.isnan(r).mean() < 0.05  # 1 % dropouts, reported as invalid


def test_time_stamps_are_corrected_for_transmission_and_age():
    """In sim:// the device clock is this process's monotonic clock: ground truth for stamps.
    At 115200 baud a 1640-point frame takes 0.43 s on the wire; the stamp must not carry that."""
    with host_sdk.LaserPi("sim://wall?points=1640&rate=2", baudrate=115200, timeout_s=2.0) as s:
        it = s.scans()
        errors = [sc.stamp - sc.device_time for sc in (next(it) for _ in range(4))]
    assert max(abs(e) for e in errors) < 0.01, errors  # uncorrected, they would be ~0.43 s


def test_configure_applies_or_refuses_with_reason():
    with host_sdk.LaserPi(QUIET) as s:
        new = s.configure(scan_rate_hz=20.0, roi_first=50, roi_count=20)
        assert (new.scan_rate_hz, new.roi_count) == (20.0, 20)
        scan = next(iter(s.scans()))
        assert scan.ranges.size == 20 and scan.angles[0] == s.info().angles[50]
        with pytest.raises(host_sdk.CommandRefused) as exc:
            s.configure(laser_power_mw=s.info().laser_limit_mw * 2)
        assert exc.value.code == m.NackCode.EYE_SAFETY and "Class 1" in exc.value.reason
        assert s.info(refresh=True).settings.laser_power_mw <= s.info().laser_limit_mw
        with pytest.raises(ValueError, match="unknown settings"):
            s.configure(power=1)


def test_slow_consumer_gets_newest_scans_and_a_count_of_the_dropped():
    with host_sdk.LaserPi("sim://wall?points=100&rate=30&noise=0", queue_scans=2) as s:
        it = s.scans()
        first = next(it)
        time.sleep(0.6)  # ~18 scans arrive meanwhile
        a, b = next(it), next(it)
        assert s.stats.scans_dropped >= 10
        assert len(s._scans) <= 2
        assert a.seq - first.seq > 10 and b.seq == a.seq + 1


def test_unplug_raises_disconnected():
    with host_sdk.LaserPi("sim://wall?points=100&unplug_after=0.5") as s:
        with pytest.raises(host_sdk.DisconnectedError, match="disconnected"):
            for _ in s.scans():
                pass
        with pytest.raises(host_sdk.DisconnectedError):
            s.health()


def test_no_scan_within_timeout_raises_device_timeout():
    with host_sdk.LaserPi(QUIET, timeout_s=0.3) as s:
        s.configure(scan_rate_hz=1.0)
        it = s.scans()
        next(it)
        with pytest.raises(host_sdk.DeviceTimeout, match="no scan"):
            next(it)


@pytest.mark.parametrize("port, words", [
    ("/dev/does-not-exist-laserpi", "plugged in"),
    ("sim://wall?distance=abc", "not a float"),
    ("sim://wall?colour=red", "unknown sim:// option"),
    ("sim://wall?distance=-1", "positive"),
    # the mock's eye-safety limit can only be lowered (100 served 100 mW; nan switched the check off)
    ("sim://wall?limit_mw=100", "limit_mw can only lower it"),
    ("sim://wall?limit_mw=nan", "limit_mw can only lower it"),
])
def test_bad_port_raises_port_error_naming_the_problem(port, words):
    with pytest.raises(host_sdk.PortError, match=words):
        host_sdk.LaserPi(port)


def test_two_sensors_on_two_threads_are_independent():
    results = {}

    def run(name, url):
        with host_sdk.LaserPi(url) as s:
            it = s.scans()
            results[name] = ([next(it) for _ in range(5)], s.stats.as_dict(), s.info().angles.size)

    threads = [threading.Thread(target=run, args=("near", "sim://wall?distance=1.0&points=120&noise=0&rate=20")),
               threading.Thread(target=run, args=("far", "sim://wall?distance=2.5&points=300&noise=0&rate=20"))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(15)
    near, far = results["near"], results["far"]
    assert near[2] == 120 and far[2] == 300
    assert np.nanmin(near[0][-1].ranges) == pytest.approx(1.0, abs=1e-3)
    assert np.nanmin(far[0][-1].ranges) == pytest.approx(2.5, abs=1e-3)
    assert [s.seq for s in near[0]] == list(range(near[0][0].seq, near[0][0].seq + 5))
    assert near[1]["scans"] >= 5 and far[1]["scans"] >= 5 and near[1]["crc_errors"] == far[1]["crc_errors"] == 0


def test_to_laserscan_has_increasing_equal_steps():
    with host_sdk.LaserPi(QUIET) as s:
        scan = next(iter(s.scans()))
    ls = scan.to_laserscan(frame_id="front")
    assert ls.frame_id == "front" and ls.angle_increment > 0
    assert ls.angle_min == pytest.approx(float(scan.angles.min()))
    assert ls.angle_max == pytest.approx(float(scan.angles.max()))
    np.testing.assert_array_equal(ls.ranges, scan.ranges[::-1])  # device columns run clockwise
    assert ls.range_max == scan.range_max and ls.scan_time == pytest.approx(0.1)


def test_to_laserscan_resamples_unequal_angles_to_the_nearest_ray():
    angles = np.array([0.0, 0.05, 0.08, 0.3], dtype=np.float32)  # not equally spaced
    scan = host_sdk.Scan(0, 0.0, 0.0, angles, np.array([1, 2, 3, 4], np.float32), np.zeros(4, np.float32),
                         0.0, 0.1, 0.1, 3.0)
    ls = scan.to_laserscan()
    assert ls.angle_increment == pytest.approx(0.1)
    np.testing.assert_array_equal(ls.ranges, [1, 3, 4, 4])  # grid 0, .1, .2, .3 -> nearest rays


def test_host_side_needs_no_opencv_or_matplotlib():
    """`pip install laserpi` on a robot has no OpenCV: the SDK, the link server and the mock
    device must work with cv2 unimportable."""
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys; sys.modules['cv2'] = None\n"
        "import host_sdk, protocol.server, protocol.mock_wall\n"
        "with host_sdk.LaserPi('sim://wall?points=20&noise=0') as s:\n"
        "    next(iter(s.scans()))\n"
        "assert 'matplotlib' not in sys.modules and 'cv2' not in [m for m in sys.modules if sys.modules[m]]\n"
        "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[1],
                         capture_output=True, text=True, timeout=30)
    assert out.stdout.strip() == "ok", out.stderr


def test_to_laserscan_moves_the_stamp_to_its_first_ray_when_reversing():
    angles = np.array([0.2, 0.1, 0.0], dtype=np.float32)  # device order: clockwise
    scan = host_sdk.Scan(0, 10.0, 5.0, angles, np.array([1, 2, 3], np.float32), np.zeros(3, np.float32),
                         0.001, 0.1, 0.1, 3.0)
    ls = scan.to_laserscan()
    # the LaserScan starts with the device's last ray, acquired 2 ms after the first
    assert ls.stamp == pytest.approx(10.002) and ls.time_increment == pytest.approx(-0.001)
    np.testing.assert_array_equal(ls.ranges, [3, 2, 1])


def test_close_from_another_thread_ends_a_waiting_scans_loop():
    s = host_sdk.LaserPi("sim://wall?points=20&rate=1", timeout_s=5.0)
    it = s.scans()
    next(it)
    errors = []

    def consume():
        try:
            next(it)
        except host_sdk.LaserPiError as exc:
            errors.append(exc)

    t = threading.Thread(target=consume)
    t.start()
    time.sleep(0.2)
    s.close()
    t.join(2.0)
    assert not t.is_alive() and "closed" in str(errors[0])
