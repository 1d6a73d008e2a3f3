"""`laserpi doctor`: every check runs here and reports what is missing; each passes where its
part is there (a fake picamera2, files standing in for the kernel's)."""

import json
import sys

import pytest

from device.cli import main
from device.config import load_preset
from device.service.doctor import CHECKS, DoctorSetup, run_checks
from tests.fake_picamera2 import ManualClock, install_fake
from tests.test_picamera2_camera import TIMING, gradient

NAMES = ["camera stack", "camera detected", "sensor mode", "co-MCU", "GPIO edge line", "UART console", "host link",
         "C kernel", "clock"]


def test_json_lists_every_check_and_the_exit_code_says_one_failed(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)  # no camera stack here
    code = main(["doctor", "--json", "--comcu", "/nonexistent/serial0", "--port", "/nonexistent/ttyGS0"])
    out = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in out] == NAMES == [name for name, _ in CHECKS]
    assert all(set(r) == {"name", "ok", "detail"} and isinstance(r["ok"], bool) and r["detail"] for r in out)
    by = {r["name"]: r for r in out}
    assert code == 1
    assert not by["camera stack"]["ok"] and "python3-picamera2" in by["camera stack"]["detail"]
    assert by["camera detected"]["detail"] == "needs the camera stack (see above)"
    assert not by["co-MCU"]["ok"] and "/nonexistent/serial0" in by["co-MCU"]["detail"]
    assert not by["GPIO edge line"]["ok"] and "degraded" in by["GPIO edge line"]["detail"]
    assert not by["host link"]["ok"] and "g_serial" in by["host link"]["detail"]
    assert by["C kernel"]["ok"] and by["clock"]["ok"]


def test_the_table_form(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)
    assert main(["doctor", "--port", "/nonexistent/ttyGS0"]) == 1
    out = capsys.readouterr().out
    assert "FAIL  camera stack" in out and "ok    C kernel" in out and "checks ok; fix the" in out


@pytest.mark.parametrize("cmdline, ok", [
    ("coherent_pool=1M 8250.nr_uarts=0 console=serial0,115200 console=tty1 root=PARTUUID=x rootwait", False),
    ("console=ttyAMA0,115200 root=/dev/mmcblk0p2", False),
    ("coherent_pool=1M 8250.nr_uarts=0 console=tty1 root=PARTUUID=x rootwait modules-load=dwc2,g_serial", True),
])
def test_checks_pass_where_their_part_is_there(tmp_path, monkeypatch, cmdline, ok):
    install_fake(monkeypatch, clock=ManualClock(), render=gradient, timing=TIMING)
    (tmp_path / "cmdline").write_text(cmdline + "\n")
    (tmp_path / "ttyGS0").write_text("")
    (tmp_path / "clocksource").write_text("arch_sys_counter\n")
    setup = DoctorSetup(load_preset("thesis-calibrated"), comcu=str(tmp_path / "serial0"), port=str(tmp_path / "ttyGS0"),
                        cmdline=str(tmp_path / "cmdline"), clocksource=str(tmp_path / "clocksource"))
    by = {r.name: r for r in run_checks(setup)}
    assert by["camera stack"].ok and by["camera detected"].ok and "imx219" in by["camera detected"].detail
    assert by["sensor mode"].ok and "1640x1232" in by["sensor mode"].detail
    assert by["UART console"].ok is ok
    assert by["host link"].ok and by["clock"].ok and "arch_sys_counter" in by["clock"].detail
    assert not by["co-MCU"].ok  # nothing at that path


def test_a_mode_the_camera_lacks_fails_the_sensor_mode_check(monkeypatch):
    from device.camera.modes import SENSOR_MODES

    install_fake(monkeypatch, clock=ManualClock(), render=gradient, timing=TIMING, modes={"3280x2464": SENSOR_MODES["3280x2464"]})
    by = {r.name: r for r in run_checks(DoctorSetup(load_preset("thesis-calibrated")))}
    assert not by["sensor mode"].ok and "1640x1232 is not among the camera's modes (3280x2464)" in by["sensor mode"].detail
