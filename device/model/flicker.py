"""Mains flicker in the difference of a lit frame and its unlit neighbours.

Lamps on AC mains (incandescent and halogen, fluorescent tubes, many LED drivers) modulate their
light at twice the mains frequency: 100 Hz on 50 Hz mains, 120 Hz on 60 Hz (the lamp's power
follows the square of the voltage). libcamera's AeFlickerPeriod (src/libcamera/
control_ids_core.yaml) cancels "50Hz mains flicker" with 10000 us and 60 Hz with 8333 us, and its
AeFlickerMode: "Although implementation dependent, many algorithms for "flicker avoidance" work by
restricting this exposure time to integer multiples of the cycle period, wherever possible."
Those act through the AGC; the device runs the camera at a manual exposure
(device/camera/picamera2_camera.py), so the rule is the configuration's here (device/config.py
``[operating_point] flicker_hz``).

Model. A component of the ambient light at frequency ``f`` with modulation depth ``m`` (of the
lamps' mean) adds to a row exposed over ``[t - E, t]`` the share ``m sinc(f E) cos(2 pi f t')``
of its mean light (``sinc(x) = sin(pi x) / (pi x)``, ``t'`` the exposure's middle). The rolling
shutter gives every row its own ``t``, so in one frame it is a row pattern (bands ``1 / f`` of
readout apart). The unlit neighbours are exposed one frame period ``T`` before and after the lit
frame: their rows' phases differ by ``-+2 pi f T``. What the flicker leaves, as a share of ``m``
times the light:

- lit minus one neighbour: ``2 |sinc(f E)| |sin(pi f T)|``;
- lit minus the neighbours' mean (device/vision/fast.py step 0): ``|sinc(f E)| (1 - cos 2 pi f T)``.

Both vanish exactly when ``f E`` or ``f T`` is a whole number, and then for every harmonic of ``f``
too: so for any waveform of that period, not only a sine. At 10 scans/s (frames 50 ms apart) both
100 and 120 Hz cancel by the frame period; at 20 scans/s (25 ms) 120 Hz does, but 100 Hz is 2.5
periods a frame, and a 9.2 ms exposure leaves 17 % of the lamps' modulation in lit minus one
neighbour (issue 18's rate, found on simulated frames: BENCHMARKS.md "Mains flicker at 15 and 20
scans/s"); a 10 ms exposure cancels it.

Near whole numbers. The sensor exposes whole lines (IMX219 register 0x015a, raspberrypi/linux
drivers/media/i2c/imx219.c; libcamera's CamHelper::exposureLines, src/ipa/rpi/cam_helper/
cam_helper.cpp, truncates the requested time to lines), so an exposure comes out up to a line
(18.9 us in mode 5) short: 10 ms is 529.0 lines, and a line short would leave 0.4 % at 100 Hz.
The mains drifts (50 +- 0.05 Hz is the usual band): where the exposure cancels, a 0.1 % drift
leaves 0.2 %; where the frame period does, it grows with the periods a frame holds (6 of 120 Hz
at 10 scans/s: 1.2 % of the modulation for 60.12 Hz mains, 0.2 % for 60.02 Hz).

Pure functions, no I/O.
"""

from __future__ import annotations

import math
from typing import Sequence

#: Flicker of lamps on 50 Hz and 60 Hz mains (twice the mains frequency).
MAINS_FLICKER_HZ = (100.0, 120.0)
#: The flicker a lit frame's difference may keep, as a share of the lamps' modulation depth
#: (lit minus one neighbour, the larger of the two residues): 1 %, a level or two of a bright
#: background under a lamp modulated in full.
MAX_RESIDUE = 0.01


def sinc(x: float) -> float:
    """sin(pi x) / (pi x), 1 at 0."""
    return 1.0 if x == 0 else math.sin(math.pi * x) / (math.pi * x)


def residue(exposure_s: float, frame_period_s: float, flicker_hz: float) -> float:
    """Flicker at ``flicker_hz`` left in a lit frame minus one unlit neighbour ``frame_period_s``
    away, as a share of the lamps' modulation depth (module docstring): ``2 |sinc(f E)| |sin(pi f T)|``."""
    if not all(x > 0 and math.isfinite(x) for x in (exposure_s, frame_period_s, flicker_hz)):
        raise ValueError(f"exposure, frame period and flicker frequency must be finite and positive, got "
                         f"{exposure_s}, {frame_period_s}, {flicker_hz}")
    return 2.0 * abs(sinc(flicker_hz * exposure_s)) * abs(math.sin(math.pi * flicker_hz * frame_period_s))


def _check_frequencies(flicker_hz: Sequence[float]) -> None:
    if not all(f > 0 and math.isfinite(f) for f in flicker_hz):  # False for NaN
        raise ValueError(f"flicker frequencies must be finite and positive, got {list(flicker_hz)}")


def not_cancelled_by_period(frame_period_s: float, flicker_hz: Sequence[float]) -> list[float]:
    """Those of ``flicker_hz`` that the frame period does not cancel (the exposure must)."""
    if not (frame_period_s > 0 and math.isfinite(frame_period_s)):
        raise ValueError(f"the frame period must be finite and positive, got {frame_period_s}")
    _check_frequencies(flicker_hz)
    return [float(f) for f in flicker_hz if 2.0 * abs(math.sin(math.pi * f * frame_period_s)) > MAX_RESIDUE]


def uncancelled(exposure_s: float, frame_period_s: float, flicker_hz: Sequence[float]) -> list[tuple[float, float]]:
    """(frequency, residue) of each of ``flicker_hz`` that leaves more than ``MAX_RESIDUE``."""
    out = [(float(f), residue(exposure_s, frame_period_s, f)) for f in flicker_hz]
    return [(f, r) for f, r in out if r > MAX_RESIDUE]


def cancelling_exposures_s(frame_period_s: float, longest_s: float, flicker_hz: Sequence[float]) -> list[float]:
    """The exposures up to ``longest_s`` with which none of ``flicker_hz`` is left, shortest first
    (each a whole number of the periods the frame period does not cancel; [] where it cancels all
    of them, or no exposure up to ``longest_s`` does)."""
    if not (longest_s > 0 and math.isfinite(longest_s)):
        raise ValueError(f"the longest exposure must be finite and positive, got {longest_s}")
    need = not_cancelled_by_period(frame_period_s, flicker_hz)
    if not need:
        return []
    base = 1.0 / min(need)  # whole numbers of the longest period, checked against the others
    candidates = (k * base for k in range(1, math.floor(longest_s / base * (1 + 1e-12)) + 1))
    return [e for e in candidates if not uncancelled(e, frame_period_s, need)]
