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


def test_firmware_unit_tests_pass_at_both_clocks():
    out = _make("test")
    runs = re.findall(r"firmware unit tests: (\d+) checks, (\d+) failed", out)
    assert len(runs) == 2, out  # 16 MHz (build/) and 8 MHz (build/8mhz/)
    assert all(int(failed) == 0 and int(checks) > 100_000 for checks, failed in runs), out


def test_firmware_elf_builds_and_fits_the_atmega328p():
    out = _make()
    m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*laserpi_pwm\.elf", out, re.M)
    assert m, f"no avr-size line in:\n{out}"
    text, data, bss = map(int, m.groups())
    assert text + data <= 32768 - 512, "flash (32 KiB minus a 512-byte bootloader) exceeded"
    assert data + bss <= 2048 - 512, "leave at least 512 bytes of the 2 KiB RAM for the stack"


def test_the_environment_cannot_change_the_envelope_but_the_command_line_rebuilds(tmp_path):
    """The clock and envelope come from the Makefile or the make command line only, and a build
    directory records those it was built with (so a change rebuilds, never a stale ELF)."""
    import os

    env = {**os.environ, "MIN_PERIOD_US": "300", "MAX_PULSE_US": "30000", "F_CPU": "8000000"}
    flags = tmp_path / "envelope.flags"
    proc = subprocess.run(["make", "--no-print-directory", "-C", str(FIRMWARE), f"BUILD={tmp_path}", str(flags)],
                          capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 0, proc.stderr
    recorded = flags.read_text().split()
    assert {"-DMIN_PERIOD_US=90000UL", "-DMAX_PULSE_US=17400UL", "-DF_CPU=16000000UL"} <= set(recorded), recorded
    _make(f"BUILD={tmp_path}", "MIN_PERIOD_US=100000", "F_CPU=8000000", str(flags))
    assert {"-DMIN_PERIOD_US=100000UL", "-DF_CPU=8000000UL"} <= set(flags.read_text().split())
