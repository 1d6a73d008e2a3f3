"""End to end through the real tty layer: `laserpi serve --simulate --link PATH` as a subprocess."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import host_sdk
from protocol import messages as m
from protocol.mock_wall import wall_ranges

ROOT = Path(__file__).resolve().parents[1]


def start_serve(link: Path, *extra: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "device.cli", "serve", "--simulate", "--mock",
                             "--distance-m", "2.0", "--link", str(link), "--points", "300", *extra],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 10
    while not (link.is_symlink() and Path(os.readlink(link)).exists()):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"serve did not come up: {proc.communicate()}")
        time.sleep(0.05)
    return proc


@pytest.fixture
def served(tmp_path):
    link = tmp_path / "laserpi"
    proc = start_serve(link)
    yield link, proc
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_scans_over_a_real_pty_and_clean_sigterm(served):
    link, proc = served
    with host_sdk.LaserPi(str(link)) as s:
        assert s.info().serial_number
        it = s.scans()
        scans = [next(it) for _ in range(3)]
    truth = wall_ranges(scans[-1].angles, 2.0)
    ok = np.isfinite(scans[-1].ranges) & np.isfinite(truth)
    assert ok.sum() > 200
    assert np.abs(scans[-1].ranges[ok] - truth[ok]).max() < 6 * (0.001 + 0.0025 * 3.0 ** 2)
    # the pty is paced like a 921600-baud UART, so stamps correct for it: same clock here
    assert all(abs(sc.stamp - sc.device_time) < 0.01 for sc in scans)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=5) == 0
    assert not link.exists() and not link.is_symlink()


def test_unclean_exit_of_a_previous_session_does_not_matter(served):
    link, _ = served
    # a client that starts streaming and dies without closing anything
    code = ("import host_sdk, os; s = host_sdk.LaserPi(%r); it = s.scans(); next(it); os._exit(0)" % str(link))
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=20).returncode == 0
    time.sleep(0.5)  # the device keeps streaming into the pty meanwhile
    with host_sdk.LaserPi(str(link)) as s:
        assert s.health().state.name == "IDLE"  # the open handshake stopped the stream
        it = s.scans()
        first = [next(it) for _ in range(3)]
        assert s.stats.crc_errors == 0 and s.stats.decode_errors == 0
    assert all(sc.ranges.size == 300 for sc in first)


def test_device_death_raises_disconnected(tmp_path):
    link = tmp_path / "laserpi"
    proc = start_serve(link)
    try:
        with host_sdk.LaserPi(str(link)) as s:
            it = s.scans()
            next(it)
            proc.kill()  # the device process dies: the pty vanishes like an unplugged cable
            with pytest.raises(host_sdk.DisconnectedError, match="disconnected"):
                for _ in it:
                    pass
    finally:
        proc.kill()
        proc.wait()


def test_reconnect_with_back_off_after_the_device_comes_back(tmp_path):
    link = tmp_path / "laserpi"
    proc = start_serve(link)
    try:
        with host_sdk.LaserPi(str(link), reconnect=True, reconnect_timeout_s=10) as s:
            it = s.scans()
            before = next(it)
            proc.kill()
            proc.wait()
            proc = start_serve(link)  # plugged in again at the same path
            after = next(it)
            assert s.stats.reconnects == 1
            assert after.ranges.size == 300 and after.device_time > before.device_time
    finally:
        proc.kill()
        proc.wait()


def test_a_second_program_on_the_same_port_is_told_so(served):
    link, _ = served
    with host_sdk.LaserPi(str(link)):
        with pytest.raises(host_sdk.PortError, match="another program has the port open"):
            host_sdk.LaserPi(str(link))


def test_serve_without_simulate_says_what_is_missing(tmp_path, capsys):
    from device.cli import main

    assert main(["serve", "--link", str(tmp_path / "x")]) == 2
    assert "--simulate" in capsys.readouterr().out
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("extra, message", [
    (["--mock"], "--mock needs --simulate"),
    (["--simulate", "--mock", "--scan-rate-hz", "15"], "--mock runs at its own rate: --scan-rate-hz does not apply to it"),
    (["--simulate", "--mock", "--firmware", "x.elf"], "--mock runs no firmware: --firmware does not apply to it"),
    (["--simulate", "--mock", "--laser-limit-mw", "100"],
     "--laser-limit-mw 100 is above the mock device's Class 1 limit, 5.00 mW; it can only lower the limit"),
])
def test_serve_mock_says_what_is_wrong_with_its_options(extra, message, tmp_path, capsys):
    from device.cli import main

    assert main(["serve", "--link", str(tmp_path / "x"), *extra]) == 2
    assert capsys.readouterr().out == f"laserpi serve: {message}\n"
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("extra, limit_mw", [((), 5.0), (("--laser-limit-mw", "3"), 3.0)])
def test_serve_mock_refuses_a_host_asking_for_more_than_its_laser_limit(extra, limit_mw, tmp_path):
    link = tmp_path / "laserpi"
    proc = start_serve(link, *extra)
    try:
        with host_sdk.LaserPi(str(link)) as s:
            assert s.info().laser_limit_mw == limit_mw and s.info().settings.laser_power_mw <= limit_mw
            s.configure(laser_power_mw=limit_mw)
            with pytest.raises(host_sdk.CommandRefused) as exc:
                s.configure(laser_power_mw=limit_mw + 1)
            assert exc.value.code == m.NackCode.EYE_SAFETY and f"Class 1 limit of {limit_mw:g} mW" in exc.value.reason
            assert s.info(refresh=True).settings.laser_power_mw == limit_mw
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0


def test_a_host_killed_with_sigkill_leaves_the_laser_off(tmp_path):
    """SPEC.md "Host liveness": a host streaming through the SDK is killed with SIGKILL (no
    close(), no STOP); the device stops scanning and its laser within host_timeout_s."""
    import json

    link, stats = tmp_path / "laserpi", tmp_path / "stats.json"
    proc = start_serve(link, "--host-timeout-s", "2.0", "--stats-file", str(stats))
    code = ("import host_sdk, sys, time\n"
            f"s = host_sdk.LaserPi({str(link)!r})\n"
            "it = s.scans(); next(it); print('streaming', flush=True)\n"
            "while True: next(it)\n")
    host = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert host.stdout.readline().strip() == "streaming"

        def health(predicate, within_s):
            deadline = time.monotonic() + within_s
            while time.monotonic() < deadline:
                try:
                    doc = json.loads(stats.read_text())
                except (OSError, ValueError):
                    doc = None
                if doc is not None and predicate(doc):
                    return doc
                time.sleep(0.1)
            raise AssertionError(f"health never matched: {doc}")

        health(lambda d: d["scanning"] and d["laser_on"], 5.0)  # streaming while the host lives
        time.sleep(3.0)
        health(lambda d: d["scanning"] and d["laser_on"] and d["monotonic_s"] > time.monotonic() - 2.5, 3.0)
        # (heartbeats kept it going: the host sends nothing else)
        host.send_signal(signal.SIGKILL)
        host.wait(5)
        killed = time.monotonic()
        health(lambda d: not d["scanning"] and not d["laser_on"], 8.0)
        assert time.monotonic() - killed < 2.0 + 2.0 + 3.0  # timeout + the stats file's 2 s period + slack
        # and the stream stopped: after what was queued in the pty before the stop, no scan frame
        fd = os.open(str(link), os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
        try:
            for _ in range(2):  # drain the pty (and whatever the device's writer was blocked on)
                while True:
                    try:
                        if not os.read(fd, 65536):
                            break
                    except BlockingIOError:
                        break
                time.sleep(0.5)
            late = b""
            try:
                late = os.read(fd, 65536)
            except BlockingIOError:
                pass
        finally:
            os.close(fd)
        from protocol.stream import StreamDecoder
        from protocol.messages import MsgType
        assert not [r for r in StreamDecoder(synced=True).feed(late) if r.frame.msg_type == MsgType.SCAN]
    finally:
        host.kill()
        host.wait()
        proc.kill()
        proc.wait()
