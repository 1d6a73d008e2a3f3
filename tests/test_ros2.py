"""`laserpi ros2`: ROS 2's rules (conventions.py), the crop, and samples on DDS as a ROS 2
subscriber sees them, decoded by rosbags' ROS 2 typestore (a CDR implementation we did not write).

DDS traffic stays on this machine: every participant here uses host_sdk/ros2/cyclonedds-loopback.xml
(the loopback interface, no multicast) and a domain id of this test run only.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rosbags.typesys import Stores, get_typestore

import host_sdk
from device.service.child import start_serve, stop_serve
from host_sdk.commands import ros2 as cmd
from host_sdk.ros2 import conventions as c
from host_sdk.ros2.node import ScanOptions, run_node
from host_sdk.ros2.subscriber import read_samples
from host_sdk.scan import Scan

ROOT = Path(__file__).resolve().parents[1]
LOOPBACK = ROOT / "host_sdk" / "ros2" / "cyclonedds-loopback.xml"
DOMAIN = 100 + os.getpid() % 100  # this run's own domain: other runs on the machine do not mix in
os.environ["CYCLONEDDS_URI"] = LOOPBACK.as_uri()  # before the first participant of this process
ROSBAGS = get_typestore(Stores.ROS2_JAZZY)


# --- ROS 2's rules ------------------------------------------------------------------------------
def test_topic_and_type_names_are_the_ones_rmw_uses():
    assert c.dds_topic_name("/scan") == "rt/scan"
    assert c.dds_topic_name("scan") == "rt/scan"  # relative: resolved in the root namespace
    assert c.dds_topic_name("/front/scan") == "rt/front/scan"
    for bad in ("", "/", "/scan/", "/1scan", "/sc an", "/a__b", "//scan", "/scan-1"):
        with pytest.raises(ValueError, match="not a valid ROS 2 topic name"):
            c.dds_topic_name(bad)
    assert c.dds_type_name("sensor_msgs/msg/LaserScan") == "sensor_msgs::msg::dds_::LaserScan_"
    assert c.dds_type_name("diagnostic_msgs/msg/DiagnosticArray") == "diagnostic_msgs::msg::dds_::DiagnosticArray_"


@pytest.mark.parametrize("store", [Stores.ROS2_IRON, Stores.ROS2_JAZZY, Stores.ROS2_KILTED])
def test_type_hashes_are_rihs01_of_the_ros2_definitions(store):
    ts = get_typestore(store)
    for msgtype, rihs in c.TYPE_HASHES.items():
        assert ts.hash_rihs01(msgtype) == rihs
    assert c.type_hash_user_data(c.LASERSCAN) == f"typehash={c.TYPE_HASHES[c.LASERSCAN]};".encode()


def test_ros_time_is_the_monotonic_stamp_on_the_system_clock():
    offset = 1_700_000_000_123_456_789 - 5_000_000_000
    assert c.ros_time(5.0, offset) == (1_700_000_000, 123_456_789)
    assert c.ros_time(5.25, offset) == (1_700_000_000, 373_456_789)
    sec, nsec = c.ros_time(time.monotonic(), time.time_ns() - time.monotonic_ns())
    assert abs(sec + nsec * 1e-9 - time.time()) < 0.01 and 0 <= nsec < 1_000_000_000


# --- crop (urg_node's conventions, REP 117) -------------------------------------------------------
def _args(*argv):
    import argparse

    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_parameters_command_line_over_file_over_defaults(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text('port = "/dev/laserpi"\nframe_id = "front_laser"\nrange_max = 4\nqos = "sensor"\n')
    p = cmd.resolve(_args("--params", str(f), "--qos", "reliable"), environ={"ROS_DOMAIN_ID": "7"})
    assert (p["port"], p["frame_id"], p["range_max"], p["qos"], p["domain_id"]) == \
        ("/dev/laserpi", "front_laser", 4.0, "reliable", 7)
    assert (p["topic"], p["diagnostics_hz"], p["reconnect"]) == ("/scan", 1.0, False)
    assert cmd.resolve(_args("--port", "x"), environ={})["domain_id"] == 0
    f.write_text('port = "x"\nframe = "laser"\n')
    with pytest.raises(ValueError, match="unknown parameter 'frame'"):
        cmd.resolve(_args("--params", str(f)), environ={})
    f.write_text('port = "x"\ndomain_id = "3"\n')
    with pytest.raises(ValueError, match="domain_id must be a int"):
        cmd.resolve(_args("--params", str(f)), environ={})
    with pytest.raises(ValueError, match="no port"):
        cmd.resolve(_args(), environ={})


def test_the_shipped_parameter_file_holds_every_parameter_with_its_default():
    import tomllib

    path = ROOT / "host_sdk" / "ros2" / "laserpi-ros2.toml"
    assert set(tomllib.loads(path.read_text())) == set(cmd.PARAMETERS)
    p = cmd.resolve(_args("--params", str(path)), environ={"ROS_DOMAIN_ID": "9"})
    assert p["port"] == "/dev/laserpi" and p["domain_id"] == 0  # the file's, not the environment's
    assert p["reconnect"] is True  # a robot's service survives an unplug
    assert all(p[k] == default for k, (_, default, _) in cmd.PARAMETERS.items()
               if k not in ("port", "domain_id", "reconnect"))
    assert cmd.resolve(_args("--params", str(path), "--no-reconnect"), environ={})["reconnect"] is False


# --- on DDS --------------------------------------------------------------------------------------
def test_the_publisher_refuses_bad_settings_before_it_joins_a_domain():
    from host_sdk.ros2.dds import Ros2Publisher

    with pytest.raises(ValueError, match="domain id must be 0..232, got 233"):
        Ros2Publisher(233, "/scan", "reliable")
    with pytest.raises(ValueError, match="unknown QoS profile 'fast'; known: reliable, sensor"):
        Ros2Publisher(DOMAIN, "/scan", "fast")
    with pytest.raises(ValueError, match="not a valid ROS 2 topic name"):
        Ros2Publisher(DOMAIN, "/bad topic", "reliable")


class Subscriber:
    """host_sdk.ros2.subscriber in its own process, as a ROS 2 node's subscription would be."""

    def __init__(self, out: Path, reliability: str, depth: int, count: int, seconds: float = 30.0,
                 topic: str = "/scan", msgtype: str = c.LASERSCAN):
        self.out = out
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "host_sdk.ros2.subscriber", "--domain-id", str(DOMAIN), "--topic", topic,
             "--type", msgtype, "--reliability", reliability, "--depth", str(depth), "--count", str(count),
             "--seconds", str(seconds), "--out", str(out)],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def wait_matched(self, timeout_s: float = 20.0) -> None:
        line = self.proc.stdout.readline()  # "matched", or "received 0" at --seconds
        assert line.strip() == "matched", (line, self.proc.stderr.read() if self.proc.poll() is not None else "")

    def samples(self, timeout_s: float = 60.0) -> list[tuple[int, object]]:
        self.proc.wait(timeout=timeout_s)
        return [(t, raw) for t, raw in read_samples(str(self.out))]

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def subscribers():
    made = []
    yield lambda *a, **k: made.append(Subscriber(*a, **k)) or made[-1]
    for s in made:
        s.kill()


def _decode(raw: bytes, msgtype: str = c.LASERSCAN):
    assert raw[:4] == c.ENCAPSULATION_CDR_LE  # XCDR1, little endian, as rmw_cyclonedds writes
    return ROSBAGS.deserialize_cdr(raw, msgtype)


def _assert_fields_equal(msg, scan: Scan, options: ScanOptions, stamp: tuple[int, int]):
    ls = scan.cropped(angle_min=options.angle_min, angle_max=options.angle_max, range_min=options.range_min,
              range_max=options.range_max).to_laserscan(options.frame_id)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == stamp
    assert msg.header.frame_id == options.frame_id
    for name in ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min", "range_max"):
        assert getattr(msg, name) == np.float32(getattr(ls, name)), name
    np.testing.assert_array_equal(msg.ranges, ls.ranges)  # NaN, +inf, -inf included
    np.testing.assert_array_equal(msg.intensities, ls.intensities)


def _publish(port: str, options: ScanOptions, count: int, qos: str = "reliable", topic: str = "/scan",
             subs=(), before=None):
    """Publish ``count`` scans from ``port`` once every subscriber matched; returns
    {(sec, nanosec): (Scan, time.time() when it was published)}."""
    from host_sdk.ros2.dds import Ros2Publisher

    published = {}
    publisher = Ros2Publisher(DOMAIN, topic, qos)
    try:
        for s in subs:
            s.wait_matched()
        deadline = time.monotonic() + 10  # discovery is two-sided: the writer must see them too
        while publisher.subscriptions_matched() < len(subs) and time.monotonic() < deadline:
            time.sleep(0.01)
        if before is not None:
            before(publisher)
        with host_sdk.LaserPi(port) as sensor:
            run_node(publisher, itertools.islice(sensor.scans(), count), options,
                     on_published=lambda scan, stamp: published.__setitem__(stamp, (scan, time.time())))
        time.sleep(0.5)  # the reliable protocol's last repairs
    finally:
        publisher.close()
    return published


def test_both_ros2_qos_profiles_receive_scans_that_rosbags_decodes_into_the_sdks_fields(tmp_path, subscribers):
    reliable = subscribers(tmp_path / "reliable.bin", "reliable", 10, count=15)
    best_effort = subscribers(tmp_path / "best_effort.bin", "best-effort", 5, count=15)
    options = ScanOptions("laser", angle_min=-0.6, angle_max=0.7, range_min=0.2, range_max=3.0)
    published = _publish("sim://wall?points=400&distance=2.5", options, 15, subs=(reliable, best_effort))
    for sub, least in ((reliable, 15), (best_effort, 10)):  # best effort may lose one to a starved reader
        samples = sub.samples()
        assert least <= len(samples) <= 15
        for _, raw in samples:
            msg = _decode(raw)
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            scan, published_at = published[stamp]
            _assert_fields_equal(msg, scan, options, stamp)
            assert 0.2 <= np.nanmin(np.where(np.isfinite(msg.ranges), msg.ranges, np.nan)) <= 3.0
            # ROS time: the first ray's time on the system clock, a little before it was published
            assert 0 < published_at - (stamp[0] + stamp[1] * 1e-9) < 0.5


def test_a_sensor_data_writer_serves_best_effort_readers_but_not_reliable_ones(tmp_path, subscribers):
    best_effort = subscribers(tmp_path / "be.bin", "best-effort", 5, count=5)
    reliable = subscribers(tmp_path / "rel.bin", "reliable", 10, count=5, seconds=6.0)
    _publish("sim://wall?points=200", ScanOptions(), 5, qos="sensor", subs=(best_effort,))
    assert len(best_effort.samples()) == 5
    assert reliable.proc.stdout.readline().strip() == "received 0"  # never matched (offered < requested)
    assert reliable.samples() == []


def test_diagnostics_are_a_diagnostic_array_of_the_callables_tuples(tmp_path, subscribers):
    from host_sdk.ros2.node import DiagnosticsThread

    sub = subscribers(tmp_path / "diag.bin", "reliable", 10, count=4, topic=c.DIAGNOSTICS_TOPIC,
                      msgtype=c.DIAGNOSTIC_ARRAY)
    calls = []

    def fake():
        calls.append(1)
        if len(calls) % 2 == 0:
            raise host_sdk.DeviceTimeout("no reply to GetHealth")
        return [("device", 1, "degraded: SYNC_LOST", {"scans_sent": 12, "laser_on": True})]

    def run_diagnostics(publisher):
        thread = DiagnosticsThread(publisher, fake, "LP-0001", hz=20.0).start()
        time.sleep(0.3)
        thread.stop()

    _publish("sim://wall?points=50", ScanOptions(), 1, subs=(sub,), before=run_diagnostics)
    msgs = [_decode(raw, c.DIAGNOSTIC_ARRAY) for _, raw in sub.samples()]
    assert len(msgs) == 4  # the callable alternates between a status and a failure
    for msg in msgs:
        (status,) = msg.status
        assert (status.name, status.hardware_id) == ("laserpi: device", "LP-0001")
        if status.level == 1:
            assert status.message == "degraded: SYNC_LOST"
            assert [(kv.key, kv.value) for kv in status.values] == [("scans_sent", "12"), ("laser_on", "True")]
        else:
            assert (status.level, status.message, list(status.values)) == \
                (2, "no answer: no reply to GetHealth", [])
        assert abs(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - time.time()) < 5
    assert {msg.status[0].level for msg in msgs} == {1, 2}


def _run_cli(*argv) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "device.cli", "ros2", "--domain-id", str(DOMAIN), *argv],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_the_command_publishes_a_real_pty_device(tmp_path, subscribers):
    link = tmp_path / "laserpi"
    serve = start_serve(link, ["--simulate", "--mock", "--distance-m", "2.0", "--points", "300"])
    # --reconnect as in the shipped parameter file: on this shared machine a scan can be later
    # than LaserPi's 1 s timeout, which without it ends the node (tested below)
    node = _run_cli("--port", str(link), "--frame-id", "front_laser", "--reconnect")
    try:
        sub = subscribers(tmp_path / "pty.bin", "best-effort", 5, count=10)
        sub.wait_matched()
        samples = sub.samples()
    finally:
        node.terminate()  # SIGTERM, as systemd stops it
        assert node.wait(timeout=10) == 0, node.communicate()
        stop_serve(serve)
    assert len(samples) == 10
    msgs = [_decode(raw) for _, raw in samples]  # best effort: one may be lost to a starved reader
    assert all(msg.header.frame_id == "front_laser" and msg.ranges.size == 300 for msg in msgs)
    finite = np.concatenate([msg.ranges[np.isfinite(msg.ranges)] for msg in msgs])
    assert finite.size > 2000 and np.median(finite) > 2.0 - 0.05  # a wall 2 m ahead: none nearer
    stamps = [msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 for msg in msgs]
    steps = np.diff(stamps)
    # 10 Hz, in order (the SDK's stamp clock settles over the first scans: no bound on each step)
    assert (steps > 0).all() and 0.09 < np.median(steps) < 0.11
    assert abs(stamps[-1] - time.time()) < 5


def test_the_command_survives_an_unplug_with_reconnect_and_exits_without(tmp_path, subscribers):
    sub = subscribers(tmp_path / "re.bin", "reliable", 10, count=40, seconds=40.0)
    node = _run_cli("--port", "sim://wall?points=100&unplug_after=1.5", "--reconnect")
    try:
        sub.wait_matched()
        samples = sub.samples()
    finally:
        node.terminate()
        node.wait(timeout=10)
    assert len(samples) == 40  # 4 s of scans: the device went away at least twice meanwhile
    assert (samples[-1][0] - samples[0][0]) * 1e-9 > 3.0
    without = _run_cli("--port", "sim://wall?points=100&unplug_after=1.0")
    out, _ = without.communicate(timeout=30)
    assert without.returncode == 1 and "disconnected" in out
