"""Builds the co-MCU firmware and runs its host-compiled unit tests (firmware_pwm/test/).

These need gcc, avr-gcc and avr-libc (`make bootstrap` installs them); a missing tool fails
the test with the command's output, it is never skipped.
"""
import re
import subprocess
from pathlib import Path

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
