"""Camera and laser plane from one capture set, end to end (thesis section 4.2).

Capture-set folder layout (what ``laserpi calibrate run DIR`` and ``calibrate capture`` use)::

    DIR/pose_000_unlit.png   8-bit grayscale, laser off  (corners are found here, section 7.2.2)
    DIR/pose_000_lit.png     8-bit grayscale, laser on, same board pose
    DIR/pose_001_unlit.png
    ...

Any ``<name>_unlit.png`` with a matching ``<name>_lit.png`` is a pose; names sort the poses.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..config import SensorConfig
from ..model.triangulation import params_from_plane
from .intrinsics import CalibrationError, Detection, IntrinsicsResult, calibrate_intrinsics, detect_corners
from .metrics import wall_range_error
from .plane import BoardLine, PlaneFit, board_mask, extract_line, fit_laser_plane, line_points
from .target import BoardSpec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Pose:
    name: str
    lit: np.ndarray  # (H, W) uint8
    unlit: np.ndarray  # (H, W) uint8


@dataclass
class CalibrationResult:
    config: SensorConfig
    intrinsics: IntrinsicsResult
    plane_fit: PlaneFit
    detections: list[Detection]
    lines: list[BoardLine]
    base: SensorConfig  # the configuration calibration started from (Table 4.8's "original" column)


def load_capture_dir(path: str | Path) -> list[Pose]:
    """Read a capture-set folder (layout in the module docstring)."""
    import cv2

    path = Path(path)
    if not path.is_dir():
        raise CalibrationError(f"{path}: not a folder of pose_NNN_lit.png / pose_NNN_unlit.png pairs")
    poses = []
    for unlit_path in sorted(path.glob("*_unlit.png")):
        name = unlit_path.name[: -len("_unlit.png")]
        lit_path = path / f"{name}_lit.png"
        if not lit_path.exists():
            raise CalibrationError(f"{unlit_path} has no matching {lit_path.name}; every pose needs a lit and an unlit frame")
        lit, unlit = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in (lit_path, unlit_path))
        if lit is None or unlit is None:
            raise CalibrationError(f"{name}: cannot read the PNG pair in {path}")
        if lit.shape != unlit.shape:
            raise CalibrationError(f"{name}: lit {lit.shape} and unlit {unlit.shape} frames differ in size")
        poses.append(Pose(name, lit, unlit))
    if not poses:
        raise CalibrationError(f"{path}: no pose_NNN_unlit.png / pose_NNN_lit.png pairs found")
    return poses


def save_capture_dir(poses: list[Pose], path: str | Path) -> None:
    import cv2

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    for p in poses:
        cv2.imwrite(str(path / f"{p.name}_unlit.png"), p.unlit)
        cv2.imwrite(str(path / f"{p.name}_lit.png"), p.lit)


def calibrate(poses: list[Pose], base: SensorConfig, spec: BoardSpec = BoardSpec(), model: str = "auto", name: str | None = None) -> CalibrationResult:
    """Intrinsics from the unlit frames, then the laser plane from the lines on the boards.

    ``base`` supplies what calibration does not measure (laser, optics, range limits, beta).
    """
    if not poses:
        raise CalibrationError("empty capture set: capture 15-25 checkerboard poses, each lit and unlit")
    h, w = poses[0].unlit.shape
    if any(p.unlit.shape != (h, w) for p in poses):
        raise CalibrationError("the capture set mixes frame sizes; capture all poses in one sensor mode")
    detections = [detect_corners(p.unlit, spec.pattern_size, p.name) for p in poses]
    intr = calibrate_intrinsics(detections, spec.object_points(), (w, h), model=model)
    outline = spec.outline(0.8 * spec.margin_squares)  # the checker area and most of the white mount
    lines = []
    for p in poses:
        if p.name not in intr.poses:
            continue
        rot, t = intr.poses[p.name]
        px = extract_line(p.lit, p.unlit, board_mask(intr.camera, rot, t, outline, (h, w)))
        ln = line_points(p.name, px, intr.camera, rot, t)
        log.info("%s: %d laser points", p.name, len(ln.points))
        lines.append(ln)
    fit = fit_laser_plane(lines)
    cam = replace(intr.camera, intrinsics=replace(intr.camera.intrinsics, width=w, height=h))
    config = replace(base, name=name or f"{base.name}-calibrated", width=w, height=h, camera=cam, plane=fit.plane,
                     active_width=min(base.active_width or w, w), active_height=min(base.active_height or h, h), post_calibration=None)
    return CalibrationResult(config, intr, fit, detections, lines, base)


@dataclass(frozen=True)
class ViewBootstrap:
    """Spread of the whole calibration (intrinsics, board poses and plane) over resampled views."""

    samples: int
    fx_std_px: float
    fy_std_px: float
    normal_std_deg: float  # RMS angle of the resampled normals to the estimate
    offset_std_m: float
    range_std_pct_at_2m: float  # RMS over samples of the wall-at-2 m range RMS against the estimate


def bootstrap_views(result: CalibrationResult, spec: BoardSpec, samples: int = 30, seed: int = 0) -> ViewBootstrap:
    """Resample the views with replacement and redo intrinsics, board poses and plane fit.

    The bootstrap inside :func:`fit_laser_plane` resamples boards with the camera fixed, so it
    misses the error the intrinsics share across all boards; this one includes it.
    """
    from .intrinsics import refit

    used = [d for d in result.detections if d.corners is not None]
    lines = {ln.name: ln for ln in result.lines}
    size = (result.config.width, result.config.height)
    rng = np.random.default_rng(seed)
    base_n = np.asarray(result.config.plane.normal)
    fx, fy, ang, off, rng_err = [], [], [], [], []
    for _ in range(samples):
        pick = rng.integers(0, len(used), len(used))
        try:
            cam, poses = refit([used[i].corners for i in pick], spec.object_points(), size, result.config.camera, result.intrinsics.kept)
            first = {}
            for i, pose in zip(pick, poses):
                first.setdefault(used[i].name, pose)
            b_lines = [line_points(n, lines[n].pixels, cam, *first[n]) for n in first if n in lines and len(lines[n].pixels)]
            fit = fit_laser_plane(b_lines, rng_seed=int(rng.integers(1 << 30)), ransac_iterations=100, bootstrap=0)
        except (CalibrationError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("bootstrap sample skipped: %s", exc)
            continue
        k = cam.intrinsics
        fx.append(k.fx)
        fy.append(k.fy)
        n = np.asarray(fit.plane.normal)
        ang.append(math.degrees(math.acos(min(1.0, abs(float(n @ base_n))))))
        off.append(fit.plane.distance)
        sample_cfg = replace(result.config, camera=replace(cam, intrinsics=replace(k, width=size[0], height=size[1])), plane=fit.plane)
        rng_err.append(wall_range_error(result.config, sample_cfg)["rms_pct"])
    if len(fx) < 2:
        raise CalibrationError("the view bootstrap failed on every sample; capture more views")
    return ViewBootstrap(len(fx), float(np.std(fx)), float(np.std(fy)), float(np.sqrt(np.mean(np.square(ang)))),
                         float(np.std(off)), float(np.sqrt(np.nanmean(np.square(rng_err)))))


def triangulation_table(result: CalibrationResult) -> dict[str, float]:
    """Thesis Table 4.8 for the calibrated plane: theta, psi, alpha (degrees) and s (metres)."""
    return plane_table(result.config.plane, result.config.beta_rad)


def plane_table(plane, beta_rad: float) -> dict[str, float]:
    """(a_c, b_c, c_c) and the triangulation parameters of section 3.2.2 / D.2.2 for a plane."""
    a, b, c = plane.to_abc()
    p = params_from_plane(a, b, c, beta_rad)
    return {"a_c": a, "b_c": b, "c_c_m": c, "theta_deg": math.degrees(p.theta), "psi_deg": math.degrees(p.psi),
            "alpha_deg": math.degrees(p.alpha), "beta_deg": math.degrees(p.beta), "s_m": p.s}
