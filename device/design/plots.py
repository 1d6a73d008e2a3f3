"""PNG plots of a design report (matplotlib, Agg backend, imported only when plotting).

alpha sweep (thesis Fig. 4.2), per-column range limits, resolution against distance (Fig. 4.3)
and laser return against background (Fig. 4.4).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from device.design import limits
from device.design.report import DesignReport
from device.model import irradiance


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_plots(rep: DesignReport, cfg, out_dir: str | Path) -> list[Path]:
    """Write the report's PNGs into ``out_dir`` (created if needed); returns the paths."""
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []

    def save(fig, name: str) -> None:
        path = out / name
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)

    if rep.sweep is not None:
        sw = rep.sweep
        order = np.argsort(sw.columns)
        fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.5))
        mesh = ax0.pcolormesh(np.degrees(sw.alphas), sw.columns[order], sw.q_high[:, order].T, shading="nearest")
        fig.colorbar(mesh, ax=ax0, label="max q / s with resolution < 1 %")
        ax0.set(xlabel="camera tilt alpha (deg)", ylabel="image column (px)", title="max q per column (s = 1)")
        ax1.plot(np.degrees(sw.alphas), sw.usable, label="whole field of view")
        ax1.plot(np.degrees(sw.alphas[~sw.feasible]), sw.usable[~sw.feasible], "x", color="grey", label="theta <= 0 (no plane)")
        if math.isfinite(sw.best_alpha):
            ax1.axvline(math.degrees(sw.best_alpha), color="r", ls="--", label=f"best {math.degrees(sw.best_alpha):.2f} deg")
        ax1.set(xlabel="camera tilt alpha (deg)", ylabel="q / s", title="range reached by every column")
        ax1.legend()
        fig.tight_layout()
        save(fig, "alpha_sweep.png")

    if rep.columns is not None:
        col = rep.columns
        fig, ax = plt.subplots(figsize=(8, 4.5))
        ax.plot(col.columns, col.q_min, label="min(q)")
        q_max = np.where(np.isinf(col.q_max), np.nan, col.q_max)
        ax.plot(col.columns, q_max, label="max(q) (gap: horizon in view, unbounded)")
        ax.set(yscale="log", xlabel="image column (px)", ylabel="distance q (m)", title=f"range limits per column: {rep.name}")
        ax.legend()
        fig.tight_layout()
        save(fig, "column_limits.png")

    geom = rep.geometry
    rows = np.arange(geom.rows, dtype=float)
    pixels = np.stack([np.full(rows.size, geom.principal_column), rows], axis=-1)
    q = limits.range_at_pixels(geom, pixels)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for s in rep.subpixels:
        ax.plot(q, 100 * limits.resolution_at_pixels(geom, pixels, float(s)), label=f"{s:g} px")
    for r in rep.ranges_m:
        ax.axvline(r, color="grey", lw=0.5)
    ax.set(xscale="log", yscale="log", xlabel="distance q (m)", ylabel="resolution (% of q)",
           title="resolution on the principal column")
    ax.legend(title="sub-pixel accuracy")
    fig.tight_layout()
    save(fig, "resolution.png")

    x = np.linspace(0.1, 5.0, 200)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for scale, label in ((1.0, "outdoor"), (irradiance.INDOOR_FRACTION, "indoor")):
        ratio = irradiance.return_to_background(x, cfg.laser.power_w, scale * rep.background_w_m2,
                                                cfg.laser.fan_angle_rad, cfg.laser.line_height_m)
        ax.plot(x, 100 * ratio, label=label)
    ax.axhline(1.0, color="grey", ls="--", label="1 %")
    ax.set(yscale="log", xlabel="distance (m)", ylabel="laser return / background (%)",
           title=f"{cfg.laser.power_w * 1e3:g} mW line laser against AM1.5 background")
    ax.legend()
    fig.tight_layout()
    save(fig, "background.png")
    return paths
