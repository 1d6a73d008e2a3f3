"""Mains flicker left in a lit frame's difference (device/model/flicker.py) and the configuration's
rule that follows from it (device/config.py [operating_point] flicker_hz)."""

import math

import numpy as np
import pytest

from device.config import ConfigError, load_preset, with_operating_point
from device.model.flicker import MAINS_FLICKER_HZ, MAX_RESIDUE, cancelling_exposures_s, residue, uncancelled

LINE_S = 18903.5e-9  # IMX219 mode 5 line (device/camera/modes.py)


def _row_light(wave, t_end: np.ndarray, exposure_s: float, n: int = 4001) -> np.ndarray:
    """Each row's mean light over [t_end - E, t_end], by the trapezoid rule on ``n`` samples."""
    t = t_end[:, None] - exposure_s * np.linspace(0.0, 1.0, n)[None, :]
    return np.trapezoid(wave(t), dx=1.0 / (n - 1), axis=1)


def _worst_difference(wave, exposure_s: float, frame_s: float) -> float:
    """Largest |lit row - the same row one frame earlier| over a flicker period of row times."""
    t = 0.3 + np.linspace(0.0, 0.0125, 200)  # rows' readout times: more than a period of 100 and 120 Hz
    return float(np.max(np.abs(_row_light(wave, t, exposure_s) - _row_light(wave, t - frame_s, exposure_s))))


@pytest.mark.parametrize("exposure_s, frame_s, hz", [
    (9.2e-3, 25e-3, 100.0), (9.2e-3, 1 / 30, 100.0), (5e-3, 1 / 36, 120.0), (12.3e-3, 31.25e-3, 120.0),
    (10e-3, 25e-3, 100.0), (9.2e-3, 50e-3, 120.0),
])
def test_residue_is_the_difference_of_the_rows_integrated_light(exposure_s, frame_s, hz):
    depth = 0.3
    wave = lambda t: 1.0 + depth * np.sin(2 * math.pi * hz * t)  # noqa: E731
    assert residue(exposure_s, frame_s, hz) * depth == pytest.approx(_worst_difference(wave, exposure_s, frame_s),
                                                                      abs=2e-4)


def test_whole_periods_cancel_every_harmonic():
    """A square wave (an LED's on/off driver) at 100 Hz: its harmonics at 200, 300 Hz... cancel with
    the fundamental when the exposure or the frame period is a whole number of 10 ms."""
    square = lambda t: 1.0 + 0.5 * np.sign(np.sin(2 * math.pi * 100.0 * t))  # noqa: E731
    assert _worst_difference(square, 10e-3, 25e-3) < 1e-3
    assert _worst_difference(square, 9.2e-3, 30e-3) < 1e-3
    assert _worst_difference(square, 9.2e-3, 25e-3) > 0.05


def test_near_whole_numbers():
    """Hard cases: the sensor exposes whole lines and libcamera truncates the time to them, so an
    exposure comes out up to a line short; the mains drifts by a tenth of a percent, rarely by
    more. Within MAX_RESIDUE where the exposure cancels; where the frame period does, the drift
    grows with the periods a frame holds. A tenth of a period off is far outside."""
    assert residue(529 * LINE_S, 25e-3, 100.0) < 0.01 * MAX_RESIDUE  # 10 ms is 529.0 lines
    for e in (10e-3 - LINE_S, 10e-3 - LINE_S / 2, 10e-3 + LINE_S / 2):
        assert residue(e, 25e-3, 100.0) < 0.4 * MAX_RESIDUE
    assert residue(10e-3, 25e-3, 100.1) < 0.3 * MAX_RESIDUE  # 50.05 Hz: the grid's usual band
    assert residue(10e-3, 25e-3, 100.4) < MAX_RESIDUE  # 50.2 Hz: rare
    assert residue(10e-3, 50e-3, 120.04) < 0.3 * MAX_RESIDUE  # 120 Hz by the 50 ms frames, 60.02 Hz mains
    assert MAX_RESIDUE < residue(10e-3, 50e-3, 120.24) < 1.5 * MAX_RESIDUE  # 60.12 Hz: 6 periods a frame
    assert residue(9e-3, 25e-3, 100.0) > 10 * MAX_RESIDUE
    assert residue(1e-9, 25e-3, 100.0) == pytest.approx(2.0, rel=1e-6)  # a short exposure keeps it all
    for bad in ((0.0, 25e-3, 100.0), (10e-3, -1.0, 100.0), (10e-3, 25e-3, 0.0), (math.nan, 25e-3, 100.0),
                (10e-3, math.inf, 100.0)):
        with pytest.raises(ValueError):
            residue(*bad)
    for bad in ((25e-3, 24e-3, (math.nan,)), (0.0, 24e-3, (100.0,)), (25e-3, math.inf, (100.0,)),
                (25e-3, 24e-3, (-100.0,))):
        with pytest.raises(ValueError):
            cancelling_exposures_s(*bad)


def test_which_exposures_cancel():
    assert uncancelled(9.2e-3, 25e-3, MAINS_FLICKER_HZ) == [(100.0, pytest.approx(0.172, abs=1e-3))]
    assert uncancelled(9.2e-3, 50e-3, MAINS_FLICKER_HZ) == []
    def exposures(frame_s, flicker_hz):
        return cancelling_exposures_s(frame_s, frame_s - 4 * LINE_S, flicker_hz)

    assert exposures(25e-3, MAINS_FLICKER_HZ) == pytest.approx([10e-3, 20e-3])
    assert exposures(1 / 30, MAINS_FLICKER_HZ) == pytest.approx([10e-3, 20e-3, 30e-3])
    assert exposures(1 / 36, MAINS_FLICKER_HZ) == []  # 18 scans/s: 100 and 120 Hz both left
    assert exposures(1 / 36, (120.0,)) == pytest.approx([1 / 120, 2 / 120, 3 / 120])


def test_the_configuration_refuses_an_exposure_that_keeps_flicker():
    from device.design.report import sensor_at_rate

    at20, _ = sensor_at_rate(load_preset("thesis-calibrated"), 20.0)
    assert at20.operating_point.exposure_us == 10000.0
    with pytest.raises(ConfigError, match=r"exposure_us = 9200 at 20 scans/s .* leaves 100 Hz flicker .* up to 17% "
                                          r".* an exposure_us of 10000 or 20000 cancels it"):
        with_operating_point(at20, exposure_us=9200.0)
    with pytest.raises(ConfigError, match=r"at 18 scans/s .* leaves 120 Hz .* "
                                          r"no exposure within a frame cancels 100 and 120 Hz"):
        with_operating_point(at20, scan_rate_hz=18.0)
    # 7 scans/s (71.4 ms frames) cancels neither: 10 ms leaves 120 Hz, and only 50 ms cancels both
    with pytest.raises(ConfigError, match=r"10000 at 7 scans/s .* leaves 120 Hz .* an exposure_us of 50000 cancels it"):
        with_operating_point(at20, scan_rate_hz=7.0, exposure_us=10000.0)
    # where no mains lighting is, or only 50 Hz mains; a list as a file's
    assert with_operating_point(at20, exposure_us=9200.0, flicker_hz=()).operating_point.exposure_us == 9200.0
    assert with_operating_point(at20, scan_rate_hz=18.0, flicker_hz=[100.0]).operating_point.flicker_hz == (100.0,)
    # what a file could not say cannot come in through with_operating_point either
    for bad, field in (({"flicker_hz": (math.nan,)}, "flicker_hz"), ({"flicker_hz": 100.0}, "flicker_hz"),
                       ({"flicker_hz": (0.0,)}, "flicker_hz"), ({"exposure_us": 0.0}, "exposure_us"),
                       ({"exposure_us": -5.0, "flicker_hz": ()}, "exposure_us"), ({"analog_gain": math.nan}, "analog_gain")):
        with pytest.raises(ConfigError, match=f"'{field}' must be"):
            with_operating_point(at20, **bad)


def test_evaluate_names_the_flicker_any_of_a_recordings_frames_keeps():
    """A recording whose exposure changed part way: the frames at 9.2 ms and 25 ms apart keep 100
    Hz flicker, those at 10 ms none; evaluate reports the frequency once, at its largest share."""
    from device.camera.frame import Frame
    from device.commands.evaluate import _flicker_kept

    def lit(exposure_us, frame_us=25000.0):
        return Frame(np.zeros((2, 2), np.uint8), 0, 10**9, exposure_us, frame_us, 18903.5, lit=True)

    assert _flicker_kept([lit(10000.0), lit(10000.0)], MAINS_FLICKER_HZ) == []
    kept = _flicker_kept([lit(10000.0), lit(9200.0), lit(9500.0)], MAINS_FLICKER_HZ)
    assert [k["hz"] for k in kept] == [100.0] and kept[0]["residue"] == pytest.approx(residue(9.2e-3, 25e-3, 100.0))
    assert _flicker_kept([lit(9200.0, 50000.0)], MAINS_FLICKER_HZ) == []  # 10 scans/s: the frame period cancels
