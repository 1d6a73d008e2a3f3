"""Camera intrinsics from checkerboard views (thesis sections 4.1.2 and 4.2.1).

Corners are found with OpenCV's sector-based detector (``findChessboardCornersSB``) and refined
with ``cornerSubPix``, always on the *unlit* frame so that the bright laser line cannot pull a
corner (section 7.2.2). A view that cannot be used (board not found, blurred, partly out of
view) is dropped with a reason, never a crash.

The distortion model is chosen by evidence - the thesis's rule of section 4.1.2 ("ignore a
parameter when its uncertainty is larger than its value"), made automatic: a coefficient whose
standard deviation (``calibrateCameraExtended``) is not smaller than its value is dropped unless
dropping it raises the held-out reprojection error (k-fold over views, each held-out view's pose
re-solved with the candidate intrinsics). With ``model="auto"`` the fisheye model
(``cv2.fisheye``, Kannala-Brandt) is fitted too and chosen when it predicts held-out corners
clearly better (by FISHEYE_MARGIN): a fisheye lens leaves Brown-Conrady with residuals that look
small on the corners it saw but that do not generalise.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..model.camera import CameraModel, Intrinsics, lens_model, lens_model_named

log = logging.getLogger(__name__)

#: 10 %-90 % edge width (pixels, ``estimateChessboardSharpness``) above which a view is blurred.
MAX_EDGE_WIDTH_PX = 4.0
#: Views needed for a calibration (each adds 6 constraints and 6 unknowns; 4 is a floor, aim for 15+).
MIN_VIEWS = 4
#: Relative standard deviation of fx/fy above which the focal length is called undetermined.
MAX_FOCAL_REL_STD = 0.01
#: The fisheye model is chosen when its held-out error is below this fraction of Brown-Conrady's.
FISHEYE_MARGIN = 0.8

#: A weak coefficient is kept only if dropping it raises the held-out error by more than this (relative).
HELDOUT_TOLERANCE = 0.005

#: The Brown-Conrady coefficients model selection keeps or drops (p1 and p2 together).
BC_NAMES = ("k1", "k2", "p1p2", "k3")
#: The fisheye fit estimates all of its coefficients.
KB_NAMES = lens_model_named("kannala-brandt").coefficient_names


class CalibrationError(ValueError):
    """A capture set that cannot be calibrated; the message says what to capture next."""


@dataclass(frozen=True)
class Detection:
    """Corners of one view, or the reason the view was dropped."""

    name: str
    corners: np.ndarray | None  # (N, 2) pixels, OpenCV order of BoardSpec.object_points
    reason: str | None = None
    edge_width_px: float = float("nan")


@dataclass
class IntrinsicsResult:
    camera: CameraModel
    rms_px: float
    per_view_rms_px: dict[str, float]
    poses: dict[str, tuple[np.ndarray, np.ndarray]]  # view -> (R (3,3), t (3,)), board -> camera
    std: dict[str, float]  # one-sigma of each estimated parameter
    kept: tuple[str, ...]  # distortion coefficients estimated (others fixed at 0)
    heldout_rms_px: float
    selection: list[dict] = field(default_factory=list)  # the model-selection steps, for the report


def _gray(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"expected a (H, W) uint8 image, got {image.shape} {image.dtype}")
    return image


def _edge_width_estimate(image: np.ndarray) -> float:
    """Rough 10-90 % edge width (pixels) of the strongest edges, for a view where no board was
    found: a Gaussian-blurred step of contrast C has peak gradient C / (sigma sqrt(2 pi)) and
    10-90 % width 2.56 sigma, so width ~ 1.02 C / max gradient."""
    import cv2

    img = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.7)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    g = np.hypot(gx, gy)
    lo, hi = np.percentile(img, [0.1, 99.9])
    gmax = float(np.percentile(g, 99.95))
    return float(1.02 * (hi - lo) / gmax) if gmax > 0 else float("inf")


def _border_edges(image: np.ndarray) -> list[str]:
    """Image sides where strong edges (checker edges) run into the border."""
    import cv2

    img = image.astype(np.float32)
    g = np.hypot(cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)) / 8.0
    lo, hi = np.percentile(img, [0.1, 99.9])
    noise = 1.4826 * float(np.median(g))  # most pixels are flat: their gradient is noise
    strong = g > max(0.25 * (hi - lo), 8.0 * noise, 1.0)
    band = 3
    sides = {"top": strong[1:band + 1, 1:-1], "bottom": strong[-band - 1:-1, 1:-1], "left": strong[1:-1, 1:band + 1], "right": strong[1:-1, -band - 1:-1]}
    return [s for s, m in sides.items() if m.sum() >= 6]


def detect_corners(image: np.ndarray, pattern_size: tuple[int, int], name: str = "", max_edge_width_px: float = MAX_EDGE_WIDTH_PX) -> Detection:
    """Inner corners of a checkerboard in an (unlit) uint8 frame, or the reason it has none."""
    import cv2

    image = _gray(image)
    found, corners = cv2.findChessboardCornersSB(image, pattern_size, flags=0)
    if not found:  # small squares (a far board): the accuracy mode works on an upsampled image
        found, corners = cv2.findChessboardCornersSB(image, pattern_size, flags=cv2.CALIB_CB_ACCURACY)
    if not found:
        width = _edge_width_estimate(image)
        if width > max_edge_width_px:
            return Detection(name, None, f"blurred: edges about {width:.1f} px wide (> {max_edge_width_px} px); hold the board still and check focus", width)
        sides = _border_edges(image)
        if sides:
            return Detection(
                name, None,
                f"board partly out of view (checker edges run into the {'/'.join(sides)} border); keep the whole board and its white margin in the frame",
                width,
            )
        return Detection(name, None, f"no {pattern_size[0]}x{pattern_size[1]}-corner checkerboard found (too far, too oblique, or poorly lit)", width)
    corners = corners.reshape(-1, 2).astype(np.float32)
    # window: a quarter of the smallest square so that it never reaches the next corner
    grid = corners.reshape(pattern_size[1], pattern_size[0], 2)
    square_px = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(), np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
    half = int(np.clip(square_px / 4, 2, 10))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    corners = cv2.cornerSubPix(image, corners.reshape(-1, 1, 2), (half, half), (-1, -1), crit).reshape(-1, 2)
    width = float(cv2.estimateChessboardSharpness(image, pattern_size, corners.reshape(-1, 1, 2))[0][0])
    if not width < 1000:  # OpenCV reports 9999 when its edge profiles fail (small squares): measure the board's box
        x0, y0 = np.floor(corners.min(0)).astype(int)
        x1, y1 = np.ceil(corners.max(0)).astype(int) + 1
        width = _edge_width_estimate(image[max(y0, 0):y1, max(x0, 0):x1])
    if width > max_edge_width_px:
        return Detection(name, None, f"blurred: checker edges {width:.1f} px wide (> {max_edge_width_px} px); hold the board still and check focus", width)
    return Detection(name, corners.astype(np.float64), None, width)


# ---------------------------------------------------------------- calibration
def _bc_flags(kept: tuple[str, ...]) -> int:
    import cv2

    flags = 0
    if "k1" not in kept:
        flags |= cv2.CALIB_FIX_K1
    if "k2" not in kept:
        flags |= cv2.CALIB_FIX_K2
    if "k3" not in kept:
        flags |= cv2.CALIB_FIX_K3
    if "p1p2" not in kept:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    return flags


def _fit(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], model: str, kept: tuple[str, ...], k0: np.ndarray | None = None):
    """One OpenCV calibration with lens model ``model`` -> (rms, K, D, rvecs, tvecs, std dict, per-view rms)."""
    return _calibration(model).fit(obj, img, size, kept, k0)


def _criteria():
    import cv2

    return (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _fit_brown_conrady(obj, img, size, kept, k0):
    """``cv2.calibrateCameraExtended`` with the coefficients not in ``kept`` fixed at 0 (starts
    from OpenCV's own guess, not ``k0``)."""
    import cv2

    crit = _criteria()
    o32, i32 = [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img]
    # Staged start: OpenCV's LM from its zero-distortion start can stop in a local minimum on
    # a wide-angle lens (seen in simulation: 0.45 px RMS where the truth gives 0.07 px); a
    # k1-only fit first, then the full model from there, reaches it. The better of the two wins.
    stage1 = cv2.calibrateCamera(o32, i32, size, None, None, flags=cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST, criteria=crit)
    d0 = np.zeros(5)
    if "k1" in kept:
        d0[0] = stage1[2].ravel()[0]
    best = None
    for k_init, d_init, extra in ((None, None, 0), (stage1[1], d0, cv2.CALIB_USE_INTRINSIC_GUESS)):
        out = cv2.calibrateCameraExtended(o32, i32, size, k_init, d_init, flags=_bc_flags(kept) | extra, criteria=crit)
        if best is None or out[0] < best[0]:
            best = out
    rms, k, d, rv, tv, std_i, _, per_view = best
    s = std_i.ravel()
    std = {"fx": s[0], "fy": s[1], "cx": s[2], "cy": s[3], "k1": s[4], "k2": s[5], "p1": s[6], "p2": s[7], "k3": s[8]}
    return rms, k, d.ravel()[:5], rv, tv, std, per_view.ravel()


def _fit_fisheye(obj, img, size, kept, k0):
    """``cv2.fisheye.calibrate`` of all four coefficients, from ``k0`` (a Brown-Conrady K; fitted
    here when not given): OpenCV 5's ``fisheye.calibrate`` fails its extrinsic initialisation
    from its own default guess on wide-angle views, and wants points as (1, N, 3) / (1, N, 2)
    float32."""
    import cv2

    if k0 is None:
        k0 = _fit(obj, img, size, "brown-conrady", BC_NAMES)[1]
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS
    rms, k, d, rv, tv = cv2.fisheye.calibrate(
        [o.reshape(1, -1, 3).astype(np.float32) for o in obj], [i.reshape(1, -1, 2).astype(np.float32) for i in img], size,
        np.array(k0, dtype=np.float64), np.zeros((4, 1)), flags=flags, criteria=_criteria(),
    )
    per_view = np.array([_view_rms(o, i, k, d, r, t, "kannala-brandt") for o, i, r, t in zip(obj, img, rv, tv)])
    return rms, k, d.ravel()[:4], rv, tv, {}, per_view


def _pose_brown_conrady(obj, img, k, d):
    import cv2

    return cv2.solvePnP(obj, img, k, d)


def _pose_fisheye(obj, img, k, d):
    """solvePnP has no fisheye model: on the corners undistorted to normalised coordinates."""
    import cv2

    undist = cv2.fisheye.undistortPoints(img.reshape(-1, 1, 2).astype(np.float64), k, d).reshape(-1, 2)
    return cv2.solvePnP(obj.astype(np.float64), undist, np.eye(3), None)


@dataclass(frozen=True)
class _OpenCvCalibration:
    """How OpenCV calibrates one lens model of device.model.camera.LENS_MODELS."""

    fit: Callable  # (obj, img, size, kept, k0) -> (rms, K, D in OpenCV's order, rvecs, tvecs, std dict, per-view rms)
    pose: Callable  # (obj, img, K, D) -> (ok, rvec, tvec): a held-out view's pose with fitted intrinsics


_CALIBRATIONS = {
    "brown-conrady": _OpenCvCalibration(_fit_brown_conrady, _pose_brown_conrady),
    "kannala-brandt": _OpenCvCalibration(_fit_fisheye, _pose_fisheye),
}


def _calibration(model: str) -> _OpenCvCalibration:
    try:
        return _CALIBRATIONS[model]
    except KeyError:
        raise ValueError(f"no OpenCV calibration for lens model {model!r}; calibrated: {', '.join(_CALIBRATIONS)}") from None


def _view_rms(obj, img, k, d, rvec, tvec, model) -> float:
    proj = lens_model_named(model).opencv_project(obj, rvec, tvec, k, d)
    return float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))


def _heldout_rms(obj, img, size, model, kept, folds: int = 5, k0=None) -> float:
    """k-fold over views: calibrate on the rest, re-solve each held-out pose, RMS of its corners."""
    n = len(obj)
    folds = min(folds, n)
    sq = []
    for f in range(folds):
        test = [i for i in range(n) if i % folds == f]
        train = [i for i in range(n) if i % folds != f]
        if len(train) < MIN_VIEWS - 1:
            continue
        _, k, d, *_ = _fit([obj[i] for i in train], [img[i] for i in train], size, model, kept, k0)
        for i in test:
            ok, rv, tv = _calibration(model).pose(obj[i], img[i], k, d)
            if ok:
                sq.append(_view_rms(obj[i], img[i], k, d, rv, tv, model) ** 2)
    return float(np.sqrt(np.mean(sq))) if sq else float("inf")


def calibrate_intrinsics(
    detections: list[Detection], object_points: np.ndarray, image_size: tuple[int, int], model: str = "auto"
) -> IntrinsicsResult:
    """Calibrate from the usable views; ``model`` "brown-conrady", "kannala-brandt" or "auto".

    Raises :class:`CalibrationError` when too few views are usable (listing why each was
    dropped) or when the focal length is not determined by the views (poses too similar).
    """
    used = [d for d in detections if d.corners is not None]
    dropped = [d for d in detections if d.corners is None]
    for d in dropped:
        log.warning("view %s dropped: %s", d.name, d.reason)
    if len(used) < MIN_VIEWS:
        why = "; ".join(f"{d.name}: {d.reason}" for d in dropped[:8])
        raise CalibrationError(
            f"too few corners: {len(used)} of {len(detections)} views have a complete checkerboard "
            f"({len(used) * len(object_points)} corners); need at least {MIN_VIEWS} views, 15-25 recommended. "
            f"Capture more poses with the whole board in view, still and in focus." + (f" Dropped: {why}" if why else "")
        )
    obj = [object_points.astype(np.float64)] * len(used)
    img = [d.corners for d in used]
    if model not in ("auto", "brown-conrady", "kannala-brandt"):
        raise ValueError(f"model must be 'auto', 'brown-conrady' or 'kannala-brandt', got {model!r}")

    selection: list[dict] = []
    if model in ("auto", "brown-conrady"):
        result = _select_brown_conrady(obj, img, image_size, selection)
        if model == "auto":
            fe = _fisheye_candidate(obj, img, image_size, selection, result[1])
            if fe is not None and fe[-1] < FISHEYE_MARGIN * result[-1]:
                result = fe
    else:
        result = _fisheye_candidate(obj, img, image_size, selection)
        if result is None:
            raise CalibrationError("the fisheye calibration did not converge; capture more views filling the frame corners")
    rms, k, d, rv, tv, std, per_view, kept, chosen_model, heldout = result

    intr = Intrinsics(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]), cy=float(k[1, 2]), width=image_size[0], height=image_size[1])
    if std:
        for key in ("fx", "fy"):
            rel = std[key] / getattr(intr, key)
            if rel > MAX_FOCAL_REL_STD:
                raise CalibrationError(
                    f"focal length not determined: {key} = {getattr(intr, key):.1f} +- {std[key]:.1f} px ({100 * rel:.1f} %); "
                    "the views are too alike - tilt the board +-30 deg about both axes and vary its distance"
                )
    dist = lens_model_named(chosen_model).from_opencv(d)
    import cv2

    poses = {u.name: (cv2.Rodrigues(np.asarray(r, float))[0], np.asarray(t, float).ravel()) for u, r, t in zip(used, rv, tv)}
    return IntrinsicsResult(
        CameraModel(intr, dist), float(rms), {u.name: float(e) for u, e in zip(used, per_view)}, poses,
        {k_: float(v) for k_, v in std.items()}, kept, heldout, selection,
    )


def _select_brown_conrady(obj, img, size, selection):
    """Backward elimination of insignificant coefficients (thesis 4.1.2), checked on held-out views."""
    kept = BC_NAMES
    fit = _fit(obj, img, size, "brown-conrady", kept)
    heldout = None
    while True:
        rms, k, d, rv, tv, std, per_view = fit
        values = {"k1": abs(d[0]), "k2": abs(d[1]), "p1p2": max(abs(d[2]), abs(d[3])), "k3": abs(d[4])}
        sigmas = {"k1": std["k1"], "k2": std["k2"], "p1p2": min(std["p1"], std["p2"]), "k3": std["k3"]}
        step = {"kept": list(kept), "rms_px": float(rms), "values": [float(x) for x in d], "std": {n: float(std[n]) for n in std}}
        weak = sorted((values[n] / max(sigmas[n], 1e-300), n) for n in kept if values[n] <= sigmas[n])
        if not weak:
            selection.append(step)
            break
        if heldout is None:
            heldout = _heldout_rms(obj, img, size, "brown-conrady", kept)
        name = weak[0][1]
        trial = tuple(n for n in kept if n != name)
        trial_heldout = _heldout_rms(obj, img, size, "brown-conrady", trial)
        step.update({"candidate": name, "heldout_with_px": heldout, "heldout_without_px": trial_heldout})
        selection.append(step)
        if trial_heldout > heldout * (1.0 + HELDOUT_TOLERANCE):
            log.info("keeping %s: |value| <= sigma but dropping it raises held-out error %.4f -> %.4f px", name, heldout, trial_heldout)
            break
        kept, heldout = trial, trial_heldout
        fit = _fit(obj, img, size, "brown-conrady", kept)
    if heldout is None:
        heldout = _heldout_rms(obj, img, size, "brown-conrady", kept)
    rms, k, d, rv, tv, std, per_view = fit
    return rms, k, d, rv, tv, std, per_view, kept, "brown-conrady", heldout


def _fisheye_candidate(obj, img, size, selection, k0=None):
    import cv2

    if k0 is None:
        k0 = _fit(obj, img, size, "brown-conrady", BC_NAMES)[1]
    try:
        rms, k, d, rv, tv, std, per_view = _fit(obj, img, size, "kannala-brandt", KB_NAMES, k0)
        heldout = _heldout_rms(obj, img, size, "kannala-brandt", KB_NAMES, k0=k0)
    except cv2.error as exc:
        log.info("fisheye model could not be fitted (Brown-Conrady kept): %s", exc)
        return None
    selection.append({"model": "kannala-brandt", "rms_px": float(rms), "heldout_px": heldout, "values": [float(x) for x in d]})
    return rms, k, d, rv, tv, std, per_view, KB_NAMES, "kannala-brandt", heldout


def refit(corners: list[np.ndarray], object_points: np.ndarray, image_size: tuple[int, int], camera: CameraModel, kept: tuple[str, ...]):
    """Calibrate again with the model already chosen (for resampling): -> (CameraModel, [(R, t)])."""
    import cv2

    lens = lens_model(camera.distortion)
    _, k, d, rv, tv, _, _ = _fit([object_points.astype(np.float64)] * len(corners), corners, image_size, lens.name, kept, camera.intrinsics.matrix)
    w, h = image_size
    intr = Intrinsics(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]), cy=float(k[1, 2]), width=w, height=h)
    return CameraModel(intr, lens.from_opencv(d)), [(cv2.Rodrigues(np.asarray(r, float))[0], np.asarray(t, float).ravel()) for r, t in zip(rv, tv)]
