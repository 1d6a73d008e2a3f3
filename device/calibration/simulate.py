"""Simulated calibration: render a capture set from a known configuration (and a wall sweep for
the post-calibration) to calibrate; metrics.py compares the estimate with the truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import SensorConfig
from ..model.camera import project_points, undistort_robust
from ..model.scan_frame import scan_frame
from ..model.triangulation import RangeStatus, intersect_plane
from ..sim.checkerboard import Scene, generate_poses, render_shot
from .pipeline import Pose
from .target import BoardSpec


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
