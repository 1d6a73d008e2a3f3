"""`laserpi focus`: the laser line's width and peak per region (device/vision/focus.py), the
in-focus width from the optics, and the terminal bars."""

import math

import numpy as np
import pytest

from device.commands.focus import render
from device.config import load_preset
from device.vision.focus import GAUSS_FWHM, RegionFocus, focused_width_px, region_focus

CFG = load_preset("thesis-calibrated")


def gaussian_line(sigma_cols, rows=200, cols=300, centre=100.3, peak=120.0):
    r = np.arange(rows, dtype=np.float64)[:, None]
    sigma = np.asarray(sigma_cols, dtype=np.float64)[None, :]
    lit = 20.0 + peak * np.exp(-0.5 * ((r - centre) / sigma) ** 2)
    return lit.astype(np.float32), np.full((rows, cols), 20.0, np.float32)


def test_the_width_is_the_lines_fwhm_region_by_region():
    sigma = np.repeat([1.0, 1.5, 2.5], 100)  # three regions, each sharper than the next
    lit, unlit = gaussian_line(sigma)
    lo, hi = np.full(300, 50), np.full(300, 150)
    regions = region_focus(lit, unlit, lo, hi, regions=3)
    assert [(r.first, r.last) for r in regions] == [(0, 100), (100, 200), (200, 300)]
    for r, s in zip(regions, (1.0, 1.5, 2.5)):
        assert r.width_px == pytest.approx(GAUSS_FWHM * s, rel=0.06)  # linear interpolation of the crossings
        assert r.peak == pytest.approx(120.0 * math.exp(-0.5 * (0.3 / s) ** 2), rel=1e-3)
    # a line outside the rows searched, or too faint, has no width
    none = region_focus(lit, unlit, np.full(300, 150), np.full(300, 199), regions=3)
    assert all(math.isnan(r.width_px) for r in none)
    with pytest.raises(ValueError, match="regions"):
        region_focus(lit, unlit, lo, hi, regions=0)
    with pytest.raises(ValueError, match="one size"):
        region_focus(lit, unlit[:10], lo, hi)


def test_the_in_focus_width_from_the_optics():
    line = CFG.camera.intrinsics.fy * CFG.laser.line_height_m / 4 / 2.0
    assert focused_width_px(CFG, 2.0, 1.1) == pytest.approx(GAUSS_FWHM * math.sqrt(1.1**2 + line**2 + 1 / 12))
    diffraction = focused_width_px(CFG, 2.0)
    assert 1.0 < diffraction < focused_width_px(CFG, 2.0, 1.1)  # 808 nm at f/2 on 2.24 um pixels
    assert focused_width_px(CFG, 0.5, 1.1) > focused_width_px(CFG, 3.0, 1.1)  # a near line is thicker
    with pytest.raises(ValueError, match="distance"):
        focused_width_px(CFG, 0.0)


def test_the_bars_grow_with_the_width_and_mark_the_target():
    regions = [RegionFocus(0, 100, 2.0, 50.0), RegionFocus(100, 200, 6.0, 20.0), RegionFocus(200, 300, math.nan, math.nan)]
    text = render(regions, 2.0, "detail").splitlines()
    assert text[0].startswith("laser line focus: target width 2.00 px")
    sharp, blurred, empty = text[2], text[3], text[4]
    assert blurred.count("#") > sharp.count("#") and sharp.count("|") == blurred.count("|") == 1
    assert sharp.index("|") == blurred.index("|")  # the target at one place
    assert " 2.00 " in sharp and "   50" in sharp and empty.rstrip().endswith("-")


@pytest.mark.slow
def test_focus_on_the_simulated_sensor(tmp_path, capsys):
    from device.cli import main

    png = tmp_path / "band.png"
    assert main(["focus", "--simulate", "--updates", "2", "--seconds", "60", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "laser line focus: target width 2.77 px" in out and "diffraction limit 1.22 px" in out
    import cv2

    band = cv2.imread(str(png))
    assert band is not None and band.shape[1] == 1640 and (band == (0, 0, 255)).all(axis=2).sum() > 1000  # the line in red
    widths = [float(line.split()[-2]) for line in out.splitlines() if line.strip()[:1].isdigit() and "#" in line]
    assert widths and all(2.0 < w < 4.0 for w in widths)  # the simulator's in-focus lens
