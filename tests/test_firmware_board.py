"""The co-MCU firmware's board variants (firmware_pwm/README.md "Board variants"): the 8 MHz /
3.3 V build next to the default 16 MHz / 5 V one, and the clock checks of src/config.h.

Needs gcc, avr-gcc and avr-libc (`make bootstrap`); a missing tool fails, never skips.
"""
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
