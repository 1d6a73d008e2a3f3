"""Background (solar) irradiance against the laser return (thesis section 3.4, eq. 3.46).

The sun's spectral irradiance is the ASTM G173-03 AM1.5 reference spectrum ("Spectra 1.5" in
the thesis, docs/thesis-notes.md N9), global-tilt column, shipped for 600-1100 nm as
``device/model/data/astm_g173_global_600_1100nm.csv`` (extracted from pvlib's copy of the
table; pvlib itself is not a dependency). SI units: W/m^2, metres; wavelengths in nm.

Eq. 3.46 compares the laser power spread over its projected line with the solar irradiance
passed by the bandpass filter; docs/thesis-notes.md N9 fixes its units (mW, mW/cm^2, cm). Written in SI the
equation is the same, since the ratio P / (E * area) is unit-free.
"""

from __future__ import annotations

import math
from importlib import resources

import numpy as np

SPECTRUM_FILE = "astm_g173_global_600_1100nm.csv"
#: Indoor irradiance as a fraction of outdoor, thesis 4.1.4 citing [36] ("typically less than 20%").
INDOOR_FRACTION = 0.2


def solar_spectrum() -> tuple[np.ndarray, np.ndarray]:
    """ASTM G173 global-tilt spectrum: (wavelength_nm (n,), irradiance W m^-2 nm^-1 (n,))."""
    with resources.files("device.model").joinpath("data", SPECTRUM_FILE).open("r") as f:
        lines = [line for line in f if not line.startswith("#")]
    if lines[0].strip() != "wavelength_nm,global_tilt_w_m2_nm":
        raise ValueError(f"{SPECTRUM_FILE}: unexpected header {lines[0].strip()!r}")
    table = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    return table[:, 0], table[:, 1]


def band_irradiance_w_m2(center_nm: float, width_nm: float,
                         spectrum: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Solar irradiance through an ideal bandpass ``center_nm +/- width_nm / 2`` (W/m^2).

    Trapezoidal integration of the spectrum, with the band edges interpolated linearly.
    Raises ValueError if the band leaves the tabulated spectrum.
    """
    wavelength, irradiance = solar_spectrum() if spectrum is None else spectrum
    center_nm, width_nm = float(center_nm), float(width_nm)
    if not (math.isfinite(center_nm) and math.isfinite(width_nm) and width_nm > 0):
        raise ValueError(f"bandpass needs a finite centre and a positive width, got {center_nm!r} +/- {width_nm!r}")
    lo, hi = center_nm - 0.5 * width_nm, center_nm + 0.5 * width_nm
    if lo < wavelength[0] or hi > wavelength[-1]:
        raise ValueError(
            f"bandpass {lo:g}-{hi:g} nm leaves the shipped solar spectrum "
            f"({wavelength[0]:g}-{wavelength[-1]:g} nm)")
    inside = (wavelength > lo) & (wavelength < hi)
    grid = np.concatenate(([lo], wavelength[inside], [hi]))
    values = np.interp(grid, wavelength, irradiance)
    # the trapezoid rule, written out as numpy's np.trapezoid computes it (that name is numpy >= 2;
    # a Pi runs Raspberry Pi OS bookworm's numpy 1.24, README "On the Pi")
    return float((np.diff(grid) * (values[1:] + values[:-1]) / 2.0).sum())


def _line_area_per_distance(fan_rad: float, line_height_m: float) -> float:
    """Area of the projected line per metre of distance, 2 tan(phi/2) y (eq. 3.43, 3.46)."""
    if not (0.0 < fan_rad < math.pi):
        raise ValueError(f"fan angle {math.degrees(fan_rad):g} deg must be in (0, 180) deg")
    if not (math.isfinite(line_height_m) and line_height_m > 0):
        raise ValueError(f"line height must be positive, got {line_height_m!r}")
    return 2.0 * math.tan(0.5 * fan_rad) * line_height_m


def return_to_background(distance_m, power_w: float, background_w_m2: float,
                         fan_rad: float, line_height_m: float) -> np.ndarray:
    """Laser irradiance on a target over background irradiance at ``distance_m`` (eq. 3.46 solved for pp).

    ``P / (x * E_sun * 2 tan(phi/2) y)``; array in, array out (same shape). Distances <= 0
    give NaN: the line model does not hold at the source.
    """
    if not (power_w > 0 and background_w_m2 > 0):
        raise ValueError(f"laser power and background must be positive, got {power_w!r}, {background_w_m2!r}")
    x = np.asarray(distance_m, dtype=float)
    per_m = _line_area_per_distance(fan_rad, line_height_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = power_w / (x * background_w_m2 * per_m)
    return np.where(x > 0, ratio, np.nan)


def background_limited_distance_m(power_w: float, background_w_m2: float, fraction: float,
                                  fan_rad: float, line_height_m: float) -> float:
    """Eq. 3.46: distance at which the laser return is ``fraction`` (pp, in (0, 1]) of the background."""
    if not (0.0 < fraction <= 1.0):
        raise ValueError(f"fraction pp must be in (0, 1], got {fraction!r}")
    if not (power_w > 0 and background_w_m2 > 0):
        raise ValueError(f"laser power and background must be positive, got {power_w!r}, {background_w_m2!r}")
    return power_w / (fraction * background_w_m2 * _line_area_per_distance(fan_rad, line_height_m))
