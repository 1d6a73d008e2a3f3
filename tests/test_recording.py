"""Record, replay (library and through a pty), ROS bag export, and the host CLI commands."""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import host_sdk
from device.cli import main
from host_sdk.recording import RecordingHeader, RecordingWriter, read_recording
from host_sdk.replay_link import ControlFilter
from protocol import messages as m
from protocol.framing import encode_frame

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).resolve().parents[1]


def scans_of(path):
    rep = host_sdk.replay(path)
    return {s.seq: s for s in rep}, rep


def test_clean_recording_replays_every_scan():
    scans, rep = scans_of(DATA / "wall_clean.lpr")
    assert len(scans) == 21 and sorted(scans) == list(range(21))
    assert rep.stats.crc_errors == rep.stats.decode_errors == rep.stats.scans_missing == 0
    assert rep.info.angles.size == 64
    for s in scans.values():  # a wall at 1.2 m: x of every finite point near 1.2
        x = s.points()[np.isfinite(s.ranges), 0]
        assert np.abs(x - 1.2).max() < 0.05
    stamps = [scans[i].stamp for i in range(21)]
    assert np.allclose(np.diff(stamps), 0.05, atol=0.005)  # 20 Hz


def test_corrupt_recording_yields_only_intact_scans_identical_to_the_clean_ones():
    clean, _ = scans_of(DATA / "wall_clean.lpr")
    got, rep = scans_of(DATA / "wall_corrupt.lpr")
    assert 0 < len(got) < len(clean)
    for seq, s in got.items():
        np.testing.assert_array_equal(s.ranges, clean[seq].ranges)
        np.testing.assert_array_equal(s.intensities, clean[seq].intensities)
        assert s.device_time == clean[seq].device_time
    st = rep.stats
    assert st.decode_errors + st.crc_errors > 0 and st.bytes_discarded > 0
    assert st.scans_missing == (max(got) - min(got) + 1) - len(got)  # the gaps between yielded scans


def test_recording_reader_refuses_other_files(tmp_path):
    bad = tmp_path / "x.lpr"
    bad.write_bytes(b"PK\x03\x04 not a recording")
    with pytest.raises(ValueError, match="not a LaserPi recording"):
        host_sdk.replay(bad)


def test_writer_refuses_to_overwrite(tmp_path):
    p = tmp_path / "r.lpr"
    p.write_bytes(b"")
    with pytest.raises(FileExistsError):
        RecordingWriter(p, RecordingHeader(921600, 0, 0, "x"))


def test_record_command_roundtrip(tmp_path, capsys):
    out = tmp_path / "r.lpr"
    assert main(["record", "--port", "sim://wall?points=32&rate=20", "--seconds", "0.4", "--out", str(out)]) == 0
    header, records = read_recording(out)
    assert header.port.startswith("sim://") and sum(len(c) for _, c in records) > 0
    scans, _ = scans_of(out)
    assert len(scans) >= 5
    assert main(["record", "--port", "sim://wall", "--seconds", "0.1", "--out", str(out)]) == 2  # exists


def test_control_filter_removes_only_intact_replies():
    scan = m.ScanMessage(1, 2, 0, 0, 0, np.ones(3), np.ones(3, np.uint8))
    s = encode_frame(scan.TYPE, 1, scan.encode())
    ack = encode_frame(m.MsgType.ACK, 2, m.Ack(5, 1).encode())
    junk = b"\x01\x02\x03\x00"
    f = ControlFilter()
    out = f.feed(s[:5]) + f.feed(s[5:] + ack + junk)
    assert out == s + junk


def test_replay_through_a_pty_serves_the_recording(tmp_path):
    link = tmp_path / "replay"
    proc = subprocess.Popen([sys.executable, "-m", "device.cli", "replay", str(DATA / "wall_clean.lpr"),
                             "--link", str(link), "--speed", "4"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 10
        while not link.is_symlink():
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        clean, _ = scans_of(DATA / "wall_clean.lpr")
        got = []
        with host_sdk.LaserPi(str(link), timeout_s=2.0) as s:
            assert s.info().angles.size == 64
            # a replay knows no fault counters: it answers with the HEALTH of protocol minor 0,
            # which the SDK reads with the counters absent
            h = s.health()
            assert h.state == m.DeviceState.IDLE and all(getattr(h, f) is None for f in m.Health.MINOR1_FIELDS)
            with pytest.raises(host_sdk.CommandRefused, match="cannot change"):
                s.configure(scan_rate_hz=5.0)
            with pytest.raises(host_sdk.DisconnectedError):  # the replay ends after the last byte
                for scan in s.scans():
                    got.append(scan)
        assert [g.seq for g in got] == sorted(clean)
        for g in got:
            np.testing.assert_array_equal(g.ranges, clean[g.seq].ranges)
        assert proc.wait(timeout=5) == 0 and not link.is_symlink()
    finally:
        proc.kill()
        proc.wait()


def test_export_bag_reads_back_with_rosbags(tmp_path, capsys):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    out = tmp_path / "bag"
    assert main(["export-bag", str(DATA / "wall_clean.lpr"), str(out), "--frame-id", "front_laser"]) == 0
    assert list(out.glob("*.mcap"))
    clean, rep = scans_of(DATA / "wall_clean.lpr")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out) as reader:
        msgs = [ts.deserialize_cdr(raw, conn.msgtype) for conn, _, raw in reader.messages()]
        assert [c.msgtype for c in reader.connections] == ["sensor_msgs/msg/LaserScan"]
    assert len(msgs) == len(clean)
    first, scan0 = msgs[0], clean[0]
    assert first.header.frame_id == "front_laser"
    np.testing.assert_array_equal(first.ranges, scan0.ranges[::-1])
    assert first.angle_min == pytest.approx(float(scan0.angles.min()), abs=1e-6)
    wall = rep.header.wall_start_ns * 1e-9
    stamp = first.header.stamp.sec + first.header.stamp.nanosec * 1e-9
    assert 0 <= stamp - wall < 1.0  # recorded within the first second
    written = {f: f.read_bytes() for f in out.iterdir()}
    capsys.readouterr()
    assert main(["export-bag", str(DATA / "wall_corrupt.lpr"), str(out)]) == 2
    assert capsys.readouterr().out == f"laserpi export-bag: {out} exists; not overwriting it\n"
    assert {f: f.read_bytes() for f in out.iterdir()} == written


def test_scans_and_view_commands(tmp_path, capsys):
    assert main(["scans", "--port", "sim://wall?points=50&rate=20", "--count", "3"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("seq")]
    assert len(lines) == 3 and "points 50" in lines[0]
    for bad in ("-1", "0"):  # -1 never stopped (no scan is number -1); "never" is leaving --count out
        with pytest.raises(SystemExit) as exit_:
            main(["scans", "--port", "sim://wall", "--count", bad])
        assert exit_.value.code == 2 and "--count: must be a positive integer" in capsys.readouterr().err
    png = tmp_path / "scan.png"
    assert main(["view", "--port", "sim://wall?points=50", "--png", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["scans", "--port", "/dev/nonexistent-laserpi"]) == 1
    assert "plugged in" in capsys.readouterr().out


@pytest.mark.parametrize("argv, name", [
    (["export-bag", "missing.lpr", "bag"], "missing.lpr"),
    (["replay", "missing.lpr", "--link", "link"], "missing.lpr"),
    (["record", "--port", "sim://wall", "--seconds", "0.1", "--out", "no-dir/r.lpr"], "no-dir/r.lpr"),
    (["view", "--port", "sim://wall?points=50", "--png", "no-dir/scan.png"], "no-dir/scan.png"),
])
def test_a_file_that_cannot_be_read_or_written_is_named_in_one_line(argv, name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert capsys.readouterr().out.splitlines()[-1] == f"laserpi {argv[0]}: {name}: No such file or directory"
    assert list(tmp_path.iterdir()) == []  # no bag, link or recording left behind


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """`laserpi scans ... | head -1`: the pipe's reader closes it; before, the dispatcher's
    message to that same stdout raised a second traceback."""
    proc = subprocess.run(f"{sys.executable} -m device.cli scans --port 'sim://wall?points=50&rate=20' | head -1",
                          shell=True, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.stdout.startswith("seq") and "Traceback" not in proc.stderr, proc.stderr


def test_replay_without_link_prints_the_scans(capsys):
    assert main(["replay", str(DATA / "wall_corrupt.lpr")]) == 0
    out = capsys.readouterr().out.splitlines()
    clean, _ = scans_of(DATA / "wall_corrupt.lpr")
    assert [line.split()[1] for line in out if line.startswith("seq")] == [str(s) for s in clean]
    assert out[-1].startswith("# {") and "'crc_errors'" in out[-1]
