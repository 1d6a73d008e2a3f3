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
