"""Eye safety of a pulsed line laser: IEC 60825-1 Class 1, 600-1050 nm (thesis section 3.3).

Pure functions, scalars in, scalars out. Units: SI at the interface (seconds, metres, watts,
joules) except where a name says otherwise: the wavelength is in nm and angular subtenses are
in mrad, because the standard's formulas are written in those units.

Readings of the thesis used here (see docs/thesis-notes.md and the notes on each function):

* docs/thesis-notes.md N1: the repetitive-pulse condition *multiplies* the single-pulse AEL by C5 (<= 1):
  ``AEL_s.p.train = AEL_single x C5``; the thesis's eq. 3.34 divides.
* docs/thesis-notes.md N2: the ``alpha`` of eq. 3.20-3.23 and 3.35-3.36 is the angular subtense of the
  apparent source (eq. 3.21), not the camera tilt of the triangulation model. Here it is
  always called ``subtense_mrad``.
* docs/thesis-notes.md N13: eq. 3.40-3.42 as printed put H_mpe in the numerator of the NOHD, which is dimensionally
  wrong (an area cannot be fluence x energy). The NOHD here is the exact inverse of
  eq. 3.45 (max power for a given NOHD), which is dimensionally right:
  ``nohd = P t / (H_mpe 2 tan(phi/2) y)``.
* docs/thesis-notes.md N13: where the beam at the viewing distance is smaller than the pupil, the whole pulse enters
  the eye; eq. 3.44 would let the power grow without bound as the area shrinks, so the
  fraction of the pulse reaching the eye is capped at 1.
* docs/thesis-notes.md N14: condition 2 (average over T) evaluates every duration-dependent factor (alpha_max inside
  C6) at the duration T, as IEC 60825-1 does for "the AEL of a single pulse of duration T".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Eq. 3.37: pulses closer together than this count as one pulse (400-1050 nm).
PULSE_GROUPING_S = 5e-6
#: Condition 2 time base for lambda > 400 nm without intentional long-term viewing.
AVERAGING_TIME_S = 100.0
#: Distance at which the angular subtense of the source is evaluated (eq. 3.21).
SUBTENSE_DISTANCE_M = 0.100
#: Pupil diameter assumed by IEC 60825-1 (eq. 3.38), 7 mm.
PUPIL_DIAMETER_M = 7e-3
#: Eq. 3.22.
ALPHA_MIN_MRAD = 1.5

WAVELENGTH_RANGE_NM = (600.0, 1050.0)
PULSE_RANGE_S = (5e-6, 0.25)

CONDITION_SINGLE = "single_pulse"
CONDITION_AVERAGE = "average_power"
CONDITION_TRAIN = "pulse_train"


def mw_down(power_w: float) -> float:
    """``power_w`` in mW rounded down to 0.01 mW, as power limits are printed: a limit copied from
    a report or a message is never above the limit."""
    return math.floor(round(power_w * 1e5, 6)) / 100  # the round: 0.3 mW as 0.0003 W is 29.999999999999996 x 0.01 mW


def _check_finite_positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return value


def _check_wavelength(wavelength_nm: float) -> float:
    wavelength_nm = float(wavelength_nm)
    lo, hi = WAVELENGTH_RANGE_NM
    if not (lo <= wavelength_nm <= hi):
        raise ValueError(
            f"wavelength_nm={wavelength_nm:g} is outside {lo:g}-{hi:g} nm: this Class 1 model "
            "(thesis 3.3, thermal retinal limits) only covers that band")
    return wavelength_nm


def _check_pulse(pulse_s: float) -> float:
    pulse_s = _check_finite_positive("pulse duration", pulse_s)
    lo, hi = PULSE_RANGE_S
    if not (lo <= pulse_s <= hi):
        raise ValueError(
            f"pulse duration {pulse_s * 1e3:g} ms is outside {lo * 1e3:g} ms..{hi * 1e3:g} ms, "
            "the range in which the AEL of eq. 3.18 and alpha_max of eq. 3.23 hold")
    return pulse_s


def c4(wavelength_nm: float) -> float:
    """Wavelength correction C4, eq. 3.19 (600-1050 nm)."""
    wavelength_nm = _check_wavelength(wavelength_nm)
    if wavelength_nm < 700.0:
        return 1.0
    return 10.0 ** (0.002 * (wavelength_nm - 700.0))


def angular_subtense_mrad(source_diameter_m: float, distance_m: float = SUBTENSE_DISTANCE_M) -> float:
    """Angular subtense of the apparent source in mrad, eq. 3.21: 2000 atan(d / 2r), r = 100 mm.

    Named apart from the camera tilt alpha of the triangulation model (docs/thesis-notes.md N2).
    """
    source_diameter_m = _check_finite_positive("source diameter", source_diameter_m)
    distance_m = _check_finite_positive("viewing distance", distance_m)
    if distance_m < SUBTENSE_DISTANCE_M:
        raise ValueError(f"viewing distance {distance_m * 1e3:g} mm is below the 100 mm of eq. 3.21")
    return 2000.0 * math.atan(0.5 * source_diameter_m / distance_m)


def alpha_max_mrad(duration_s: float) -> float:
    """Largest angular subtense that still counts as extended-source, eq. 3.23 (mrad)."""
    duration_s = _check_finite_positive("duration", duration_s)
    if duration_s < 625e-6:
        return 5.0
    if duration_s <= 0.25:
        return 200.0 * math.sqrt(duration_s)
    return 100.0


def c6(subtense_mrad: float, duration_s: float) -> float:
    """Extended-source correction C6, eq. 3.20, with alpha_min (3.22) and alpha_max (3.23)."""
    subtense_mrad = _check_finite_positive("angular subtense", subtense_mrad)
    a_max = alpha_max_mrad(duration_s)
    if subtense_mrad <= ALPHA_MIN_MRAD:
        return 1.0
    if subtense_mrad <= a_max:
        return subtense_mrad / ALPHA_MIN_MRAD
    return a_max / ALPHA_MIN_MRAD


def t2_s(subtense_mrad: float) -> float:
    """Time window T2 over which pulses are counted for C5, eq. 3.36 (seconds)."""
    subtense_mrad = _check_finite_positive("angular subtense", subtense_mrad)
    if subtense_mrad <= ALPHA_MIN_MRAD:
        return 10.0
    if subtense_mrad <= 100.0:
        return 10.0 * 10.0 ** ((subtense_mrad - ALPHA_MIN_MRAD) / 98.5)
    return 100.0


def pulses_in_window(window_s: float, rate_hz: float, grouping_s: float = PULSE_GROUPING_S) -> int:
    """Number of pulses of a regular train that fall in a window, eq. 3.37 grouping applied.

    Pulses closer together than ``grouping_s`` (Ti) count as one, so the effective rate is at
    most 1/Ti. A window that does not hold a whole number of periods is rounded up: counting
    one pulse more is the conservative side (smaller C5, smaller average-power limit).
    """
    window_s = _check_finite_positive("window", window_s)
    rate_hz = _check_finite_positive("pulse rate", rate_hz)
    grouping_s = _check_finite_positive("grouping time Ti", grouping_s)
    effective_rate_hz = min(rate_hz, 1.0 / grouping_s)
    # The tolerance keeps 100 s x 10 Hz at 1000 and not 1001 from floating-point noise.
    return max(1, math.ceil(window_s * effective_rate_hz - 1e-9))


def c5(subtense_mrad: float, pulse_count: int, pulse_s: float) -> float:
    """Repetitive-pulse correction C5 (<= 1), eq. 3.35, as printed in the thesis.

    ``pulse_count`` is N, the number of pulses in T2 (``pulses_in_window(t2_s(...), rate)``);
    alpha_max is that of the single pulse duration.
    """
    subtense_mrad = _check_finite_positive("angular subtense", subtense_mrad)
    if isinstance(pulse_count, bool) or int(pulse_count) != pulse_count or pulse_count < 1:
        raise ValueError(f"pulse count N must be a positive integer, got {pulse_count!r}")
    n = int(pulse_count)
    a_max = alpha_max_mrad(pulse_s)
    if subtense_mrad <= 5.0 or subtense_mrad > 100.0:
        return 1.0
    if subtense_mrad <= a_max:
        return n ** -0.25 if n <= 40 else 0.4
    return n ** -0.25 if n <= 625 else 0.2


def ael_j(duration_s: float, wavelength_nm: float, subtense_mrad: float) -> float:
    """Class 1 accessible emission limit of one exposure of ``duration_s``, eq. 3.18 (J).

    ``7e-4 t^0.75 C4 C6``, with C6 evaluated at this duration.
    """
    duration_s = _check_finite_positive("duration", duration_s)
    return 7e-4 * duration_s ** 0.75 * c4(wavelength_nm) * c6(subtense_mrad, duration_s)


def pupil_area_m2() -> float:
    """Eq. 3.38: area of a 7 mm pupil (0.385 cm^2)."""
    return math.pi * (0.5 * PUPIL_DIAMETER_M) ** 2


@dataclass(frozen=True)
class PulsedLineLaser:
    """The laser inputs of the safety model (thesis Table 3.3), SI units.

    ``fan_rad`` is the horizontal divergence phi, ``line_height_m`` the height y of the
    projected line, ``source_diameter_m`` the diameter d of the apparent source.
    """

    wavelength_nm: float
    pulse_s: float
    rate_hz: float
    fan_rad: float
    line_height_m: float
    source_diameter_m: float

    def __post_init__(self) -> None:
        _check_wavelength(self.wavelength_nm)
        _check_pulse(self.pulse_s)
        _check_finite_positive("pulse rate", self.rate_hz)
        if self.pulse_s >= 1.0 / self.rate_hz:
            raise ValueError(
                f"pulse duration {self.pulse_s * 1e3:g} ms is not shorter than the period "
                f"{1e3 / self.rate_hz:g} ms at {self.rate_hz:g} Hz: that is not a pulsed source")
        fan = _check_finite_positive("fan angle", self.fan_rad)
        if fan >= math.pi:
            raise ValueError(f"fan angle {math.degrees(fan):g} deg must be below 180 deg")
        _check_finite_positive("line height", self.line_height_m)
        _check_finite_positive("source diameter", self.source_diameter_m)


@dataclass(frozen=True)
class PulseEnergyLimit:
    """The three Class 1 conditions as per-pulse energy limits (J), eq. 3.24.

    single_pulse_j: condition 1, eq. 3.27. average_power_j: condition 2, eq. 3.31
    (AEL over T = 100 s shared by the N pulses in T). pulse_train_j: condition 3,
    AEL_single x C5 (docs/thesis-notes.md N1). ``limit_j`` is the smallest and ``limiting_condition`` names it.
    """

    subtense_mrad: float
    c4: float
    c6: float
    c5: float
    t2_s: float
    pulses_in_t2: int
    pulses_in_t: int
    single_pulse_j: float
    average_power_j: float
    pulse_train_j: float

    @property
    def limit_j(self) -> float:
        return min(self.single_pulse_j, self.average_power_j, self.pulse_train_j)

    @property
    def limiting_condition(self) -> str:
        by_name = {CONDITION_SINGLE: self.single_pulse_j, CONDITION_AVERAGE: self.average_power_j,
                   CONDITION_TRAIN: self.pulse_train_j}
        # min() keeps the first of equal values: ties name the simplest condition.
        return min(by_name, key=by_name.__getitem__)

    @property
    def h_mpe_j_per_m2(self) -> float:
        """Eq. 3.39: the per-pulse limit spread over the pupil (J/m^2)."""
        return self.limit_j / pupil_area_m2()


def pulse_energy_limit(laser: PulsedLineLaser, averaging_time_s: float = AVERAGING_TIME_S) -> PulseEnergyLimit:
    """Largest energy per pulse that keeps ``laser`` Class 1, eq. 3.18-3.37 with docs/thesis-notes.md N1, N2."""
    subtense = angular_subtense_mrad(laser.source_diameter_m)
    single = ael_j(laser.pulse_s, laser.wavelength_nm, subtense)
    n_t = pulses_in_window(averaging_time_s, laser.rate_hz)
    average = ael_j(averaging_time_s, laser.wavelength_nm, subtense) / n_t
    t2 = t2_s(subtense)
    n_t2 = pulses_in_window(t2, laser.rate_hz)
    c5_value = c5(subtense, n_t2, laser.pulse_s)
    return PulseEnergyLimit(
        subtense_mrad=subtense, c4=c4(laser.wavelength_nm), c6=c6(subtense, laser.pulse_s),
        c5=c5_value, t2_s=t2, pulses_in_t2=n_t2, pulses_in_t=n_t,
        single_pulse_j=single, average_power_j=average, pulse_train_j=single * c5_value)


def line_area_m2(distance_m: float, fan_rad: float, line_height_m: float) -> float:
    """Eq. 3.43: area of the projected line at ``distance_m``: 2 r tan(phi/2) y."""
    return 2.0 * distance_m * math.tan(0.5 * fan_rad) * line_height_m


def max_power_w(laser: PulsedLineLaser, nohd_m: float, limit: PulseEnergyLimit | None = None) -> float:
    """Eq. 3.45: the largest peak power whose NOHD is ``nohd_m`` (W).

    The pupil collects ``A_eye / A_line`` of each pulse, capped at the whole pulse when the
    line at that distance is smaller than the pupil.
    """
    nohd_m = _check_finite_positive("NOHD", nohd_m)
    limit = pulse_energy_limit(laser) if limit is None else limit
    area = line_area_m2(nohd_m, laser.fan_rad, laser.line_height_m)
    return limit.h_mpe_j_per_m2 * max(area, pupil_area_m2()) / laser.pulse_s


def nohd_m(laser: PulsedLineLaser, power_w: float, limit: PulseEnergyLimit | None = None) -> float:
    """NOHD of a laser of peak power ``power_w`` (m): the inverse of eq. 3.45 (eq. 3.42 corrected).

    Returns 0 when even the whole pulse entering the eye stays below the limit.
    """
    power_w = _check_finite_positive("laser power", power_w)
    limit = pulse_energy_limit(laser) if limit is None else limit
    if power_w * laser.pulse_s <= limit.limit_j:
        return 0.0
    distance = power_w * laser.pulse_s / (
        limit.h_mpe_j_per_m2 * 2.0 * math.tan(0.5 * laser.fan_rad) * laser.line_height_m)
    # power_w * t > limit_j puts the line at this distance above the pupil's area, so the
    # uncapped branch of max_power_w applies and the two functions are exact inverses.
    return distance


@dataclass(frozen=True)
class SafetyAssessment:
    """Result of `assess`: the power allowed at the closest eye distance and the NOHD."""

    limit: PulseEnergyLimit
    closest_eye_m: float
    max_power_w: float
    power_w: float | None
    nohd_m: float

    @property
    def class1(self) -> bool:
        # The relative slack absorbs rounding when power_w is exactly max_power_w.
        return self.nohd_m <= self.closest_eye_m * (1.0 + 1e-9)

    @property
    def limiting_condition(self) -> str:
        return self.limit.limiting_condition


def assess(laser: PulsedLineLaser, closest_eye_m: float, power_w: float | None = None) -> SafetyAssessment:
    """Class 1 check of a line laser that no eye can get closer to than ``closest_eye_m``.

    Without ``power_w`` the laser is taken at its maximum allowed power, whose NOHD is
    ``closest_eye_m`` by construction. With it, Class 1 holds when its NOHD is at most
    ``closest_eye_m`` (thesis 4.1.4: eyes cannot come closer than 1 cm).
    """
    closest_eye_m = _check_finite_positive("closest eye distance", closest_eye_m)
    limit = pulse_energy_limit(laser)
    p_max = max_power_w(laser, closest_eye_m, limit)
    if power_w is None:
        return SafetyAssessment(limit, closest_eye_m, p_max, None, closest_eye_m)
    return SafetyAssessment(limit, closest_eye_m, p_max, float(power_w), nohd_m(laser, power_w, limit))
