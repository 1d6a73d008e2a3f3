"""Simulated calibration: render a capture set from a known configuration, calibrate it, and
compare the estimate with the truth (fx/fy, plane normal and offset, range error on a wall)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..config import SensorConfig
from ..model.camera import project_points, undistort_robust
from ..model.scan_frame import scan_frame, to_scan_plane
from ..model.triangulation import RangeStatus, intersect_plane
from ..sim.checkerboard import BoardSpec, Scene, generate_poses, render_shot
from .pipeline import Pose


def scaled_config(cfg: SensorConfig, scale: float) -> SensorConfig:
    """The same sensor imaged at ``scale`` x the resolution (binning): focal lengths and image size
    scale, pixel centres map as c' = (c + 0.5) s - 0.5. For fast tests at reduced cost."""
    if scale == 1.0:
        return cfg
    k = cfg.camera.intrinsics
    w, h = int(round(cfg.width * scale)), int(round(cfg.height * scale))
    k2 = replace(k, fx=k.fx * scale, fy=k.fy * scale, cx=(k.cx + 0.5) * scale - 0.5, cy=(k.cy + 0.5) * scale - 0.5, width=w, height=h)
    aw = int(round(cfg.active_width * scale)) if cfg.active_width else None
    ah = int(round(cfg.active_height * scale)) if cfg.active_height else None
    return replace(cfg, width=w, height=h, camera=replace(cfg.camera, intrinsics=k2), active_width=aw, active_height=ah)


def simulate_capture(truth: SensorConfig, count: int, seed: int, spec: BoardSpec = BoardSpec(), scene: Scene = Scene(), motion_blur_px: float = 0.0, poses=None):
    """``count`` rendered poses (lit and unlit) of the board, deterministic by ``seed``.
    Returns (capture set, the rendered shots with their ground truth)."""
    cam, w, h = truth.camera, truth.width, truth.height
    if poses is None:
        poses = generate_poses(cam, w, h, truth.plane, count, seed, spec)
    rng = np.random.default_rng(seed + 1)
    shots = [render_shot(cam, w, h, truth.plane, p, rng, spec, scene, motion_blur_px) for p in poses]
    return [Pose(f"pose_{i:03d}", s.lit, s.unlit) for i, s in enumerate(shots)], shots


def wall_range_error(truth: SensorConfig, estimate: SensorConfig, distance_m: float = 2.0, samples: int = 2001) -> dict[str, float]:
    """Range error of ``estimate`` on a wall ``distance_m`` ahead (perpendicular to the true scan
    frame's forward axis): true laser points on the wall are imaged with the true camera, then
    triangulated with the estimated camera and plane; ranges compared in each one's scan frame.
    Returns the RMS and the worst relative error (percent) over the columns that see the wall,
    and the error at the principal-point column (where the thesis states its 1 % at 2 m
    requirement, section 4.1.5 and docs/thesis-notes.md N5)."""
    fr = scan_frame(truth.plane)
    y = np.linspace(-4 * distance_m, 4 * distance_m, samples)
    scan_pts = np.stack([np.full_like(y, distance_m), y, np.zeros_like(y)], axis=-1)
    cam_pts = scan_pts @ fr.rotation + fr.origin
    px = project_points(cam_pts, truth.camera)
    inside = np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) & (px[:, 0] <= truth.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= truth.height - 1)
    # the true model must itself map these pixels back (inside its invertible region)
    back = undistort_robust(px[inside], truth.camera)
    px = px[inside][back.valid]
    true_range = to_scan_plane(cam_pts[inside][back.valid], fr)[1]
    if len(px) < 2:
        raise ValueError(f"a wall at {distance_m} m is not visible to the true sensor")
    un = undistort_robust(px, estimate.camera)
    tri = intersect_plane(un.xy, estimate.plane)
    est_range = to_scan_plane(tri.points, scan_frame(estimate.plane))[1]
    ok = un.valid & (tri.status == RangeStatus.OK)
    if not ok.all():
        return {"max_pct": float("nan"), "rms_pct": float("nan"), "centre_pct": float("nan"), "columns": int(len(px))}
    rel = 100 * (est_range - true_range) / true_range
    centre = int(np.argmin(np.abs(px[:, 0] - truth.camera.intrinsics.cx)))
    return {"max_pct": float(np.max(np.abs(rel))), "rms_pct": float(np.sqrt(np.mean(rel**2))),
            "centre_pct": float(abs(rel[centre])), "columns": int(len(px))}


def compare(truth: SensorConfig, estimate: SensorConfig) -> dict[str, float]:
    """True-vs-estimated figures of ``laserpi calibrate --simulate``."""
    kt, ke = truth.camera.intrinsics, estimate.camera.intrinsics
    nt, ne = np.asarray(truth.plane.normal), np.asarray(estimate.plane.normal)
    wall = wall_range_error(truth, estimate)
    return {
        "fx_err_pct": 100 * (ke.fx - kt.fx) / kt.fx,
        "fy_err_pct": 100 * (ke.fy - kt.fy) / kt.fy,
        "cx_err_px": ke.cx - kt.cx,
        "cy_err_px": ke.cy - kt.cy,
        "plane_normal_err_deg": math.degrees(math.acos(min(1.0, abs(float(nt @ ne))))),
        "plane_offset_err_mm": 1000 * (estimate.plane.distance - truth.plane.distance),
        # headline: RMS over the whole scan; the worst column (frame corners, where the lens model
        # is extrapolated beyond the board corners) and the principal-point column beside it
        "range_err_pct_at_2m": wall["rms_pct"],
        "range_err_max_pct_at_2m": wall["max_pct"],
        "range_err_centre_pct_at_2m": wall["centre_pct"],
    }


def simulated_wall_sweep(
    truth: SensorConfig, estimate: SensorConfig, distances_m: np.ndarray, seed: int, row_noise_px: float = 0.1, samples: int = 400
):
    """A wall sweep as the post-calibration of section 6.3 records it: for each distance, a wall
    perpendicular to the true scan direction; its laser points are imaged by the true camera,
    the line rows get ``row_noise_px`` Gaussian noise, and the estimated configuration
    triangulates them. Returns (x_m, z_measured_m, z_true_m, wall index) of the valid points."""
    rng = np.random.default_rng(seed)
    fr = scan_frame(truth.plane)
    out = []
    for w, dist in enumerate(distances_m):
        y = np.linspace(-4 * dist, 4 * dist, samples)
        cam_pts = np.stack([np.full_like(y, dist), y, np.zeros_like(y)], axis=-1) @ fr.rotation + fr.origin
        px = project_points(cam_pts, truth.camera)
        inside = np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) & (px[:, 0] <= truth.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= truth.height - 1)
        px, cam_pts = px[inside], cam_pts[inside]
        px = px + np.stack([np.zeros(len(px)), rng.normal(0.0, row_noise_px, len(px))], axis=-1)
        un = undistort_robust(px, estimate.camera)
        tri = intersect_plane(un.xy, estimate.plane)
        ok = un.valid & (tri.status == RangeStatus.OK)
        out.append(np.stack([tri.points[ok, 0], tri.points[ok, 2], cam_pts[ok, 2], np.full(ok.sum(), w)], axis=-1))
    data = np.concatenate(out) if out else np.empty((0, 4))
    return data[:, 0], data[:, 1], data[:, 2], data[:, 3].astype(int)
