"""Line-laser triangulation: the ideal model, the laser-plane model and conversions between them
(thesis section 3.2, appendix D).

The laser plane is kept in Hessian normal form ``n . X = d`` (unit normal n pointing away from the
camera side, d > 0 the distance from the optical centre to the plane, metres) in the OpenCV
camera frame (docs/thesis-notes.md N4). The thesis writes it as ``z = a_c x + b_c y + c_c`` (eq. 3.16); that
form cannot represent a plane parallel to the optical axis (b_c -> inf), which is exactly one
of the hard cases, so it is only used at the edges (config files, the `plane` command; docs/thesis-notes.md N16).

Ray/plane intersection (eq. 3.17 / D.67):  for a normalised pixel p = (x_n, y_n, 1),
``X = t p`` with ``t = d / (n . p)``; with n = (-a, -b, 1)/N and d = c/N this is exactly
``z = c_c / (1 - (a_c x_n + b_c y_n))``. ``n . p <= 0`` means the ray never meets the plane in
front of the camera: the pixel is at or beyond the plane's horizon.
"""

from __future__ import annotations

import enum
import math
import warnings
from dataclasses import dataclass

import numpy as np

#: Denominator (n . p) below which a ray counts as at the horizon: about 1e-9 rad of ray angle.
HORIZON_EPS = 1e-9
#: Angle between the optical axis and the plane below which the geometry is called ill-conditioned.
WARN_AXIS_ANGLE_RAD = math.radians(5.0)
#: Smallest distance from the optical centre to the plane that is not degenerate (metres).
MIN_BASELINE_M = 1e-4


class PlaneConditioningWarning(UserWarning):
    """The laser plane is nearly parallel or perpendicular to the optical axis (thesis 7.2.1)."""


class DegeneratePlaneError(ValueError):
    """A laser plane that cannot be used for triangulation, with the reason in the message."""


@dataclass(frozen=True)
class LaserPlane:
    """Laser plane ``normal . X = distance`` in the camera frame; normal is a unit 3-vector."""

    normal: tuple[float, float, float]
    distance: float  # metres, > 0

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float)
        if n.shape != (3,) or not np.all(np.isfinite(n)):
            raise DegeneratePlaneError(f"laser plane normal must be 3 finite numbers, got {self.normal}")
        if abs(np.linalg.norm(n) - 1.0) > 1e-9:
            raise DegeneratePlaneError(f"laser plane normal must be a unit vector, |n| = {np.linalg.norm(n)}")
        if not math.isfinite(self.distance) or self.distance < MIN_BASELINE_M:
            raise DegeneratePlaneError(
                f"laser plane passes {self.distance} m from the optical centre; a plane through the "
                f"centre (< {MIN_BASELINE_M} m) has no baseline and gives no depth"
            )

    @staticmethod
    def from_abc(a: float, b: float, c: float) -> "LaserPlane":
        """From the thesis form z = a x + b y + c (eq. 3.16), c in metres."""
        vals = np.array([a, b, c], dtype=float)
        if not np.all(np.isfinite(vals)):
            raise DegeneratePlaneError(f"plane coefficients must be finite, got a={a}, b={b}, c={c}")
        if c <= 0:
            raise DegeneratePlaneError(
                f"plane offset c = {c} m must be positive: the laser plane must cross the optical axis "
                "in front of the camera"
            )
        n = np.array([-a, -b, 1.0])
        norm = np.linalg.norm(n)
        return LaserPlane(tuple((n / norm).tolist()), float(c / norm))

    def to_abc(self) -> tuple[float, float, float]:
        """(a, b, c) of z = a x + b y + c; raises when the plane is parallel to the optical axis."""
        nx, ny, nz = self.normal
        if abs(nz) < 1e-12:
            raise DegeneratePlaneError(
                "the plane is parallel to the optical axis: b_c is infinite in the form z = a x + b y + c"
            )
        return float(-nx / nz), float(-ny / nz), float(self.distance / nz)

    def axis_angle(self) -> float:
        """Angle between the optical axis (+z) and the plane, radians in [0, pi/2].

        0: the plane contains the axis direction (|b_c| -> inf); pi/2: the plane is perpendicular to
        the axis (b_c -> 0, a_c -> 0) and the line's image row no longer depends on range.
        """
        return math.asin(min(1.0, abs(self.normal[2])))


def check_conditioning(plane: LaserPlane, warn_angle: float = WARN_AXIS_ANGLE_RAD) -> list[str]:
    """Reasons the plane is ill-conditioned for triangulation (thesis 7.2.1); warns for each.

    Returns an empty list for a well-conditioned plane.
    """
    angle = plane.axis_angle()
    reasons = []
    if angle < warn_angle:
        reasons.append(
            f"laser plane is within {math.degrees(angle):.2f} deg of parallel to the optical axis: range "
            "resolution collapses towards the horizon and b_c -> inf"
        )
    if angle > math.pi / 2 - warn_angle:
        reasons.append(
            f"laser plane is within {90 - math.degrees(angle):.2f} deg of perpendicular to the optical axis: "
            "the line's image row barely changes with range (b_c -> 0)"
        )
    for r in reasons:
        warnings.warn(r, PlaneConditioningWarning, stacklevel=2)
    return reasons


class RangeStatus(enum.IntEnum):
    """Per-point outcome of triangulation (REP 117 mapping in brackets)."""

    OK = 0
    INVALID_PIXEL = 1  # no valid normalised coordinate (unprojection failed)  [NaN]
    BEYOND_HORIZON = 2  # ray parallel to or pointing away from the plane (denominator <= eps)  [NaN]
    TOO_CLOSE = 3  # nearer than the minimum range  [-inf]
    TOO_FAR = 4  # farther than the maximum range  [+inf]


@dataclass(frozen=True)
class Triangulation:
    """``points`` (..., 3) camera-frame metres, NaN unless OK; ``depth`` z (...); ``status`` codes."""

    points: np.ndarray
    depth: np.ndarray
    status: np.ndarray


def intersect_plane(
    xy: np.ndarray, plane: LaserPlane, min_depth: float = 0.0, max_depth: float = math.inf
) -> Triangulation:
    """Normalised coordinates (..., 2) -> 3-D points on the laser plane (eq. 3.13, 3.17 / D.67).

    ``min_depth``/``max_depth`` bound z (metres), as Algorithm 2's 1..10000 mm filter (docs/thesis-notes.md N3).
    A point at or beyond the horizon is never returned as a distance: its status says why.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim < 1 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
    nx, ny, nz = plane.normal
    denom = nx * xy[..., 0] + ny * xy[..., 1] + nz
    status = np.full(xy.shape[:-1], RangeStatus.OK, dtype=np.uint8)
    finite = np.isfinite(denom)
    status[~finite] = RangeStatus.INVALID_PIXEL
    horizon = finite & (denom <= HORIZON_EPS)
    status[horizon] = RangeStatus.BEYOND_HORIZON
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(status == RangeStatus.OK, plane.distance / denom, np.nan)
    status[(status == RangeStatus.OK) & (depth < min_depth)] = RangeStatus.TOO_CLOSE
    status[(status == RangeStatus.OK) & (depth > max_depth)] = RangeStatus.TOO_FAR
    ok = status == RangeStatus.OK
    points = np.where(ok[..., None], np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1) * depth[..., None], np.nan)
    return Triangulation(points, np.where(ok, depth, np.nan), status)


# ---------------------------------------------------------------- ideal model (section 3.2.1)
@dataclass(frozen=True)
class TriangulationParams:
    """Triangulation configuration of Table 3.1 (radians, metres).

    alpha: camera rotation w.r.t. the baseline s; beta: laser rotation w.r.t. s; psi: laser roll
    (pi/2 = line parallel to the image rows); s: baseline. theta = pi - alpha - beta (eq. D.72) is
    the angle between the laser's central axis and the optical axis.
    """

    alpha: float
    beta: float
    psi: float
    s: float

    @property
    def theta(self) -> float:
        return math.pi - self.alpha - self.beta


def ideal_depth(xy: np.ndarray, p: TriangulationParams) -> np.ndarray:
    """z of a normalised point, eq. 3.12 / D.22: z = s sin(beta) / (sin(theta) + y_n cos(theta) + x_n / tan(psi)).

    y_n in the OpenCV frame (y down): the far end of the line lies above the image centre
    (y_n < 0), where the denominator goes to zero at the horizon y_n = -tan(theta).
    """
    xy = np.asarray(xy, dtype=np.float64)
    th = p.theta
    denom = math.sin(th) + xy[..., 1] * math.cos(th) + xy[..., 0] / math.tan(p.psi)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(denom > HORIZON_EPS, p.s * math.sin(p.beta) / denom, np.nan)


def ideal_range(xy: np.ndarray, p: TriangulationParams) -> np.ndarray:
    """Distance q perpendicular to s, eq. 3.14 / D.38: q = z sqrt((sin a - y_n cos a)^2 + x_n^2)."""
    xy = np.asarray(xy, dtype=np.float64)
    z = ideal_depth(xy, p)
    return z * np.sqrt((math.sin(p.alpha) - xy[..., 1] * math.cos(p.alpha)) ** 2 + xy[..., 0] ** 2)


def plane_from_params(p: TriangulationParams) -> tuple[float, float, float]:
    """(a_c, b_c, c_c) of the plane implied by the ideal model (inverse of section 3.2.2).

    Matching eq. 3.12 term by term with eq. 3.17 gives c = s sin(beta)/sin(theta),
    b = -cot(theta) (OpenCV frame, docs/thesis-notes.md N4) and a = -cot(psi)/sin(theta).
    """
    th = p.theta
    if not (0 < th < math.pi) or math.isclose(math.sin(th), 0.0, abs_tol=1e-12):
        raise DegeneratePlaneError(
            f"theta = pi - alpha - beta = {math.degrees(th):.3f} deg: the laser axis must cross the optical "
            "axis in front of the camera (0 < theta < 180 deg)"
        )
    if not 0 < p.beta < math.pi or p.s <= 0 or not 0 < p.psi < math.pi:
        raise DegeneratePlaneError(f"need 0 < beta < 180 deg, 0 < psi < 180 deg and s > 0, got {p}")
    c = p.s * math.sin(p.beta) / math.sin(th)
    b = -1.0 / math.tan(th)
    a = -1.0 / (math.tan(p.psi) * math.sin(th))
    return a, b, c


def params_from_plane(a: float, b: float, c: float, beta: float) -> TriangulationParams:
    """Triangulation parameters from a calibrated plane, section 3.2.2 / D.2.2, for a known beta.

    theta = atan(1/|b_c|) (docs/thesis-notes.md N4), alpha = pi - (beta + theta) (D.72),
    s = sin(theta) c_c / sin(beta) (D.71), psi = pi/2 - atan(-a_c sin(theta)).

    Note on psi (docs/thesis-notes.md N11): D.75 writes the unit-step offset as -a_c cos(theta). That disagrees with eq. 3.12
    (D.22), whose x_n/tan(psi) term the plane form must reproduce: equating 3.12 and 3.17 gives
    a_c = -1/(tan(psi) sin(theta)). Rolling the laser by delta about its axis (direction at theta
    to the optical axis) tilts the plane's x-slope by tan(delta)/sin(theta), which confirms it.
    We use sin(theta), so that plane -> params -> plane is the identity and the two models agree.
    """
    if not all(map(math.isfinite, (a, b, c, beta))):
        raise DegeneratePlaneError(f"plane and beta must be finite, got a={a}, b={b}, c={c}, beta={beta}")
    if b == 0:
        raise DegeneratePlaneError("b_c = 0: the plane is perpendicular to the optical axis, theta = 90 deg has no depth cue")
    if not 0 < beta < math.pi:
        raise DegeneratePlaneError(f"beta must be in (0, 180) deg, got {math.degrees(beta)}")
    theta = math.atan(1.0 / abs(b))
    psi = math.pi / 2 - math.atan(-a * math.sin(theta))
    return TriangulationParams(alpha=math.pi - (beta + theta), beta=beta, psi=psi, s=math.sin(theta) * c / math.sin(beta))


def spot_range(y_n: np.ndarray, p: TriangulationParams) -> np.ndarray:
    """Spot-laser special case, eq. D.43: q = s (sin b sin a - y_n sin b cos a) / (sin t + y_n cos t)."""
    y = np.asarray(y_n, dtype=np.float64)
    th = p.theta
    return p.s * (math.sin(p.beta) * math.sin(p.alpha) - y * math.sin(p.beta) * math.cos(p.alpha)) / (
        math.sin(th) + y * math.cos(th)
    )
