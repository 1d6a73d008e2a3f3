"""The co-MCU firmware's board variants (firmware_pwm/README.md "Board variants", "Flashing"):
the 8 MHz / 3.3 V build next to the default 16 MHz / 5 V one, the clock checks of src/config.h,
and the avrdude command lines of `make flash` and `make fuses` (run against a stand-in avrdude:
none is installed here, and there is no board).

Needs gcc, avr-gcc and avr-libc (`make bootstrap`); a missing tool fails, never skips.
"""
import os
import re
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware_pwm"
BUILD_8MHZ = "build/8mhz"

#: config.h's constants, printed by a probe compiled with a build directory's recorded flags
PROBE = r"""
#include <stdio.h>
#include "config.h"
int main(void)
{
    printf("%lu %lu %lu %lu %lu %lu %lu %lu %lu %lu\n", (unsigned long)TICKS_PER_SECOND,
           (unsigned long)BAUD_UBRR, (unsigned long)MAX_PULSE_TICKS, (unsigned long)MIN_PERIOD_TICKS,
           (unsigned long)HEARTBEAT_TIMEOUT_TICKS, (unsigned long)MAX_LEAD_TICKS, (unsigned long)MIN_PULSE_TICKS,
           (unsigned long)MIN_GAP_TICKS, (unsigned long)ARM_MARGIN_TICKS, (unsigned long)MIN_LEAD_TICKS);
    return 0;
}
"""
NAMES = ("ticks_per_second", "ubrr", "max_pulse", "min_period", "heartbeat", "max_lead", "min_pulse",
         "min_gap", "arm_margin", "min_lead")


def _make(*args, env=None):
    return subprocess.run(["make", "--no-print-directory", "-C", str(FIRMWARE), *args],
                          capture_output=True, text=True, timeout=300, env=env)


def _constants(build: str, tmp_path: Path) -> dict[str, int]:
    """config.h's constants with the flags ``build`` (relative to firmware_pwm) was compiled with."""
    flags = (FIRMWARE / build / "envelope.flags").read_text().split()
    src, exe = tmp_path / "probe.c", tmp_path / f"probe_{build.replace('/', '_')}"
    src.write_text(PROBE)
    proc = subprocess.run(["gcc", "-std=gnu11", "-Wall", "-Werror", *flags, f"-I{FIRMWARE / 'src'}", "-o", str(exe),
                           str(src)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return dict(zip(NAMES, map(int, subprocess.run([str(exe)], capture_output=True, text=True).stdout.split())))


def test_the_8mhz_build_compiles_fits_and_keeps_the_envelope_in_seconds(tmp_path):
    for args in (["all"], [f"BUILD={BUILD_8MHZ}", "F_CPU=8000000", "all"]):
        proc = _make(*args)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*laserpi_pwm\.elf", proc.stdout, re.M)
        assert m, proc.stdout
        text, data, bss = map(int, m.groups())
        assert text + data <= 32768 - 512 and data + bss <= 2048 - 512
    fast, slow = _constants("build", tmp_path), _constants(BUILD_8MHZ, tmp_path)
    # the default build: today's tick values, bit for bit (0.5 us ticks, UBRR 3)
    assert fast == dict(ticks_per_second=2_000_000, ubrr=3, max_pulse=34_800, min_period=180_000, heartbeat=100_000,
                        max_lead=20_000_000, min_pulse=200, min_gap=400, arm_margin=48, min_lead=200)
    # 8 MHz: 1 us ticks, UBRR 1 (8 MHz / 16 / 250000 - 1, exact); the envelope, the heartbeat
    # timeout and the schedule horizon the same in seconds; the allowances for the firmware's own
    # work the same in ticks (CPU cycles / 8), so twice as long in time
    assert slow["ticks_per_second"] == 1_000_000 and slow["ubrr"] == 1
    for name in ("max_pulse", "min_period", "heartbeat", "max_lead"):
        assert slow[name] / slow["ticks_per_second"] == fast[name] / fast["ticks_per_second"], name
    for name in ("min_pulse", "min_gap", "arm_margin", "min_lead"):
        assert slow[name] == fast[name], name


@pytest.mark.parametrize("f_cpu, message", [
    ("10000000", "no 250000 baud within 0.5 %"),         # UBRR 1.5: 208333 or 312500 baud
    ("14745600", "a whole number of Timer1 ticks per millisecond"),
    ("24000000", "above 20 MHz"),
])
def test_a_clock_the_firmware_cannot_time_is_refused_at_compile_time(tmp_path, f_cpu, message):
    proc = _make(f"BUILD={tmp_path}", f"F_CPU={f_cpu}", str(tmp_path / "laserpi_pwm.elf"))
    assert proc.returncode != 0 and message in proc.stderr, proc.stderr


@pytest.fixture
def avrdude(tmp_path):
    """A stand-in avrdude on PATH that records its arguments, one call a line."""
    log = tmp_path / "avrdude.log"
    exe = tmp_path / "bin" / "avrdude"
    exe.parent.mkdir()
    exe.write_text(f'#!/bin/sh\necho "$*" >> {log}\n')
    exe.chmod(0o755)
    env = {**os.environ, "PATH": f"{exe.parent}:{os.environ['PATH']}"}
    return env, log


def test_make_flash_writes_the_builds_hex_and_needs_the_clock(avrdude):
    env, log = avrdude
    proc = _make("flash", env=env)
    assert proc.returncode != 0 and "needs F_CPU=8000000 or F_CPU=16000000" in proc.stdout + proc.stderr
    assert not log.exists(), "avrdude must not run without the board's clock"
    proc = _make(f"BUILD={BUILD_8MHZ}", "F_CPU=8000000", "flash", env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    proc = _make(f"BUILD={BUILD_8MHZ}", "F_CPU=8000000", "PROGRAMMER=arduino", "PORT=/dev/ttyUSB0", "PROG_BAUD=115200",
                 "flash", env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert log.read_text().splitlines() == [
        f"-p m328p -c usbasp -U flash:w:{BUILD_8MHZ}/laserpi_pwm.hex:i",
        f"-p m328p -c arduino -P /dev/ttyUSB0 -b 115200 -U flash:w:{BUILD_8MHZ}/laserpi_pwm.hex:i"]


def test_make_fuses_writes_each_clocks_fuses_and_needs_the_clock(avrdude):
    env, log = avrdude
    for args in ([], ["F_CPU=12000000"]):
        proc = _make(*args, "fuses", env=env)
        assert proc.returncode != 0 and "needs F_CPU=8000000 or F_CPU=16000000" in proc.stdout + proc.stderr
    assert not log.exists()
    for f_cpu in ("16000000", "8000000"):
        proc = _make(f"F_CPU={f_cpu}", "PROGRAMMER=avrisp", "PORT=/dev/ttyACM0", "PROG_BAUD=19200", "fuses", env=env)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    assert log.read_text().splitlines() == [
        "-p m328p -c avrisp -P /dev/ttyACM0 -b 19200 -U lfuse:w:0xFF:m -U hfuse:w:0xD9:m -U efuse:w:0xFC:m",
        "-p m328p -c avrisp -P /dev/ttyACM0 -b 19200 -U lfuse:w:0xFF:m -U hfuse:w:0xD9:m -U efuse:w:0xFD:m"]


def test_the_fuse_bytes_are_the_documented_settings_in_avr_libcs_bit_definitions(tmp_path):
    """README.md "Fuses": low = crystal 8-16 MHz, slow rising power, no CKDIV8 (no bit programmed);
    high = SPIEN and the factory BOOTSZ1:0 = 00 programmed, BOOTRST not (no bootloader); extended =
    BODLEVEL2:0 = 100 (4.3 V) at 16 MHz, 101 (2.7 V) at 8 MHz; with optiboot the high byte is 0xDE
    (BOOTSZ1:0 = 11, 256 words, BOOTRST programmed).  A programmed fuse bit is 0 (avr-libc's FUSE_x)."""
    makefile = (FIRMWARE / "Makefile").read_text()
    values = {name: re.search(rf"^{name} := (0x[0-9A-F]{{2}})$", makefile, re.M).group(1)
              for name in ("LFUSE", "HFUSE", "EFUSE_16000000", "EFUSE_8000000")}
    src = tmp_path / "fuses.c"
    src.write_text("#include <avr/io.h>\n" + "".join(
        f"_Static_assert((unsigned char)({expr}) == {values[name]}, \"{name}\");\n" for name, expr in (
            ("LFUSE", "0xFF"),
            ("HFUSE", "FUSE_SPIEN & FUSE_BOOTSZ1 & FUSE_BOOTSZ0"),
            ("EFUSE_16000000", "FUSE_BODLEVEL1 & FUSE_BODLEVEL0"),
            ("EFUSE_8000000", "FUSE_BODLEVEL1"))) +
        "_Static_assert((unsigned char)(FUSE_SPIEN & FUSE_BOOTRST) == 0xDE, \"optiboot high fuse\");\n")
    proc = subprocess.run(["avr-gcc", "-mmcu=atmega328p", "-std=gnu11", "-fsyntax-only", str(src)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
