"""Camera projection and distortion, both ways (thesis section 3.1, appendix A.4).

The lens models are the rows of one table, :data:`LENS_MODELS` (as mrcal's one table of lens
models): per model its name (the configuration file's ``[camera] model``, the calibration
report's), its coefficients (a dataclass; its fields are the names in the configuration file's
order), OpenCV's order of the same coefficients, and its forward and backward projection
functions, with OpenCV's counterparts of both. Every function here, the configuration file, the
calibration and the benchmarks look a model up in that table; a model that is not in it is an
error everywhere (:func:`lens_model`, :func:`lens_model_named`), never taken for another one.

* ``brown-conrady`` (:class:`BrownConrady`) - pinhole + radial (k1, k2, k3) + tangential
  (p1, p2), eq. 3.1-3.4; the same as OpenCV's 5-coefficient model.
* ``kannala-brandt`` (:class:`KannalaBrandt`) - equidistant fisheye with an odd polynomial in the
  incidence angle, the same as OpenCV's ``cv2.fisheye``, for lenses past ~140 deg.

Conventions: the OpenCV camera frame (x right, y down, z forward); *normalised* coordinates are
``(x/z, y/z)``; *pixel* coordinates have (0, 0) at the centre of the top-left pixel. Arrays have
shape ``(..., 2)`` (or ``(..., 3)`` for 3-D points); leading dimensions are kept.

Backward projection (pixel -> normalised) has no closed form. Two solvers are offered:

* :func:`undistort_fixed` - the thesis's fixed-iteration Heikkila scheme (eq. 3.5-3.11); 5
  iterations as the Caltech toolbox and the thesis, 20 as OpenCV.
* :func:`undistort_robust` - damped Newton to a stated tolerance in pixels. It also rejects
  solutions past the *radial fold*, the radius where a strong wide-angle profile turns back
  (d r_d / d r <= 0): there the forward model is not invertible and any answer would be wrong.

Both return an :class:`Unprojection` with, per point, whether it is valid and its reprojection
residual in pixels, so a point where the fixed iteration silently diverged is flagged, never
returned as valid (the failure mode of OpenCV's and kornia's fixed-iteration undistortion).
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

#: Convergence tolerance of the robust solver and the validity threshold of every solver, pixels.
DEFAULT_TOL_PX = 1e-6


@dataclass(frozen=True)
class Intrinsics:
    """Camera matrix KK of eq. 3.2 (pixels) and the image size it applies to."""

    fx: float
    fy: float
    cx: float
    cy: float
    skew: float = 0.0
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"intrinsics: {name} must be a positive focal length in pixels, got {v}")
        for name in ("cx", "cy", "skew"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"intrinsics: {name} must be finite, got {getattr(self, name)}")
        if self.width < 0 or self.height < 0:
            raise ValueError(f"intrinsics: image size must be non-negative, got {self.width}x{self.height}")

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


class _Coefficients:
    """What every lens model's coefficient dataclass can do with its row of :data:`LENS_MODELS`."""

    def opencv_coefficients(self) -> np.ndarray:
        """The coefficients in the order OpenCV's functions take them (the row's ``opencv_order``)."""
        return np.array([getattr(self, n) for n in lens_model(self).opencv_order])


@dataclass(frozen=True)
class BrownConrady(_Coefficients):
    """Radial (k1, k2, k3) and tangential (p1, p2) distortion of eq. 3.4 (OpenCV's order)."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def radial_fold(self) -> float:
        """Smallest undistorted radius where d(r_d)/dr <= 0 (inf if the profile never turns back).

        r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6), so d r_d/dr = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6,
        a cubic in u = r^2 whose smallest positive root is the fold.
        """
        roots = np.roots([7 * self.k3, 5 * self.k2, 3 * self.k1, 1.0]) if any((self.k1, self.k2, self.k3)) else []
        u = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
        return float(np.sqrt(min(u))) if u else float("inf")


@dataclass(frozen=True)
class KannalaBrandt(_Coefficients):
    """Equidistant fisheye: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).

    theta is the angle of the ray to the optical axis; the distorted point is theta_d along the
    ray's azimuth (OpenCV ``cv2.fisheye``; thesis appendix A.4, eq. A.18).
    """

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0

    def theta_fold(self) -> float:
        """Smallest incidence angle where d(theta_d)/d(theta) <= 0 (inf if none)."""
        c = [9 * self.k4, 7 * self.k3, 5 * self.k2, 3 * self.k1, 1.0]
        roots = np.roots(c) if any((self.k1, self.k2, self.k3, self.k4)) else []
        u = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
        return float(np.sqrt(min(u))) if u else float("inf")


Distortion = Union[BrownConrady, KannalaBrandt]


@dataclass(frozen=True)
class CameraModel:
    intrinsics: Intrinsics
    distortion: Distortion = BrownConrady()


class UnprojectStatus(enum.IntEnum):
    """Why a backward projection is valid or not (per point)."""

    OK = 0
    NOT_CONVERGED = 1  # residual above tolerance after the iterations allowed
    BEYOND_FOLD = 2  # the solution lies past the radius where the lens profile turns back
    NOT_FINITE = 3  # input pixel was NaN/inf, or the iteration blew up
    BEYOND_90_DEG = 4  # fisheye ray at or past 90 deg: no normalised coordinate exists


@dataclass(frozen=True)
class Unprojection:
    """Result of backward projection.

    ``xy``: (..., 2) normalised coordinates, NaN where not valid; ``valid``: bool (...);
    ``residual_px``: (...) distance between the input pixel and the reprojected solution;
    ``error_px``: (...) estimated error of the solution (remaining Newton correction x focal
    length); a point is valid only if this is within the solver's tolerance;
    ``status``: (...) :class:`UnprojectStatus` codes; ``iterations``: iterations used.
    """

    xy: np.ndarray
    valid: np.ndarray
    residual_px: np.ndarray
    error_px: np.ndarray
    status: np.ndarray
    iterations: int


def _check_last_dim(a: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim < 1 or a.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


# ---------------------------------------------------------------- camera matrix (eq. 3.2, 3.5-3.6)
def to_pixels(xy_d: np.ndarray, k: Intrinsics) -> np.ndarray:
    """Distorted normalised coordinates -> pixels, eq. 3.2: x_p = fx x_d + s y_d + cx, y_p = fy y_d + cy."""
    xy_d = _check_last_dim(xy_d, 2, "xy_d").astype(np.float64, copy=False)
    x, y = xy_d[..., 0], xy_d[..., 1]
    return np.stack([k.fx * x + k.skew * y + k.cx, k.fy * y + k.cy], axis=-1)


def from_pixels(pixels: np.ndarray, k: Intrinsics) -> np.ndarray:
    """Pixels -> distorted normalised coordinates, eq. 3.5-3.6."""
    pixels = _check_last_dim(pixels, 2, "pixels").astype(np.float64, copy=False)
    y_d = (pixels[..., 1] - k.cy) / k.fy
    x_d = (pixels[..., 0] - k.cx - k.skew * y_d) / k.fx
    return np.stack([x_d, y_d], axis=-1)


# ---------------------------------------------------------------- the lens models' table
@dataclass(frozen=True)
class LensModel:
    """One row of :data:`LENS_MODELS`: everything the rest of the code knows about a lens model.

    The functions work on arrays of shape (..., 2) or (..., 3) as the public functions below do,
    ``dist`` being an instance of ``distortion``.
    """

    name: str  # in the configuration file ([camera] model) and the calibration report
    distortion: type  # the frozen dataclass of its coefficients, fields in the configuration file's order
    opencv_order: tuple[str, ...]  # the same coefficient names in the order OpenCV's functions take them
    distort: Callable  # forward: (xy, dist) -> distorted normalised coordinates
    project: Callable  # forward: (points (..., 3) in the camera frame, dist) -> distorted normalised, NaN where not imaged
    undistort_fixed: Callable  # backward, fixed iterations: (xy_d, dist, iterations) -> (xy, status)
    undistort_robust: Callable  # backward to a tolerance: (pixels, xy_d, cam, tol, tol_px, max_iterations) -> Unprojection
    beyond_fold: Callable  # (r, dist) -> bool: a normalised point at radius r lies past the fold
    newton_error: Callable  # (xy, xy_d, distort(xy), dist, f) -> the Newton correction xy still needs, x f (px)
    opencv_project: Callable  # OpenCV's forward: (points (N, 3), rvec, tvec, K, D) -> pixels (N, 2)
    opencv_undistort: Callable  # OpenCV's backward: (pixels (..., 2), K, D, criteria) -> normalised (..., 2)

    @property
    def coefficient_names(self) -> tuple[str, ...]:
        """The coefficient names in the configuration file's order (the dataclass's fields)."""
        return tuple(f.name for f in dataclasses.fields(self.distortion))

    def from_opencv(self, values) -> Distortion:
        """The coefficients from an array in OpenCV's order (``opencv_order``)."""
        return self.distortion(**{n: float(v) for n, v in zip(self.opencv_order, values)})


def lens_model(dist: Distortion) -> LensModel:
    """The row of :data:`LENS_MODELS` of a coefficient object; ValueError for a model not in it."""
    try:
        return _BY_TYPE[type(dist)]
    except KeyError:
        raise ValueError(f"unknown lens model {type(dist).__name__}: not in LENS_MODELS "
                         f"({', '.join(m.distortion.__name__ for m in LENS_MODELS.values())})") from None


def lens_model_named(name: str) -> LensModel:
    """The row of :data:`LENS_MODELS` called ``name``; ValueError naming the known ones otherwise."""
    try:
        return LENS_MODELS[name]
    except KeyError:
        raise ValueError(f"lens model must be one of {', '.join(map(repr, LENS_MODELS))}, got {name!r}") from None


# ---------------------------------------------------------------- Brown-Conrady (eq. 3.1-3.11)
def _bc_distort(xy: np.ndarray, d: BrownConrady) -> np.ndarray:
    """Eq. 3.4: radial and tangential distortion of undistorted normalised coordinates."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
    xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)
    yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _bc_project(points: np.ndarray, d: BrownConrady) -> np.ndarray:
    """Pinhole (eq. 3.1; NaN for z <= 0), then eq. 3.4."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = np.stack([x / z, y / z], axis=-1)
    xy = np.where((z > 0)[..., None], xy, np.nan)
    return _bc_distort(xy, d)


def _brown_jacobian(x: np.ndarray, y: np.ndarray, d: BrownConrady) -> tuple[np.ndarray, ...]:
    """d(x_d, y_d)/d(x, y) of eq. 3.4 as four arrays (j11, j12, j21, j22)."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
    dradial = d.k1 + r2 * (2 * d.k2 + 3 * d.k3 * r2)  # d radial / d(r^2)
    j11 = radial + 2 * x * x * dradial + 2 * d.p1 * y + 6 * d.p2 * x
    j12 = 2 * x * y * dradial + 2 * d.p1 * x + 2 * d.p2 * y
    j21 = 2 * x * y * dradial + 2 * d.p1 * x + 2 * d.p2 * y
    j22 = radial + 2 * y * y * dradial + 6 * d.p1 * y + 2 * d.p2 * x
    return j11, j12, j21, j22


def _bc_newton_error(xy, xy_d, dist_xy, d: BrownConrady, f: float) -> np.ndarray:
    """J^-1 times the residual in distorted coordinates, times f; inf where J is singular."""
    rx, ry = dist_xy[..., 0] - xy_d[..., 0], dist_xy[..., 1] - xy_d[..., 1]
    j11, j12, j21, j22 = _brown_jacobian(xy[..., 0], xy[..., 1], d)
    det = j11 * j22 - j12 * j21
    error = np.hypot(j22 * rx - j12 * ry, -j21 * rx + j11 * ry) / np.abs(det) * f
    return np.where(det > 0, error, np.inf)


def _bc_beyond_fold(r: np.ndarray, d: BrownConrady) -> np.ndarray:
    return r >= d.radial_fold()


def _bc_undistort_fixed(xy_d: np.ndarray, d: BrownConrady, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Heikkila's iteration, eq. 3.8-3.11, from p_n = p_d."""
    with np.errstate(all="ignore"):
        xd, yd = xy_d[..., 0], xy_d[..., 1]
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y  # step 1 (eq. 3.8)
            dr = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))  # step 2 (eq. 3.9)
            dtx = 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)  # step 3 (eq. 3.10)
            dty = d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
            x, y = (xd - dtx) / dr, (yd - dty) / dr  # step 4 (eq. 3.11)
        xy = np.stack([x, y], axis=-1)
    return xy, _fold_status(xy, d)


def _bc_undistort_robust(pixels, xy_d, cam: CameraModel, tol, tol_px, max_iterations) -> Unprojection:
    """Damped Newton with the 2x2 Jacobian of eq. 3.4 (see :func:`undistort_robust`)."""
    d = cam.distortion
    shape = xy_d.shape[:-1]
    xd, yd = xy_d[..., 0].ravel(), xy_d[..., 1].ravel()
    fold = d.radial_fold()
    with np.errstate(all="ignore"):
        # warm start: three Heikkila steps (eq. 3.11) get most points within a Newton step or two
        x, y = xd.copy(), yd.copy()
        for _ in range(3):
            r2 = x * x + y * y
            dr = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
            x, y = (xd - 2 * d.p1 * x * y - d.p2 * (r2 + 2 * x * x)) / dr, (yd - d.p1 * (r2 + 2 * y * y) - 2 * d.p2 * x * y) / dr
        r0 = np.hypot(x, y)
        cold = ~np.isfinite(r0) | (r0 >= 0.9 * fold)
        x, y = np.where(cold, xd, x), np.where(cold, yd, y)
        if np.isfinite(fold):
            # start inside the one-to-one region so Newton cannot wander onto the folded branch
            r0 = np.hypot(x, y)
            shrink = np.where(r0 > 0.9 * fold, 0.9 * fold / np.maximum(r0, 1e-300), 1.0)
            x, y = x * shrink, y * shrink
    with np.errstate(all="ignore"):
        ex, ey = _residual_xy(x, y, xd, yd, d)
        err = np.hypot(ex, ey)
        lam = np.ones_like(err)  # per-point step length: halved after a step that did not help
        active = np.nonzero(np.isfinite(err))[0]
        it = 0
        for it in range(1, max_iterations + 1):
            if active.size == 0:
                break
            xa, ya, la = x[active], y[active], lam[active]
            j11, j12, j21, j22 = _brown_jacobian(xa, ya, d)
            det = j11 * j22 - j12 * j21
            exa, eya = ex[active], ey[active]
            sx = (j22 * exa - j12 * eya) / det  # full Newton step = error estimate
            sy = (-j21 * exa + j11 * eya) / det
            small = np.hypot(sx, sy) <= tol
            la = np.where(small, 1.0, la)
            xn, yn = xa - la * sx, ya - la * sy
            if np.isfinite(fold):  # never step onto the folded branch: stop halfway to the fold
                rn, ra = np.hypot(xn, yn), np.hypot(xa, ya)
                over = rn >= fold
                pull = np.where(over, 0.5 * (ra + fold) / np.maximum(rn, 1e-300), 1.0)
                xn, yn = xn * pull, yn * pull
            rx, ry = _residual_xy(xn, yn, xd[active], yd[active], d)
            en = np.hypot(rx, ry)
            accept = en < err[active]
            x[active] = np.where(accept, xn, xa)
            y[active] = np.where(accept, yn, ya)
            ex[active] = np.where(accept, rx, exa)
            ey[active] = np.where(accept, ry, eya)
            err[active] = np.where(accept, en, err[active])
            lam[active] = np.where(accept, np.minimum(1.0, 2.0 * la), 0.5 * la)
            # a point is done after taking a step below tolerance, or when it can no longer move
            done = small | ~(lam[active] > 1e-6) | ~np.isfinite(err[active])
            x[active[small]], y[active[small]] = xn[small], yn[small]
            active = active[~done]
    xy = np.stack([x, y], axis=-1).reshape(*shape, 2)
    return _result(cam, pixels, xy, _fold_status(xy, d), tol_px, it)


def _residual_xy(x, y, xd, yd, d: BrownConrady):
    r2 = x * x + y * y
    radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3))
    ex = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x) - xd
    ey = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y - yd
    return ex, ey


def _bc_opencv_project(points, rvec, tvec, k, d) -> np.ndarray:
    import cv2

    return cv2.projectPoints(points.astype(np.float64), rvec, tvec, k, d)[0].reshape(-1, 2)


def _bc_opencv_undistort(pixels, k, d, criteria) -> np.ndarray:
    import cv2

    fn = getattr(cv2, "undistortPointsIter", None)  # OpenCV 4 name; OpenCV 5 takes criteria in undistortPoints
    if fn:
        return fn(pixels.reshape(-1, 1, 2), k, d, None, None, criteria=criteria).reshape(pixels.shape)
    return cv2.undistortPoints(pixels.reshape(-1, 1, 2), k, d, criteria=criteria).reshape(pixels.shape)


# ---------------------------------------------------------------- Kannala-Brandt (eq. A.18)
def _kb_theta_d(theta: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    t2 = theta * theta
    return theta * (1.0 + t2 * (d.k1 + t2 * (d.k2 + t2 * (d.k3 + t2 * d.k4))))


def _kb_slope(theta: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    """d(theta_d)/d(theta)."""
    t2 = theta * theta
    return 1.0 + t2 * (3 * d.k1 + t2 * (5 * d.k2 + t2 * (7 * d.k3 + t2 * 9 * d.k4)))


def _kb_scale(theta: np.ndarray, r: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    """theta_d / r, with its limit 1 at r -> 0."""
    with np.errstate(invalid="ignore", divide="ignore"):
        s = _kb_theta_d(theta, d) / r
    return np.where(r > 1e-12, s, 1.0)


def _kb_distort(xy: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    """A normalised point at incidence angle theta = atan(r) moved to radius theta_d."""
    x, y = xy[..., 0], xy[..., 1]
    r = np.sqrt(x * x + y * y)
    theta = np.arctan(r)
    return xy * _kb_scale(theta, r, d)[..., None]


def _kb_project(points: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    """Any direction up to the fold angle (incidence angle from atan2, so rays at or past 90 deg
    are imaged); NaN past the fold."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    r = np.hypot(x, y)
    theta = np.arctan2(r, z)
    theta_d = _kb_theta_d(theta, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(r > 1e-300, theta_d / r, 0.0)
    xy_d = np.stack([x * scale, y * scale], axis=-1)
    return np.where((theta < d.theta_fold())[..., None], xy_d, np.nan)


def _kb_newton_error(xy, xy_d, dist_xy, d: KannalaBrandt, f: float) -> np.ndarray:
    """The Newton correction d(theta) the solution still needs, times f; inf where the slope is not positive."""
    theta = np.arctan(np.hypot(xy[..., 0], xy[..., 1]))
    slope = _kb_slope(theta, d)
    error = np.abs(_kb_theta_d(theta, d) - np.hypot(xy_d[..., 0], xy_d[..., 1])) / slope * f
    return np.where(slope > 0, error, np.inf)


def _kb_beyond_fold(r: np.ndarray, d: KannalaBrandt) -> np.ndarray:
    return np.arctan(r) >= d.theta_fold()


def _fisheye_xy(xy_d: np.ndarray, theta_d: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Normalised point at incidence angle theta along the azimuth of xy_d."""
    with np.errstate(all="ignore"):
        scale = np.where(theta_d > 1e-15, np.tan(theta) / theta_d, 1.0)
        xy = xy_d * scale[..., None]
    return np.where((theta < np.pi / 2)[..., None], xy, np.nan)


def _kb_undistort_fixed(xy_d: np.ndarray, d: KannalaBrandt, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """The fixed-point idea of eq. 3.11 on the angle: theta = theta_d / (1 + k1 theta^2 + ...)."""
    with np.errstate(all="ignore"):
        theta_d = np.hypot(xy_d[..., 0], xy_d[..., 1])
        theta = theta_d.copy()
        for _ in range(iterations):
            t2 = theta * theta
            theta = theta_d / (1.0 + t2 * (d.k1 + t2 * (d.k2 + t2 * (d.k3 + t2 * d.k4))))
        xy = _fisheye_xy(xy_d, theta_d, theta)
    status = _fold_status(xy, d)
    status[(theta >= np.pi / 2) & (status == UnprojectStatus.OK)] = UnprojectStatus.BEYOND_90_DEG
    return xy, status


def _kb_undistort_robust(pixels, xy_d, cam: CameraModel, tol, tol_px, max_iterations) -> Unprojection:
    """1-D Newton on theta, kept inside the fold angle (see :func:`undistort_robust`)."""
    d: KannalaBrandt = cam.distortion
    theta_d = np.hypot(xy_d[..., 0], xy_d[..., 1])
    fold = min(d.theta_fold(), np.pi)
    theta = np.minimum(theta_d, 0.9 * fold)
    it = 0
    with np.errstate(all="ignore"):
        for it in range(1, max_iterations + 1):
            f = _kb_theta_d(theta, d) - theta_d
            df = _kb_slope(theta, d)
            step = np.where(df > 0, f / df, 0.0)
            theta_new = np.clip(theta - step, 0.0, fold)
            done = np.abs(theta_new - theta) < tol
            theta = theta_new
            if np.all(done | ~np.isfinite(theta)):
                break
    xy = _fisheye_xy(xy_d, theta_d, theta)
    status = _fold_status(np.where(np.isfinite(xy), xy, 0.0), d)
    status[theta >= fold] = UnprojectStatus.BEYOND_FOLD
    status[(theta >= np.pi / 2) & (status == UnprojectStatus.OK)] = UnprojectStatus.BEYOND_90_DEG
    status[~np.isfinite(theta_d)] = UnprojectStatus.NOT_FINITE
    return _result(cam, pixels, xy, status, tol_px, it)


def _kb_opencv_project(points, rvec, tvec, k, d) -> np.ndarray:
    import cv2

    return cv2.fisheye.projectPoints(points.reshape(1, -1, 3).astype(np.float64), np.asarray(rvec, float).reshape(3, 1),
                                     np.asarray(tvec, float).reshape(3, 1), k, d)[0].reshape(-1, 2)


def _kb_opencv_undistort(pixels, k, d, criteria) -> np.ndarray:
    import cv2

    return cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2), k, d, criteria=criteria).reshape(pixels.shape)


#: The lens models, by name. Adding one: its coefficient dataclass (add it to ``Distortion``),
#: its functions and one row here; tests/test_lens_models.py then checks it against OpenCV.
LENS_MODELS: dict[str, LensModel] = {m.name: m for m in (
    LensModel("brown-conrady", BrownConrady, ("k1", "k2", "p1", "p2", "k3"), _bc_distort, _bc_project,
              _bc_undistort_fixed, _bc_undistort_robust, _bc_beyond_fold, _bc_newton_error, _bc_opencv_project,
              _bc_opencv_undistort),
    LensModel("kannala-brandt", KannalaBrandt, ("k1", "k2", "k3", "k4"), _kb_distort, _kb_project,
              _kb_undistort_fixed, _kb_undistort_robust, _kb_beyond_fold, _kb_newton_error, _kb_opencv_project,
              _kb_opencv_undistort),
)}
_BY_TYPE = {m.distortion: m for m in LENS_MODELS.values()}


# ---------------------------------------------------------------- forward projection
def distort(xy: np.ndarray, dist: Distortion) -> np.ndarray:
    """Undistorted normalised -> distorted normalised coordinates (eq. 3.4, or the fisheye model)."""
    xy = _check_last_dim(xy, 2, "xy").astype(np.float64, copy=False)
    return lens_model(dist).distort(xy, dist)


def project_normalized(xy: np.ndarray, cam: CameraModel) -> np.ndarray:
    """Undistorted normalised coordinates (..., 2) -> pixels (..., 2) (eq. 3.2-3.4)."""
    return to_pixels(distort(xy, cam.distortion), cam.intrinsics)


def project_points(points: np.ndarray, cam: CameraModel) -> np.ndarray:
    """3-D points in the camera frame (..., 3) -> pixels (..., 2) (eq. 3.1-3.4).

    Points with z <= 0 give NaN for the pinhole model. The fisheye model projects any direction
    up to its fold angle (incidence angle from atan2, so rays at or past 90 deg are allowed).
    """
    points = _check_last_dim(points, 3, "points").astype(np.float64, copy=False)
    return to_pixels(lens_model(cam.distortion).project(points, cam.distortion), cam.intrinsics)


# ---------------------------------------------------------------- backward projection
def _result(cam: CameraModel, pixels: np.ndarray, xy: np.ndarray, status: np.ndarray, tol_px: float, iters: int) -> Unprojection:
    """Measure the solution and finish its status.

    ``residual_px`` is the reprojection residual. Validity is judged on ``error_px``, the Newton
    correction the solution still needs (J^-1 times the residual in distorted coordinates, or
    d(theta) for the fisheye) times the focal length: near the fold J is nearly singular, so a
    tiny reprojection residual can hide a large error in the ray, and only this measure sees it.
    """
    d = cam.distortion
    f = max(cam.intrinsics.fx, cam.intrinsics.fy)
    xy_d = from_pixels(pixels, cam.intrinsics)
    with np.errstate(all="ignore"):
        dist_xy = distort(xy, d)
        reproj = to_pixels(dist_xy, cam.intrinsics)
        residual = np.hypot(reproj[..., 0] - pixels[..., 0], reproj[..., 1] - pixels[..., 1])
        error = lens_model(d).newton_error(xy, xy_d, dist_xy, d, f)
    status = status.copy()
    status[~np.isfinite(residual) & (status == UnprojectStatus.OK)] = UnprojectStatus.NOT_FINITE
    status[(status == UnprojectStatus.OK) & ~(error <= tol_px)] = UnprojectStatus.NOT_CONVERGED
    valid = status == UnprojectStatus.OK
    residual = np.where(np.isfinite(residual), residual, np.inf)
    error = np.where(np.isfinite(error), error, np.inf)
    return Unprojection(np.where(valid[..., None], xy, np.nan), valid, residual, error, status, iters)


def _fold_status(xy: np.ndarray, dist: Distortion) -> np.ndarray:
    status = np.full(xy.shape[:-1], UnprojectStatus.OK, dtype=np.uint8)
    r = np.hypot(xy[..., 0], xy[..., 1])
    status[lens_model(dist).beyond_fold(r, dist)] = UnprojectStatus.BEYOND_FOLD
    status[~np.isfinite(r)] = UnprojectStatus.NOT_FINITE
    return status


def undistort_fixed(pixels: np.ndarray, cam: CameraModel, iterations: int = 5, tol_px: float = 0.01) -> Unprojection:
    """Heikkila's fixed-iteration backward projection, eq. 3.5-3.11 (thesis: 5 iterations).

    Runs exactly ``iterations`` steps of  p_n <- (p_d - d_t(p_n)) / d_r(p_n)  from p_n = p_d.
    For the fisheye model the same fixed-point idea is applied to theta = theta_d / (1 + ...).
    Unlike the thesis (and OpenCV/kornia; docs/thesis-notes.md N15), the result is checked: a point whose estimated error
    (see :class:`Unprojection`) exceeds ``tol_px`` is returned invalid, never as a wrong point.
    """
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    pixels = _check_last_dim(pixels, 2, "pixels").astype(np.float64, copy=False)
    xy_d = from_pixels(pixels, cam.intrinsics)
    xy, status = lens_model(cam.distortion).undistort_fixed(xy_d, cam.distortion, iterations)
    return _result(cam, pixels, xy, status, tol_px, iterations)


def undistort_robust(
    pixels: np.ndarray, cam: CameraModel, tol_px: float = DEFAULT_TOL_PX, max_iterations: int = 50
) -> Unprojection:
    """Backward projection to a stated tolerance, with per-point convergence and residual.

    Damped Newton on  distort(p_n) = p_d  (2x2 Jacobian of eq. 3.4; 1-D Newton on theta for the
    fisheye), warm-started by three Heikkila steps (or at p_d, pulled inside the fold, where
    those land outside it), with step halving whenever a step does not reduce the residual.
    A point stops iterating once its full Newton step, times the focal length, is below
    ``tol_px`` / 4: that step is the error estimate validity is judged on (:func:`_result`), and
    near a fold it is much larger than the reprojection residual. A solution is valid only if it
    converged *and* lies inside the radial fold, where the forward model is one-to-one.
    """
    if tol_px <= 0:
        raise ValueError(f"tol_px must be positive, got {tol_px}")
    pixels = _check_last_dim(pixels, 2, "pixels").astype(np.float64, copy=False)
    xy_d = from_pixels(pixels, cam.intrinsics)
    scale_px = max(cam.intrinsics.fx, cam.intrinsics.fy)
    tol = tol_px / scale_px / 4  # iterate a little past the pixel tolerance
    return lens_model(cam.distortion).undistort_robust(pixels, xy_d, cam, tol, tol_px, max_iterations)


def unproject(pixels: np.ndarray, cam: CameraModel, method: str = "robust", **kwargs) -> Unprojection:
    """Pixels (..., 2) -> normalised coordinates, by ``method`` "robust" or "fixed" (see above)."""
    if method == "robust":
        return undistort_robust(pixels, cam, **kwargs)
    if method == "fixed":
        return undistort_fixed(pixels, cam, **kwargs)
    raise ValueError(f"unknown backward-projection method {method!r}; use 'robust' or 'fixed'")


def pixel_grid(width: int, height: int, dtype=np.float64) -> np.ndarray:
    """All pixel centres of a width x height image as an (height, width, 2) array of (x, y)."""
    u, v = np.meshgrid(np.arange(width, dtype=dtype), np.arange(height, dtype=dtype))
    return np.stack([u, v], axis=-1)
