"""Builds the co-MCU firmware and runs its host-compiled unit tests (firmware_pwm/test/).

These need gcc, avr-gcc and avr-libc (`make bootstrap` installs them); a missing tool fails
the test with the command's output, it is never skipped.
"""
import re
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware_pwm"


def _make(*targets):
    proc = subprocess.run(["make", "--no-print-directory", "-C", str(FIRMWARE), *targets],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"make {' '.join(targets)} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def test_firmware_unit_tests_pass():
    out = _make("test")
    m = re.search(r"firmware unit tests: (\d+) checks, (\d+) failed", out)
    assert m, out
    assert int(m.group(2)) == 0 and int(m.group(1)) > 1000, out


def test_firmware_elf_builds_and_fits_the_atmega328p():
    out = _make()
    m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*laserpi_pwm\.elf", out, re.M)
    assert m, f"no avr-size line in:\n{out}"
    text, data, bss = map(int, m.groups())
    assert text + data <= 32768 - 512, "flash (32 KiB minus a 512-byte bootloader) exceeded"
    assert data + bss <= 2048 - 512, "leave at least 512 bytes of the 2 KiB RAM for the stack"


def _make_default(name):
    m = re.search(rf"^{name} \?= (\d+)$", (FIRMWARE / "Makefile").read_text(), re.M)
    assert m, f"{name} default not in firmware_pwm/Makefile"
    return int(m.group(1))


def test_default_envelope_keeps_the_thesis_laser_class1_at_its_densest_long_pulse_train():
    """Cross-check with the sensor model (device.model.safety): 25 mW, 808 nm, 120 deg fan,
    4 mm line, 1 mm source, pulses of the compiled-in maximum at the highest rate the duty cap
    allows: the NOHD stays under the thesis's 10 mm (appendix B)."""
    import math

    from device.model.safety import PulsedLineLaser, nohd_m

    pulse_s = _make_default("MAX_PULSE_TICKS") / 2_000_000
    duty = _make_default("MAX_DUTY_PPM") / 1e6
    assert pulse_s == pytest.approx(17.4e-3) and duty == pytest.approx(0.2)
    laser = PulsedLineLaser(wavelength_nm=808, pulse_s=pulse_s, rate_hz=duty / pulse_s * 0.999,
                            fan_rad=math.radians(120), line_height_m=4e-3, source_diameter_m=1e-3)
    assert nohd_m(laser, 0.025) < 0.010
