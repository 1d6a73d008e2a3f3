"""Post-calibration of the depth, thesis eq. 6.5 in a well-conditioned form (docs/thesis-notes.md N8).

``z_corrected = z - sum_k c_k X^i_k Z^j_k`` with ``X = x / x_scale_m`` and
``Z = (z - z_offset_m) / z_scale_m`` (:class:`device.config.PostCalibration`), x and z the
camera-frame coordinates of the point in metres. The thesis's Table 6.1 gives the same
polynomial in raw millimetre monomials up to z^4 (~1e14 at 3 m); :func:`from_thesis_mm`
re-expands it exactly into scaled coordinates, and :func:`fit` fits new coefficients there.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import PostCalibration

#: Table 6.1: (i, j) of the monomial x^i z^j (millimetres) -> coefficient p_ij (correction in mm).
THESIS_TABLE_6_1: dict[tuple[int, int], float] = {
    (0, 0): -14.2902751197414,
    (1, 0): 0.0050563731787,
    (0, 1): 0.1052658383751,
    (2, 0): 0.0000644780056,
    (1, 1): 0.0000182952860,
    (0, 2): -0.0001576897638,
    (2, 1): 0.0000000306129,
    (1, 2): 0.0000000017341,
    (0, 3): 0.0000000365886,
    (2, 2): -0.0000000000076,
    (1, 3): -0.0000000000001,
    (0, 4): -0.0000000000052,
}


def correction(post: PostCalibration, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """sum_k c_k X^i Z^j (metres) at camera-frame x, z (metres); same shape as x and z."""
    X = np.asarray(x, dtype=np.float64) / post.x_scale_m
    Z = (np.asarray(z, dtype=np.float64) - post.z_offset_m) / post.z_scale_m
    out = np.zeros(np.broadcast(X, Z).shape)
    for (i, j), c in zip(post.terms, post.coefficients):
        out += c * X**i * Z**j
    return out


def apply(post: PostCalibration | None, points: np.ndarray) -> np.ndarray:
    """Correct camera-frame points (..., 3) by eq. 6.5: z' = z - correction(x, z).

    The thesis corrects z only; the point is moved along its own camera ray (scaled by z'/z) so
    it stays on the pixel it was measured at. NaN points stay NaN.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {p.shape}")
    if post is None or not post.terms:
        return p
    z = p[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = (z - correction(post, p[..., 0], z)) / z
    return p * scale[..., None]


def from_thesis_mm(
    coefficients: dict[tuple[int, int], float] = THESIS_TABLE_6_1,
    x_scale_m: float = 1.0,
    z_offset_m: float = 1.5,
    z_scale_m: float = 1.5,
) -> PostCalibration:
    """Exact re-expansion of eq. 6.5's mm monomials into scaled coordinates (metres).

    With x_mm = 1000 x_s X and z_mm = 1000 (z0 + z_s Z):
    p_ij x_mm^i z_mm^j = p_ij (1000 x_s)^i sum_m C(j, m) (1000 z0)^(j-m) (1000 z_s)^m X^i Z^m,
    and the correction in metres is 1e-3 times the one in millimetres.
    """
    if not (x_scale_m > 0 and z_scale_m > 0 and math.isfinite(z_offset_m)):
        raise ValueError(f"scales must be positive and the offset finite, got {x_scale_m}, {z_scale_m}, {z_offset_m}")
    acc: dict[tuple[int, int], float] = {}
    for (i, j), p in coefficients.items():
        if i < 0 or j < 0:
            raise ValueError(f"monomial exponents must be non-negative, got ({i}, {j})")
        for m in range(j + 1):
            c = p * (1000 * x_scale_m) ** i * math.comb(j, m) * (1000 * z_offset_m) ** (j - m) * (1000 * z_scale_m) ** m
            acc[(i, m)] = acc.get((i, m), 0.0) + 1e-3 * c
    terms = tuple(sorted(acc, key=lambda t: (t[0] + t[1], t)))
    return PostCalibration(terms, tuple(acc[t] for t in terms), x_scale_m, z_offset_m, z_scale_m)


def fit(
    x: np.ndarray, z: np.ndarray, z_true: np.ndarray, terms: tuple[tuple[int, int], ...],
    x_scale_m: float | None = None, z_offset_m: float | None = None, z_scale_m: float | None = None,
) -> PostCalibration:
    """Least-squares post-calibration from measured (x, z) and true depth, in scaled coordinates
    (defaults: centre and half-span of the data), so the design matrix stays well conditioned."""
    x, z, z_true = (np.asarray(a, dtype=np.float64).ravel() for a in (x, z, z_true))
    ok = np.isfinite(x) & np.isfinite(z) & np.isfinite(z_true)
    if ok.sum() < len(terms):
        raise ValueError(f"need at least {len(terms)} finite samples to fit {len(terms)} terms, got {ok.sum()}")
    x, z, z_true = x[ok], z[ok], z_true[ok]
    xs = x_scale_m or max(float(np.max(np.abs(x))), 1e-3)
    z0 = float((z.max() + z.min()) / 2) if z_offset_m is None else z_offset_m
    zs = z_scale_m or max(float((z.max() - z.min()) / 2), 1e-3)
    X, Z = x / xs, (z - z0) / zs
    A = np.stack([X**i * Z**j for i, j in terms], axis=1)
    coef, *_ = np.linalg.lstsq(A, z - z_true, rcond=None)
    return PostCalibration(tuple(terms), tuple(float(c) for c in coef), xs, z0, zs)
