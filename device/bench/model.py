"""`laserpi bench model`: backward-projection variants, time per full pixel grid against error.

Every variant un-projects the same full grid of pixel positions (all pixel centres of a
1664x928 frame shifted by (0.25, 0.5) px, so that a lookup table is also tested between its
nodes). Error is the angle between the variant's ray and the ray of a high-precision reference
(the robust solver run to 1e-8 px, or to 1e-5 / 1e-3 px next to a fold where double
precision cannot do better), times the focal length: pixel-equivalent units that stay
meaningful for a fisheye near 90 deg. Maxima and RMS are over the points the variant returns
as valid. "flagged" is the fraction of points a variant reports invalid; "wrong" counts points
returned valid that are more than 0.01 px from the reference, or that have no preimage at all -
the number that must be zero. OpenCV returns no validity, so every point counts as returned.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..model.camera import (
    BrownConrady, CameraModel, Intrinsics, KannalaBrandt, Unprojection, lens_model, pixel_grid, undistort_fixed,
    undistort_robust,
)

WRONG_PX = 0.01


def lenses() -> dict[str, CameraModel]:
    from ..config import load_preset

    return {
        "thesis-calibrated": load_preset("thesis-calibrated").camera,
        # a strong wide-angle Brown-Conrady lens whose profile turns back inside the frame corners
        "wide-folding": CameraModel(Intrinsics(520.0, 520.0, 832.0, 464.0, 0.0, 1664, 928), BrownConrady(-0.28, 0.06, -0.004)),
        # a 170 deg fisheye (OpenCV fisheye model)
        "fisheye-170": CameraModel(Intrinsics(540.0, 540.0, 832.0, 464.0, 0.0, 1664, 928), KannalaBrandt(0.012, -0.004, 0.0008, -0.0001)),
    }


@dataclass
class LookupTable:
    """Per-pixel table of unit rays from the robust solver, bilinear in between.

    Rays rather than normalised coordinates, so that a fisheye near 90 deg interpolates well.
    Cells where bilinear interpolation would err by more than ``tol_px`` (estimated from the
    second differences of the rays, h^2/8 |f''|) are marked invalid, as are cells touching a
    pixel without a valid solution.
    """

    rays: np.ndarray  # (H, W, 3), NaN where invalid

    @staticmethod
    def build(cam: CameraModel, tol_px: float = WRONG_PX) -> "LookupTable":
        k = cam.intrinsics
        xy = undistort_robust(pixel_grid(k.width, k.height), cam).xy
        rays = np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1)
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        f = max(k.fx, k.fy)
        curv = np.zeros(rays.shape[:2])
        curv[:, 1:-1] = np.linalg.norm(rays[:, 2:] - 2 * rays[:, 1:-1] + rays[:, :-2], axis=-1)
        curv[1:-1, :] = np.maximum(curv[1:-1, :], np.linalg.norm(rays[2:] - 2 * rays[1:-1] + rays[:-2], axis=-1))
        bad = ~(curv * f / 8 * 2 <= tol_px)  # both directions add up in the worst case
        bad[[0, -1], :] = bad[[1, -2], :]
        bad[:, [0, -1]] = bad[:, [1, -2]]
        rays[bad] = np.nan
        return LookupTable(rays)

    def __call__(self, pixels: np.ndarray) -> np.ndarray:
        h, w = self.rays.shape[:2]
        u = np.clip(pixels[..., 0], 0, w - 1.000001)
        v = np.clip(pixels[..., 1], 0, h - 1.000001)
        u0, v0 = u.astype(np.intp), v.astype(np.intp)
        fu, fv = (u - u0)[..., None], (v - v0)[..., None]
        t = self.rays
        top = t[v0, u0] * (1 - fu) + t[v0, u0 + 1] * fu
        bot = t[v0 + 1, u0] * (1 - fu) + t[v0 + 1, u0 + 1] * fu
        ray = top * (1 - fv) + bot * fv
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(ray[..., 2:] > 0, ray[..., :2] / ray[..., 2:], np.nan)


def ray_angle_px(xy: np.ndarray, ref: np.ndarray, f: float) -> np.ndarray:
    """Angle between the rays through normalised points xy and ref, times f (pixel-equivalent)."""
    a = np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1)
    b = np.concatenate([ref, np.ones_like(ref[..., :1])], axis=-1)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(a * b, axis=-1)) * f


def _opencv(cam: CameraModel, iterations: int) -> Callable[[np.ndarray], np.ndarray]:
    import cv2

    crit = (cv2.TERM_CRITERIA_COUNT, iterations, 0.0)
    undistort = lens_model(cam.distortion).opencv_undistort
    k, d = cam.intrinsics.matrix, cam.distortion.opencv_coefficients()
    return lambda pix: undistort(pix, k, d, crit)


def variants(cam: CameraModel) -> dict[str, Callable[[np.ndarray], np.ndarray | Unprojection]]:
    table = LookupTable.build(cam)
    return {
        "fixed-5 (thesis)": lambda p: undistort_fixed(p, cam, iterations=5),
        "fixed-20": lambda p: undistort_fixed(p, cam, iterations=20),
        "opencv-5": _opencv(cam, 5),
        "opencv-20": _opencv(cam, 20),
        "robust": lambda p: undistort_robust(p, cam),
        "lookup-table": table,
    }


def _median_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def run_benchmark(step: int = 1, repeats: int = 3) -> list[dict]:
    """Rows of results; ``step`` > 1 subsamples the grid (for quick checks), 1 is the full grid."""
    rows = []
    for lens_name, cam in lenses().items():
        k = cam.intrinsics
        pix = pixel_grid(k.width, k.height)[::step, ::step] + np.array([0.25, 0.5])
        pix = np.minimum(pix, [k.width - 1, k.height - 1])
        # reference: the tightest of 1e-8, 1e-5, 1e-3 px the solver reaches in double precision
        # (next to a fold the Jacobian is nearly singular and 1e-8 is out of reach)
        refs = [undistort_robust(pix, cam, tol_px=t, max_iterations=100) for t in (1e-8, 1e-5, 1e-3)]
        ref_xy = refs[2].xy
        for r in refs[1::-1]:
            ref_xy = np.where(r.valid[..., None], r.xy, ref_xy)
        f = max(cam.intrinsics.fx, cam.intrinsics.fy)
        reference_ok = refs[2].valid
        for name, fn in variants(cam).items():
            seconds, out = _median_time(lambda: fn(pix), repeats)
            if isinstance(out, Unprojection):
                xy, valid = out.xy, out.valid
            else:  # OpenCV and the table return points without a validity flag
                xy = np.asarray(out)
                valid = np.all(np.isfinite(xy), axis=-1)
            err = ray_angle_px(xy, ref_xy, f)
            both = valid & reference_ok
            wrong = valid & (~reference_ok | ~(err <= WRONG_PX))
            rows.append({
                "lens": lens_name,
                "variant": name,
                "ms_per_grid": seconds * 1e3,
                "max_err_px": float(np.nanmax(err[both])) if both.any() else float("nan"),
                "rms_err_px": float(np.sqrt(np.nanmean(err[both] ** 2))) if both.any() else float("nan"),
                "flagged_pct": float(100 * (1 - valid.mean())),
                "wrong_valid": int(wrong.sum()),
                "no_preimage_pct": float(100 * (1 - reference_ok.mean())),
            })
    base = {r["lens"]: r["ms_per_grid"] for r in rows if r["variant"] == "fixed-5 (thesis)"}
    for r in rows:
        r["time_vs_fixed5"] = r["ms_per_grid"] / base[r["lens"]]
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--step", type=int, default=1, help="use every STEP-th pixel (default 1: the full 1664x928 grid)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per variant; the median is shown")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")


def run(args: argparse.Namespace) -> int:
    if args.step < 1 or args.repeats < 1:
        raise SystemExit("laserpi bench model: --step and --repeats must be >= 1")
    rows = run_benchmark(args.step, args.repeats)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"backward projection of a 1664x928 grid (every {args.step}. pixel); machine: {platform.machine()}, "
          f"one core, median of {args.repeats}; error = ray angle x f against a precise reference")
    print(f"{'lens':<18} {'variant':<17} {'ms/grid':>8} {'x fixed5':>8} {'max px':>10} {'rms px':>10} {'flagged%':>8} {'wrong':>6}")
    for r in rows:
        print(f"{r['lens']:<18} {r['variant']:<17} {r['ms_per_grid']:8.1f} {r['time_vs_fixed5']:8.2f} "
              f"{r['max_err_px']:10.2e} {r['rms_err_px']:10.2e} {r['flagged_pct']:8.2f} {r['wrong_valid']:6d}")
    return 0
