"""The pipeline variants by name, so evaluate, bench and the device process build them alike."""

from __future__ import annotations

from ..config import SensorConfig
from .fast import FastParams, FastPipeline
from .peaks import ESTIMATORS
from .reference import ReferencePipeline

#: Every variant: the thesis baseline, and the fast pipeline with each estimator (line fit over
#: neighbouring columns), plus the centre of mass without the fit to show what the fit buys.
VARIANTS = ("reference",) + tuple(f"fast-{e}" for e in ESTIMATORS) + ("fast-com-raw",)


def make_pipeline(name: str, config: SensorConfig, min_m: float | None = None, max_m: float | None = None):
    """Build variant ``name`` for ``config``; ``min_m``/``max_m`` narrow the fast pipeline's depth
    limits (and so its region of interest) below the configuration's ``[range]``."""
    if name == "reference":
        return ReferencePipeline(config)
    if name.startswith("fast-"):
        est = name[len("fast-"):]
        raw = est.endswith("-raw")
        est = est[: -len("-raw")] if raw else est
        if est in ESTIMATORS:
            params = FastParams(estimator=est, smooth_half=0 if raw else FastParams.smooth_half)
            return FastPipeline(config, params, min_m, max_m)
    raise ValueError(f"unknown pipeline {name!r}; choose from {', '.join(VARIANTS)}")
