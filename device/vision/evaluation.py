"""Scoring pipeline output against the simulator's ground truth, and simulated frame pairs.

Used by ``laserpi evaluate``, ``laserpi bench pipeline`` and the accuracy tests, so that all
three measure the same thing the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..camera.frame import Frame
from ..config import SensorConfig
from ..sim.truth import FrameTruth
from .measurements import ColumnMeasurements

#: Distance bins (scan range, metres) of the range-error report.
DISTANCE_BINS = (0.0, 0.5, 1.0, 1.5, 2.5, 3.5, 5.0, 10.0)
#: A valid range further than this from the truth (relative) counts as a gross error.
GROSS_ERROR_REL = 0.05


def depth_jump(truth: FrameTruth, columns: np.ndarray) -> np.ndarray:
    """Which image ``columns``' light crossed a depth jump during the exposure: the ranges of the
    surfaces it fell on (``truth.range_span_m``, a moving sensor or object) more than
    GROSS_ERROR_REL apart. Such a column has no one true range or row: its ``range_m`` and
    ``row``, the light-weighted means, lie between the surfaces, where nothing is."""
    if truth.range_span_m is None:
        return np.zeros(np.shape(columns), bool)
    near, far = truth.range_span_m[columns].T
    with np.errstate(invalid="ignore"):
        return far > near * (1 + GROSS_ERROR_REL)


def reference_range(measured_m: np.ndarray, truth: FrameTruth, columns: np.ndarray) -> np.ndarray:
    """The true range a range ``measured_m`` at image ``columns`` is judged against: the truth's
    ``range_m``; in a depth-jump column (:func:`depth_jump`) the range of whichever of its two
    surfaces (the nearest and the farthest) is nearer to the measurement: a device that measured
    either surface measured a true range, and one that measured between them a phantom however
    near the mean. +inf where the truth has no return."""
    t = truth.range_m[columns]
    jump = depth_jump(truth, columns)
    if not jump.any():
        return t
    near, far = truth.range_span_m[columns].T
    with np.errstate(invalid="ignore", divide="ignore"):
        nearer = np.abs(measured_m - near) / near <= np.abs(measured_m - far) / far
    return np.where(jump, np.where(nearer, near, far), t)


def range_error_rel(measured_m: np.ndarray, truth: FrameTruth, columns: np.ndarray) -> np.ndarray:
    """Relative range error of ``measured_m`` at image ``columns`` against :func:`reference_range`
    (NaN where the truth has no return)."""
    return _relative_to(measured_m, reference_range(measured_m, truth, columns))


def _relative_to(measured_m: np.ndarray, ref: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return (measured_m - ref) / ref


def nearest_true_range(truth: FrameTruth, columns: np.ndarray) -> np.ndarray:
    """The nearest true range of image ``columns``: the truth's, or in a depth-jump column its
    nearer surface's (something that near was there during the exposure); +inf where none."""
    t = truth.range_m[columns]
    if truth.range_span_m is None:
        return t
    return np.where(depth_jump(truth, columns), truth.range_span_m[columns, 0], t)


@dataclass(frozen=True)
class FramePair:
    """Simulated frames (device.camera.frame.Frame: their timestamps and line time, which the
    fast pipeline's turn needs for the rolling shutter) and the lit frame's truth."""

    lit: Frame
    unlit: Frame
    truth: FrameTruth  # of the lit frame
    lit_rows: np.ndarray  # (H,) rows the pulse lit in the lit frame
    unlit_before: Frame | None = None  # the unlit frame before the lit one (``neighbours=True``)


#: Operating point of the simulated camera: the simulator's defaults (device/sim/render.py,
#: "Anchoring"): 40 ms exposure (the 17.4 ms pulse fits in the 22.5 ms during which all rows
#: expose) and analogue gain 10 (device.sim.sensor.SIMULATOR_DEFAULT).
EXPOSURE_US = 40000.0


def simulated_pairs(config: SensorConfig, scene_spec, count: int, seed: int = 0, options=None,
                    exposure_us: float = EXPOSURE_US, analog_gain: float | None = None,
                    pulse_us: float | None = None, isp: str = "linear", neighbours: bool = False) -> list[FramePair]:
    """``count`` (lit, unlit) pairs of a simulated scene: the camera free-runs, the laser fires
    on every other frame (docs/thesis-notes.md N10), centred on the frame's common exposure window
    (:func:`device.sim.pulses.frame_aligned_train`). Speckle is static (same scene), sensor
    noise differs per frame. ``scene_spec``: a name or spec for get_scene, or a Scene. ``isp``: the
    camera's luminance transfer (device/sim/sensor.py ``SensorParams.isp``). ``neighbours``: the
    camera starts with an unlit frame, so that every lit frame also has the unlit frame before it
    (``FramePair.unlit_before``; the device's pipeline takes both, issue 16)."""
    from ..sim.camera import SimulatedCamera
    from ..sim.pulses import frame_aligned_train
    from ..sim.render import RenderOptions
    from ..sim.scene import get_scene
    from ..sim.sensor import SIMULATOR_DEFAULT, SensorParams

    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    frame_us = 50000.0
    start_ns = 1_000_000_000
    cam_line_ns = config.window.mode.line_time_ns
    pulse = config.laser.pulse_s * 1e6 if pulse_us is None else pulse_us
    first_lit_ns = start_ns + int(round(frame_us * 1e3)) if neighbours else start_ns
    train = frame_aligned_train(first_lit_ns, frame_us, exposure_us, cam_line_ns, config.height, pulse, every=2)
    scene = get_scene(scene_spec) if isinstance(scene_spec, str) else scene_spec
    cam = SimulatedCamera(config, scene, train, exposure_us=exposure_us, frame_duration_us=frame_us,
                          start_ns=start_ns, seed=seed, options=options or RenderOptions(), line_time_ns=cam_line_ns,
                          sensor=replace(SIMULATOR_DEFAULT if analog_gain is None else SensorParams(analog_gain=analog_gain),
                                         isp=isp))
    cam.start()
    pairs = []
    before = cam.capture_with_truth()[0] if neighbours else None
    for _ in range(count):
        lit, truth = cam.capture_with_truth()
        unlit, _ = cam.capture_with_truth()
        pairs.append(FramePair(lit, unlit, truth, truth.lit_rows, before))
        before = unlit if neighbours else None
    return pairs


@dataclass
class Score:
    """Accumulated comparison of measurements with truth over frames."""

    row_err: list = field(default_factory=list)
    range_rel_err: list = field(default_factory=list)
    true_range: list = field(default_factory=list)
    all_true_range: list = field(default_factory=list)  # every column with a return
    all_valid: list = field(default_factory=list)
    columns_with_return: int = 0
    valid_with_return: int = 0
    columns_without_return: int = 0
    false_returns: int = 0

    def add(self, meas: ColumnMeasurements, truth: FrameTruth) -> None:
        c = meas.column
        t_row = truth.row[c]
        t_rng = truth.range_m[c]
        has = np.isfinite(t_row) & np.isfinite(t_rng)
        ok = meas.valid & np.isfinite(meas.range)
        self.columns_with_return += int(has.sum())
        self.valid_with_return += int((has & ok).sum())
        self.columns_without_return += int((~has).sum())
        self.false_returns += int((~has & ok).sum())
        both = has & ok
        ref = reference_range(meas.range, truth, c)
        self.all_true_range.append(t_rng[has])
        self.all_valid.append(ok[has])
        # a depth-jump column has no one true row (depth_jump)
        one = both & ~depth_jump(truth, c)
        self.row_err.append(meas.row[one] - t_row[one])
        self.range_rel_err.append(_relative_to(meas.range, ref)[both])
        self.true_range.append(ref[both])

    def valid_fraction_within(self, max_range_m: float) -> float:
        """Valid share of the columns whose true range is at most ``max_range_m``."""
        rng = np.concatenate(self.all_true_range) if self.all_true_range else np.zeros(0)
        ok = np.concatenate(self.all_valid) if self.all_valid else np.zeros(0, bool)
        m = rng <= max_range_m
        return float(ok[m].mean()) if m.any() else float("nan")

    def range_error_near(self, range_m: float, half_width_m: float = 0.25) -> tuple[float, float]:
        """(mean, std) of the relative range error (%) of columns whose true range is within
        +-half_width_m of ``range_m``."""
        rel = np.concatenate(self.range_rel_err) if self.range_rel_err else np.zeros(0)
        rng = np.concatenate(self.true_range) if self.true_range else np.zeros(0)
        m = np.abs(rng - range_m) <= half_width_m
        if m.sum() < 2:
            return float("nan"), float("nan")
        return float(np.mean(rel[m]) * 100), float(np.std(rel[m]) * 100)

    def summary(self) -> dict:
        row = np.concatenate(self.row_err) if self.row_err else np.zeros(0)
        rel = np.concatenate(self.range_rel_err) if self.range_rel_err else np.zeros(0)
        rng = np.concatenate(self.true_range) if self.true_range else np.zeros(0)
        all_rng = np.concatenate(self.all_true_range) if self.all_true_range else np.zeros(0)
        all_ok = np.concatenate(self.all_valid) if self.all_valid else np.zeros(0, bool)
        out = {
            "subpixel_rms_px": _rms(row),
            "subpixel_bias_px": float(np.mean(row)) if row.size else float("nan"),
            "valid_fraction": self.valid_with_return / self.columns_with_return if self.columns_with_return else float("nan"),
            "false_return_fraction": self.false_returns / self.columns_without_return if self.columns_without_return else 0.0,
            "columns_with_return": self.columns_with_return,
            "columns_without_return": self.columns_without_return,
            "gross_error_fraction": float(np.mean(np.abs(rel) > GROSS_ERROR_REL)) if rel.size else float("nan"),
            "range_error_by_distance": [],
        }
        for lo, hi in zip(DISTANCE_BINS[:-1], DISTANCE_BINS[1:]):
            m = (rng >= lo) & (rng < hi)
            n_truth = int(((all_rng >= lo) & (all_rng < hi)).sum())
            if n_truth == 0:
                continue
            e = rel[m] * 100
            out["range_error_by_distance"].append({
                "bin_m": [lo, hi], "columns": n_truth, "n": int(m.sum()),
                "valid_fraction": float(all_ok[(all_rng >= lo) & (all_rng < hi)].mean()),
                "mean_pct": float(np.mean(e)) if e.size else float("nan"),
                "std_pct": float(np.std(e)) if e.size > 1 else float("nan"),
                "p95_abs_pct": float(np.percentile(np.abs(e), 95)) if e.size else float("nan"),
            })
        return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def run_pipeline(pipeline, pairs: list[FramePair], use_lit_rows: bool = True) -> Score:
    """Process every pair in order (the reference's blend carries over, as on the device)."""
    score = Score()
    if hasattr(pipeline, "reset"):
        pipeline.reset()
    for p in pairs:
        rows = p.lit_rows if use_lit_rows else None
        if p.unlit_before is None:
            meas = pipeline.process(p.lit, p.unlit, lit_rows=rows)
        else:
            meas = pipeline.process(p.lit, p.unlit, lit_rows=rows, other_unlit=p.unlit_before)
        score.add(meas, p.truth)
    return score
