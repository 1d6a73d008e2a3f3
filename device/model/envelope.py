"""The co-MCU firmware's compiled-in eye-safety envelope, computed and verified against the Class 1
model of device/model/safety.py (IEC 60825-1, thesis section 3.3, docs/thesis-notes.md N1, N2).

The firmware (firmware_pwm/, src/core.c) allows every pulse train with
  * widths from its MIN_PULSE_TICKS (100 us at 16 MHz, longer at a slower clock) to ``max_pulse_us``,
  * consecutive pulses at least ``min_period_us`` apart, rise to rise and fall to fall,
  * off time g >= max(w1, w2) (1 - D) / D between pulses (duty D = ``max_duty_ppm``).
A regular train of width w and period P is inside when w <= max_pulse, P >= min_period and
w / P <= D.  `verify_envelope` evaluates the safety model on that whole region: every width of a
fine grid that includes the kinks of the model (625 us, where alpha_max of eq. 3.23 leaves its
floor, and the width where alpha_max reaches the source's subtense, which switches C6 and the C5
branch) and, for each width, every period where a pulse count of eq. 3.36/3.37 steps up, from the
densest corner of the region on (within a step the NOHD only grows with the rate, so the start
of each step is its worst point), plus a geometric period grid as a cross-check.

Why every step and not just the densest corner: C5 (eq. 3.35) is not monotonic in the pulse
count (N^-0.25 = 0.398 at N = 40 but the 0.4 floor at N = 41), so a slower train can have a
slightly larger NOHD than a faster one.

Irregular and mixed trains: with rises (and falls) at least P apart, a window of length L holds
at most floor(L / P) + 1 pulses, one more than a regular train at period P when L / P is whole;
the densest corner is evaluated a hair below P so that this count is the one used.  The per-pulse
limits of the three conditions are evaluated at that largest count for every width, so a train
mixing widths of the region keeps each of its pulses inside its own limit (for condition 2 the
pulse energies add up to at most the AEL over T).

The limits are in microseconds, as in firmware_pwm/Makefile: the firmware converts them to ticks of
its clock (config.h), so the 16 MHz and the 8 MHz build have the same envelope in seconds.

Pure functions, no I/O; `main` (``python -m device.model.envelope``) is the generator of the
Makefile line.
"""

from __future__ import annotations

import argparse
import functools
import math
import re
from dataclasses import dataclass

import numpy as np

from . import safety

#: Shortest pulse the firmware places and shortest off time (config.h MIN_PULSE_TICKS and
#: MIN_GAP_TICKS: 200 and 400 ticks, in time shortest at the fastest clock, 16 MHz).
MIN_PULSE_US = 100
MIN_GAP_US = 200
#: Longest pulse that fits one 16-bit compare window (config.h's #error bound, 61344 ticks) at 16 MHz.
MAX_PULSE_US_LIMIT = (65536 - 2 * 48 - 4096) // 2
#: Room below the sensor's pulse period that an envelope's minimum period leaves for the sync's
#: period trims (ppm) and phase steps: minimum period = 1 / rate - this.
SYNC_SLACK_S = 10e-3
#: Relative amount below the minimum period at which the densest corner is evaluated, so that a
#: window holding a whole number of minimum periods counts floor(L / P) + 1 pulses.
_HAIR = 1e-9


class EnvelopeError(ValueError):
    """An envelope that cannot be built or is not Class 1; the message says which limit and why."""


@dataclass(frozen=True)
class LineLaserOptics:
    """The laser inputs of the safety model other than the pulse train (thesis Table 3.3), SI."""

    wavelength_nm: float
    fan_rad: float
    line_height_m: float
    source_diameter_m: float

    def train(self, pulse_s: float, period_s: float) -> safety.PulsedLineLaser:
        """This laser pulsed regularly: ``pulse_s`` every ``period_s``."""
        return safety.PulsedLineLaser(self.wavelength_nm, pulse_s, 1.0 / period_s, self.fan_rad,
                                      self.line_height_m, self.source_diameter_m)


@dataclass(frozen=True)
class FirmwareEnvelope:
    """The three compiled-in limits, in the Makefile's units (microseconds, ppm of time)."""

    max_pulse_us: int
    max_duty_ppm: int
    min_period_us: int

    def __post_init__(self) -> None:
        if not MIN_PULSE_US <= self.max_pulse_us <= MAX_PULSE_US_LIMIT:
            raise EnvelopeError(f"max_pulse_us = {self.max_pulse_us} is outside "
                                f"{MIN_PULSE_US}..{MAX_PULSE_US_LIMIT} (100 us .. one 16-bit timer window at 16 MHz)")
        if not 1 <= self.max_duty_ppm < 1_000_000:
            raise EnvelopeError(f"max_duty_ppm = {self.max_duty_ppm} is outside 1..999999")
        if not MIN_PULSE_US + MIN_GAP_US <= self.min_period_us <= (2**31 - 1) // 2:
            raise EnvelopeError(f"min_period_us = {self.min_period_us} is outside "
                                f"{MIN_PULSE_US + MIN_GAP_US}..{(2**31 - 1) // 2} (2^31 - 1 ticks at 16 MHz)")

    @property
    def max_pulse_s(self) -> float:
        return self.max_pulse_us * 1e-6

    @property
    def max_duty(self) -> float:
        return self.max_duty_ppm / 1e6

    @property
    def min_period_s(self) -> float:
        return self.min_period_us * 1e-6

    @classmethod
    def from_ticks(cls, max_pulse_ticks: int, max_duty_ppm: int, min_period_ticks: int,
                   ticks_per_second: int) -> FirmwareEnvelope:
        """The envelope a firmware announces in ticks of its clock (its INFO), in microseconds
        rounded to the loose side (pulse up, period down), so that it covers every train that
        firmware allows."""
        if ticks_per_second <= 0:
            raise EnvelopeError(f"ticks_per_second must be positive, got {ticks_per_second}")
        return cls(math.ceil(max_pulse_ticks * 1_000_000 / ticks_per_second), max_duty_ppm,
                   math.floor(min_period_ticks * 1_000_000 / ticks_per_second))

    @property
    def build_dir(self) -> str:
        """This envelope's firmware build directory (relative to firmware_pwm/): one of its own, so
        that building it never replaces the production ELF in build/ (the Makefile's envelope,
        which `laserpi serve --simulate` runs by default)."""
        return f"build/envelope-{self.max_pulse_us}-{self.max_duty_ppm}-{self.min_period_us}"

    def make_command(self) -> str:
        """The firmware build line with these limits (firmware_pwm/Makefile variables), into
        build_dir: its ELF is firmware_pwm/<build_dir>/laserpi_pwm.elf."""
        return (f"make -C firmware_pwm BUILD={self.build_dir} MAX_PULSE_US={self.max_pulse_us} "
                f"MAX_DUTY_PPM={self.max_duty_ppm} MIN_PERIOD_US={self.min_period_us}")


def parse_makefile_envelope(makefile_text: str) -> FirmwareEnvelope:
    """The compiled-in defaults from the text of firmware_pwm/Makefile (their one source of truth)."""
    values = {}
    for name in ("MAX_PULSE_US", "MAX_DUTY_PPM", "MIN_PERIOD_US"):
        m = re.search(rf"^{name} :?= *(\d+) *$", makefile_text, re.M)
        if m is None:
            raise EnvelopeError(f"no `{name} := <integer>` line in the firmware Makefile")
        values[name.lower()] = int(m.group(1))
    return FirmwareEnvelope(**values)


@dataclass(frozen=True)
class EnvelopeCheck:
    """Result of `verify_envelope`: the largest NOHD over the allowed region and where it is."""

    worst_nohd_m: float
    worst_pulse_s: float
    worst_period_s: float
    limiting_condition: str
    closest_eye_m: float
    points: int

    @property
    def class1(self) -> bool:
        return self.worst_nohd_m <= self.closest_eye_m * (1.0 + 1e-9)


def width_grid_s(optics: LineLaserOptics, envelope: FirmwareEnvelope, points: int = 200) -> np.ndarray:
    """Pulse widths to check (s, sorted): geometric from MIN_PULSE to the maximum, plus the ends,
    the model's kinks (625 us; the width where alpha_max equals the source's subtense) and the
    width at which the duty cap meets the minimum period."""
    lo, hi = MIN_PULSE_US * 1e-6, envelope.max_pulse_s
    subtense = safety.angular_subtense_mrad(optics.source_diameter_m)
    kinks = [625e-6, (subtense / 200.0) ** 2, envelope.max_duty * envelope.min_period_s]
    widths = np.concatenate([np.geomspace(lo, hi, points), [lo, hi], [k for k in kinks if lo <= k <= hi]])
    return np.unique(widths)


#: Cross-check grid of periods (s), from the firmware's shortest placeable period to T = 100 s.
_PERIOD_GRID_S = np.geomspace((MIN_PULSE_US + MIN_GAP_US) * 1e-6, safety.AVERAGING_TIME_S, 60)


def period_candidates_s(optics: LineLaserOptics, envelope: FirmwareEnvelope, pulse_s: float) -> np.ndarray:
    """Periods to check for one width (s): the densest allowed one (a hair below the minimum
    period, see the module doc), the start of every step of the pulse count N in T2 above it
    (eq. 3.36/3.37), and a fixed geometric grid.  Within one step of N only the count in T = 100 s
    (condition 2) still changes, and it is largest at the step's start, so the steps of that count
    need no points of their own."""
    densest = max(envelope.min_period_s * (1.0 - _HAIR), pulse_s / envelope.max_duty,
                  pulse_s + MIN_GAP_US * 1e-6)
    t2 = safety.t2_s(safety.angular_subtense_mrad(optics.source_diameter_m))
    steps = t2 / np.arange(1, math.floor(t2 / densest) + 1)  # the shortest period holding N pulses in T2
    periods = np.concatenate([[densest], steps, _PERIOD_GRID_S])
    return np.unique(periods[periods >= densest])


@functools.lru_cache(maxsize=500_000)
def _nohd_point(optics: LineLaserOptics, power_w: float, pulse_s: float, period_s: float) -> tuple[float, str]:
    """NOHD (m) and limiting condition of one regular train (cached: the bisection of
    `shortest_class1_period_s` revisits the same step starts)."""
    laser = optics.train(pulse_s, period_s)
    limit = safety.pulse_energy_limit(laser)
    return safety.nohd_m(laser, power_w, limit), limit.limiting_condition


def _allowed_trains(optics: LineLaserOptics, envelope: FirmwareEnvelope, width_points: int):
    """(pulse_s, period_s) of every regular train `verify_envelope` evaluates (module doc)."""
    for pulse_s in width_grid_s(optics, envelope, width_points):
        for period_s in period_candidates_s(optics, envelope, float(pulse_s)):
            yield float(pulse_s), float(period_s)


def verify_envelope(optics: LineLaserOptics, power_w: float, closest_eye_m: float, envelope: FirmwareEnvelope,
                    width_points: int = 200) -> EnvelopeCheck:
    """Largest NOHD of any pulse train the firmware allows (module doc), and where it is.

    Class 1 holds (``.class1``) when it is within ``closest_eye_m``.
    """
    power_w = float(power_w)
    if not math.isfinite(power_w) or power_w <= 0:
        raise EnvelopeError(f"laser power must be a finite positive number, got {power_w!r}")
    worst = (-1.0, math.nan, math.nan, "")
    points = 0
    for pulse_s, period_s in _allowed_trains(optics, envelope, width_points):
        nohd, condition = _nohd_point(optics, power_w, pulse_s, period_s)
        points += 1
        if nohd > worst[0]:
            worst = (nohd, pulse_s, period_s, condition)
    return EnvelopeCheck(worst[0], worst[1], worst[2], worst[3], float(closest_eye_m), points)


def envelope_max_power_w(optics: LineLaserOptics, closest_eye_m: float, envelope: FirmwareEnvelope,
                         width_points: int = 200) -> float:
    """Largest peak power (W) at which every train of the envelope is Class 1: the smallest of
    the trains' own limits (eq. 3.45), over the trains `verify_envelope` evaluates."""
    return min(safety.max_power_w(optics.train(pulse_s, period_s), closest_eye_m)
               for pulse_s, period_s in _allowed_trains(optics, envelope, width_points))


def envelope_for(max_pulse_s: float, min_period_s: float) -> FirmwareEnvelope:
    """The envelope for pulses up to ``max_pulse_s`` at most one per ``min_period_s``, in whole
    microseconds rounded to the safe side (pulse down, period up); not yet checked against the model."""
    max_pulse_us, min_period_us = _us_down(max_pulse_s), us_up(min_period_s)
    return FirmwareEnvelope(max_pulse_us, duty_ppm_for(max_pulse_us, min_period_us), min_period_us)


def duty_ppm_for(max_pulse_us: int, min_period_us: int) -> int:
    """The duty cap of an envelope: max_pulse / min_period rounded up to a whole percent, so that it
    never refuses a regular train the other two limits allow (the region, and so the check, is the
    same as without it); it still bounds irregular patterns pulse by pulse."""
    percent = math.ceil(100 * max_pulse_us / min_period_us - 1e-9)
    return min(percent, 99) * 10_000


def compute_envelope(optics: LineLaserOptics, power_w: float, closest_eye_m: float, max_pulse_s: float,
                     min_period_s: float) -> tuple[FirmwareEnvelope, EnvelopeCheck]:
    """The firmware envelope for pulses up to ``max_pulse_s`` at most one per ``min_period_s``
    (the sensor's pulse period minus the slack its sync needs), verified Class 1.

    Microseconds are rounded as in `envelope_for`.  Raises EnvelopeError naming the worst train and
    the shortest Class 1 period when the envelope is not Class 1.
    """
    envelope = envelope_for(max_pulse_s, min_period_s)
    check = verify_envelope(optics, power_w, closest_eye_m, envelope)
    if not check.class1:
        shortest = shortest_class1_period_s(optics, power_w, closest_eye_m, max_pulse_s)
        raise EnvelopeError(
            f"not Class 1 at {power_w * 1e3:g} mW with eyes >= {closest_eye_m * 1e3:g} mm: pulses up to "
            f"{max_pulse_s * 1e3:g} ms every {min_period_s * 1e3:g} ms reach a NOHD of {check.worst_nohd_m * 1e3:.2f} mm "
            f"({check.worst_pulse_s * 1e3:.3f} ms every {check.worst_period_s * 1e3:.2f} ms, "
            f"{check.limiting_condition}); the shortest Class 1 period for these pulses is "
            + (f"{shortest * 1e3:.2f} ms" if shortest is not None else "none (the single pulse alone is too much)"))
    return envelope, check


def shortest_class1_period_s(optics: LineLaserOptics, power_w: float, closest_eye_m: float,
                             max_pulse_s: float) -> float | None:
    """Shortest minimum period (s, whole microseconds) whose envelope with pulses up to ``max_pulse_s``
    is Class 1, by bisection (a longer minimum period allows a subset of the trains); None if even
    one pulse per 100 s is not."""
    pulse_us = _us_down(max_pulse_s)

    def ok(period_us: int) -> bool:
        env = FirmwareEnvelope(pulse_us, duty_ppm_for(pulse_us, period_us), period_us)
        return verify_envelope(optics, power_w, closest_eye_m, env, width_points=60).class1

    lo = max(pulse_us + MIN_GAP_US, MIN_PULSE_US + MIN_GAP_US) - 1  # lo: not known to be ok
    hi = int(safety.AVERAGING_TIME_S * 1e6)
    if not ok(hi):
        return None
    while hi - lo > 1:  # evaluates periods near the answer only, never the dense end
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi * 1e-6


def _us_down(seconds: float) -> int:
    """Whole microseconds, rounded down (a hair of float error aside)."""
    return math.floor(seconds * 1e6 + 1e-6)


def us_up(seconds: float) -> int:
    """Whole microseconds, rounded up (a hair of float error aside): an envelope's minimum period."""
    return math.ceil(seconds * 1e6 - 1e-6)


# ---------------------------------------------------------------- generator (python -m ...)
def main(argv: list[str] | None = None) -> int:
    """Prints the `make` line of the Class 1 envelope of a sensor configuration's laser."""
    from device.config import ConfigError, load_config, load_preset

    parser = argparse.ArgumentParser(prog="python -m device.model.envelope", description=main.__doc__)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--config", help="sensor configuration TOML (its [laser] table)")
    source.add_argument("--preset", help="a preset name, e.g. thesis-design")
    parser.add_argument("--power-mw", type=float, help="peak power (default: the configuration's power_w)")
    parser.add_argument("--closest-eye-mm", type=float, default=10.0,
                        help="closest distance an eye can reach (default 10: thesis 4.1.4)")
    parser.add_argument("--max-pulse-ms", type=float,
                        help="longest pulse the sensor needs (default: the configuration's pulse_s)")
    parser.add_argument("--slack-ms", type=float, default=SYNC_SLACK_S * 1e3,
                        help="minimum period = 1 / rate_hz minus this, room for the sync's period trims "
                             f"(ppm) and phase steps (default {SYNC_SLACK_S * 1e3:g})")
    args = parser.parse_args(argv)
    try:
        cfg = load_config(args.config) if args.config else load_preset(args.preset)
    except (ConfigError, OSError) as exc:
        parser.error(str(exc))
    laser = cfg.laser
    optics = LineLaserOptics(laser.wavelength_m * 1e9, laser.fan_angle_rad, laser.line_height_m,
                             laser.source_diameter_m)
    power_w = laser.power_w if args.power_mw is None else args.power_mw * 1e-3
    max_pulse_s = laser.pulse_s if args.max_pulse_ms is None else args.max_pulse_ms * 1e-3
    min_period_s = 1.0 / laser.rate_hz - args.slack_ms * 1e-3
    try:
        envelope, check = compute_envelope(optics, power_w, args.closest_eye_mm * 1e-3, max_pulse_s, min_period_s)
    except (EnvelopeError, ValueError) as exc:
        print(f"error: {exc}")
        return 1
    print(envelope.make_command())
    print(f"# worst NOHD {check.worst_nohd_m * 1e3:.2f} mm <= {args.closest_eye_mm:g} mm at "
          f"{check.worst_pulse_s * 1e3:.3f} ms every {check.worst_period_s * 1e3:.2f} ms ({check.limiting_condition}); "
          f"{check.points} trains checked; {power_w * 1e3:g} mW")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
