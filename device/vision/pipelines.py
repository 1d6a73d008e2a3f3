"""The pipeline variants by name, so evaluate, bench and the device process build them alike."""

from __future__ import annotations

from ..config import SensorConfig
from .fast import FastParams, FastPipeline
from .peaks import ESTIMATORS
from .reference import ReferencePipeline

#: Every variant: the thesis baseline, and the fast pipeline with each estimator (line fit over
#: neighbouring columns), plus the centre of mass without the fit to show what the fit buys, and
#: with a tracked region of interest (``-track``: rows near the previous frame's line, see
#: :class:`device.vision.fast.FastParams`), and that with the range gate (``-gated``: the
#: device's pipeline, DEVICE_VARIANT).
VARIANTS = ("reference",) + tuple(f"fast-{e}" for e in ESTIMATORS) + ("fast-com-raw", "fast-com-track",
                                                                      "fast-com-track-gated")
#: The variant the device runs (device/service/assembly.py builds it with the operating point's
#: depth limits, and hands it both unlit neighbours of each lit frame).
DEVICE_VARIANT = "fast-com-track-gated"

#: Rows searched each side of the previous frame's line by the ``-track`` variants.
TRACK_MARGIN_ROWS = 24
#: The ``-gated`` variants' bound on a range's predicted relative 1 sigma (FastParams.max_range_sigma).
#: A gross error is one > 5 % off (device.vision.evaluation.GROSS_ERROR_REL); a range whose
#: predicted 1 sigma is 1.5 % is that far off only beyond 3.3 sigma. Measured (BENCHMARKS.md
#: "Motion"): the still scenes' gross errors 0.28 % -> 0.04 % and no false returns, at the price
#: of the far, dim columns (a 90 % wall at 3 m keeps 83 % of its columns instead of 99 %).
RANGE_GATE_SIGMA = 0.015
#: A variant's name suffix -> the FastParams field it sets and the value; the last suffix first
#: (``fast-com-track-gated``).
_SUFFIXES = {"-gated": ("max_range_sigma", RANGE_GATE_SIGMA), "-track": ("track_margin", TRACK_MARGIN_ROWS),
             "-raw": ("smooth_half", 0)}


def make_pipeline(name: str, config: SensorConfig, min_m: float | None = None, max_m: float | None = None):
    """Build variant ``name`` for ``config``; ``min_m``/``max_m`` narrow the fast pipeline's depth
    limits (and so its region of interest) below the configuration's ``[range]``."""
    if name == "reference":
        return ReferencePipeline(config)
    if name.startswith("fast-"):
        est, changes = name[len("fast-"):], {}
        for suffix, (field, value) in _SUFFIXES.items():  # in the order they are stripped
            if est.endswith(suffix):
                est, changes[field] = est[: -len(suffix)], value
        if est in ESTIMATORS:
            return FastPipeline(config, FastParams(estimator=est, **changes), min_m, max_m)
    raise ValueError(f"unknown pipeline {name!r}; choose from {', '.join(VARIANTS)}")
