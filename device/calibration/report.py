"""Calibration report: a JSON summary and PNG plots (reprojection error per view, laser-plane
residuals, board coverage, post-calibration correction curve)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..model.camera import lens_model
from .pipeline import CalibrationResult, plane_table, triangulation_table


def report_dict(result: CalibrationResult) -> dict:
    intr, fit = result.intrinsics, result.plane_fit
    k, d = result.config.camera.intrinsics, result.config.camera.distortion
    return {
        "camera": {
            "model": lens_model(d).name,
            "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            "distortion": [float(v) for v in (d.opencv_coefficients())],
            "kept_coefficients": list(intr.kept),
            "std": intr.std,
            "rms_px": intr.rms_px,
            "heldout_rms_px": intr.heldout_rms_px,
            "model_selection": intr.selection,
        },
        "views": {
            det.name: {"used": det.corners is not None, "reason": det.reason, "edge_width_px": det.edge_width_px,
                       "reprojection_rms_px": intr.per_view_rms_px.get(det.name)}
            for det in result.detections
        },
        "laser_plane": {
            "normal": list(fit.plane.normal), "distance_m": fit.plane.distance,
            "rms_residual_mm": 1000 * fit.rms_m,
            "normal_std_deg": fit.normal_std_deg, "offset_std_mm": 1000 * fit.offset_std_m,
            "points": int(len(fit.inliers)), "inliers": int(fit.inliers.sum()),
            "spread_ratio_s2_s1": fit.spread_ratio,
            "per_board_rms_mm": {n: 1000 * v for n, v in fit.per_board_rms_m.items()},
        },
        "triangulation": {  # thesis Table 4.8: the starting configuration against the calibrated one
            "original": plane_table(result.base.plane, result.base.beta_rad),
            "calibrated": triangulation_table(result),
        },
    }


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def json_safe(o):
    """NaN/inf are not JSON: write them as null."""
    if isinstance(o, dict):
        return {k: json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def write_report(result: CalibrationResult, folder: str | Path, extra: dict | None = None, postcal_curve=None) -> Path:
    """report.json plus PNG plots in ``folder``; returns the JSON path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    doc = report_dict(result)
    if extra:
        doc.update(extra)
    path = folder / "report.json"
    path.write_text(json.dumps(json_safe(json.loads(json.dumps(doc, default=_json_default))), indent=2))
    _plots(result, folder, postcal_curve)
    return path


def _plots(result: CalibrationResult, folder: Path, postcal_curve) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    intr, fit = result.intrinsics, result.plane_fit
    names = [d.name for d in result.detections]
    errs = [intr.per_view_rms_px.get(n, np.nan) for n in names]
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.bar(range(len(names)), np.nan_to_num(errs), color=["C0" if np.isfinite(e) else "C3" for e in errs])
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=6)
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title(f"per-view reprojection error (red: dropped); overall {intr.rms_px:.3f} px")
    fig.tight_layout()
    fig.savefig(folder / "reprojection.png", dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3))
    ax.hist(1000 * fit.residuals_m[fit.inliers], bins=60)
    ax.set_xlabel("point-to-plane residual (mm)")
    ax.set_title(f"laser plane residuals, RMS {1000 * fit.rms_m:.3f} mm")
    fig.tight_layout()
    fig.savefig(folder / "plane_residuals.png", dpi=100)
    plt.close(fig)

    k = result.config
    fig, ax = plt.subplots(figsize=(6, 6 * k.height / k.width))
    for det in result.detections:
        if det.corners is not None:
            ax.plot(det.corners[:, 0], det.corners[:, 1], ".", ms=2)
    for ln in result.lines:
        if len(ln.pixels):
            ax.plot(ln.pixels[:, 0], ln.pixels[:, 1], "r-", lw=0.8)
    ax.set_xlim(0, k.width)
    ax.set_ylim(k.height, 0)
    ax.set_title("board coverage (corners) and laser lines (red)")
    fig.tight_layout()
    fig.savefig(folder / "coverage.png", dpi=100)
    plt.close(fig)

    if postcal_curve is not None:
        z, before, after = postcal_curve
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot(z, 1000 * before, ".", ms=2, label="error before")
        ax.plot(z, 1000 * after, ".", ms=2, label="after correction")
        ax.set_xlabel("z measured (m)")
        ax.set_ylabel("error (mm)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(folder / "correction.png", dpi=100)
        plt.close(fig)
