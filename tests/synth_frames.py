"""Small synthetic frame pairs for pipeline tests: Gaussian lines at rows computed from the
calibration for given depths, speckle-like multiplicative noise, additive noise. Not a renderer:
no scene, no optics; only enough to know the true row and point of every column."""

from __future__ import annotations

import functools

import numpy as np

from device.model.camera import undistort_robust
from device.model.triangulation import intersect_plane


@functools.lru_cache(maxsize=4)
def _inverse_depth(config) -> np.ndarray:
    """1/depth of every pixel of the upper 60 % of the image (where the tests put lines)."""
    rows = np.arange(int(0.6 * config.height), dtype=np.float64)
    u, v = np.meshgrid(np.arange(config.width, dtype=np.float64), rows)
    return 1.0 / intersect_plane(undistort_robust(np.stack([u, v], -1), config.camera).xy, config.plane).depth


def row_for_depth(config, depth: np.ndarray) -> np.ndarray:
    """(W,) sub-pixel row where the laser at camera depth ``depth[u]`` appears in column u."""
    W = config.width
    inv = _inverse_depth(config)
    rows = np.arange(inv.shape[0], dtype=np.float64)
    out = np.full(W, np.nan)
    for c in range(W):
        if not np.isfinite(depth[c]):
            continue
        col = inv[:, c]
        ok = np.isfinite(col)
        # 1/z grows with the row below the horizon (OpenCV frame, camera above the plane)
        out[c] = np.interp(1.0 / depth[c], col[ok], rows[ok], left=np.nan, right=np.nan)
    return out


def true_points(config, rows: np.ndarray) -> np.ndarray:
    px = np.stack([np.arange(rows.size, dtype=np.float64), np.nan_to_num(rows)], -1)
    pts = intersect_plane(undistort_robust(px, config.camera).xy, config.plane).points
    return np.where(np.isfinite(rows)[:, None], pts, np.nan)


def frame_pair(config, rows, amplitude=120.0, sigma=1.4, speckle=0.0, noise=1.0, background=40.0,
               seed=0, extra_lines=()):
    """(lit, unlit) uint8 frames with a line at ``rows`` (NaN: none) plus ``extra_lines`` given as
    (rows, amplitude) pairs (ghosts)."""
    rng = np.random.default_rng(seed)
    H, W = config.height, config.width
    r = np.arange(H, dtype=np.float64)[:, None]
    signal = np.zeros((H, W))
    for rr, amp in ((np.asarray(rows), amplitude),) + tuple(extra_lines):
        rr = np.asarray(rr, dtype=np.float64)
        ok = np.isfinite(rr)
        prof = np.exp(-((r - np.where(ok, rr, -1e3)) ** 2) / (2 * sigma**2))
        signal += np.where(ok, np.broadcast_to(amp, (W,)), 0.0)[None, :] * prof
    if speckle > 0:
        k = 1.0 / speckle**2
        signal = signal * rng.gamma(k, 1.0 / k, signal.shape)
    bg = np.full((H, W), float(background))
    lit = bg + signal + rng.normal(0, noise, (H, W))
    unlit = bg + rng.normal(0, noise, (H, W))
    q = lambda a: np.clip(np.rint(a), 0, 255).astype(np.uint8)
    return q(lit), q(unlit)
