"""The backward-projection benchmark's accuracy columns (not its timings)."""

import numpy as np

from device.bench.model import LookupTable, lenses, run_benchmark
from device.model.camera import pixel_grid, undistort_robust


def test_checked_variants_never_return_a_wrong_point():
    rows = run_benchmark(step=24, repeats=1)
    by = {(r["lens"], r["variant"]): r for r in rows}
    for lens in lenses():
        for variant in ("fixed-5 (thesis)", "fixed-20", "robust", "lookup-table"):
            assert by[lens, variant]["wrong_valid"] == 0, (lens, variant)
        assert by[lens, "robust"]["max_err_px"] < 1e-5
    # OpenCV's default 5 iterations return wrong points on the thesis's own lens without a flag
    assert by["thesis-calibrated", "opencv-5"]["wrong_valid"] > 0


def test_lookup_table_interpolates_within_tolerance():
    cam = lenses()["thesis-calibrated"]
    table = LookupTable.build(cam)
    pix = pixel_grid(1664, 928)[5::97, 3::89] + np.array([0.5, 0.5])
    xy = table(pix)
    ref = undistort_robust(pix, cam).xy
    assert np.all(np.abs(xy - ref) * cam.intrinsics.fx < 0.01)
