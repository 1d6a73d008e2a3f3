"""Ray casting against a scene of vertical prisms (walls, boxes, cylinders) and a floor.

All in the scan frame (device.sim.scene). Rays are ``origin + t * direction`` with t >= 0 and
arrays of shape (N, 3) (or (N, 2) for rays in the laser plane); the functions return, per ray,
the first hit's ``t`` (inf for none), the surface id (-1 for none) and the 2-D surface normal.
Plain numpy, vectorised over rays and looped over the scene's few primitives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Box, Cylinder, Floor, Scene, Wall


@dataclass(frozen=True)
class Primitives:
    """The scene flattened to line segments and circles (vertical prisms) plus the floor."""

    seg_a: np.ndarray  # (S, 2)
    seg_b: np.ndarray  # (S, 2)
    seg_z: np.ndarray  # (S, 2) bottom, top
    seg_surface: np.ndarray  # (S,) surface id
    seg_offset: np.ndarray  # (S,) arc length before this segment along its surface (texture coordinate)
    circ_c: np.ndarray  # (C, 2)
    circ_r: np.ndarray  # (C,)
    circ_z: np.ndarray  # (C, 2)
    circ_surface: np.ndarray  # (C,)
    floor_z: float | None
    floor_surface: int


def primitives(scene: Scene) -> Primitives:
    a, b, z, sid, off = [], [], [], [], []
    cc, cr, cz, csid = [], [], [], []
    floor_z, floor_id = None, -1
    for i, s in enumerate(scene.surfaces):
        if isinstance(s, Wall):
            a.append(s.start), b.append(s.end), z.append(s.z_range), sid.append(i), off.append(0.0)
        elif isinstance(s, Box):
            corners = s.corners()
            run = 0.0
            for k in range(4):
                p, q = corners[k], corners[(k + 1) % 4]
                a.append(p), b.append(q), z.append(s.z_range), sid.append(i), off.append(run)
                run += float(np.hypot(q[0] - p[0], q[1] - p[1]))
        elif isinstance(s, Cylinder):
            cc.append(s.center), cr.append(s.radius), cz.append(s.z_range), csid.append(i)
        elif isinstance(s, Floor):
            floor_z, floor_id = s.z, i
    f = lambda x, shape: np.asarray(x, dtype=float).reshape(shape)  # noqa: E731
    return Primitives(
        f(a, (-1, 2)), f(b, (-1, 2)), f(z, (-1, 2)), np.asarray(sid, dtype=int), f(off, (-1,)),
        f(cc, (-1, 2)), f(cr, (-1,)), f(cz, (-1, 2)), np.asarray(csid, dtype=int), floor_z, floor_id,
    )


@dataclass(frozen=True)
class Hits:
    t: np.ndarray  # (N,) inf where nothing is hit
    surface: np.ndarray  # (N,) int, -1 where nothing is hit
    normal: np.ndarray  # (N, 3) unit surface normal (NaN where nothing is hit)
    texcoord: np.ndarray  # (N, 2) surface coordinates (arc length or x, height or y), metres


def cast(origin: np.ndarray, dirs: np.ndarray, prims: Primitives, t_min: float = 1e-9) -> Hits:
    """First hit of rays ``origin + t dirs`` (origin (3,) or (N, 3), dirs (N, 3)) with t > t_min."""
    dirs = np.asarray(dirs, dtype=float)
    if dirs.ndim != 2 or dirs.shape[1] != 3:
        raise ValueError(f"dirs must be (N, 3), got {dirs.shape}")
    o = np.broadcast_to(np.asarray(origin, dtype=float), dirs.shape)
    n = dirs.shape[0]
    best_t = np.full(n, np.inf)
    best_s = np.full(n, -1, dtype=int)
    normal = np.full((n, 3), np.nan)
    tex = np.full((n, 2), np.nan)
    dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    ox, oy, oz = o[:, 0], o[:, 1], o[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(prims.seg_a.shape[0]):
            ax, ay = prims.seg_a[k]
            ex, ey = prims.seg_b[k] - prims.seg_a[k]
            denom = dx * ey - dy * ex
            wx, wy = ax - ox, ay - oy
            s = (wx * dy - wy * dx) / denom
            # the rays that cross the segment's line within it, then the rest of the test on them
            # only: a wall of a room spans a part of the view (same arithmetic, fewer rays)
            near = np.flatnonzero((np.abs(denom) > 1e-15) & (s >= 0) & (s <= 1))
            if not near.size:
                continue
            t = (wx[near] * ey - wy[near] * ex) / denom[near]
            z = oz[near] + t * dz[near]
            lo, hi = prims.seg_z[k]
            ok = (t > t_min) & (z >= lo) & (z <= hi) & (t < best_t[near])
            if ok.any():
                hit = near[ok]
                length = np.hypot(ex, ey)
                best_t[hit], best_s[hit] = t[ok], prims.seg_surface[k]
                normal[hit] = (ey / length, -ex / length, 0.0)
                tex[hit, 0] = prims.seg_offset[k] + s[hit] * length
                tex[hit, 1] = z[ok]
        for k in range(prims.circ_c.shape[0]):
            cx, cy = prims.circ_c[k]
            r = prims.circ_r[k]
            px, py = ox - cx, oy - cy
            a = dx * dx + dy * dy
            b = px * dx + py * dy
            c = px * px + py * py - r * r
            disc = b * b - a * c
            root = np.sqrt(disc)
            lo, hi = prims.circ_z[k]
            for t in ((-b - root) / a, (-b + root) / a):
                z = oz + t * dz
                hit = (disc >= 0) & (a > 0) & (t > t_min) & (z >= lo) & (z <= hi) & (t < best_t)
                if hit.any():
                    hx, hy = px[hit] + t[hit] * dx[hit], py[hit] + t[hit] * dy[hit]
                    best_t[hit], best_s[hit] = t[hit], prims.circ_surface[k]
                    normal[hit] = np.stack([hx / r, hy / r, np.zeros_like(hx)], axis=-1)
                    tex[hit, 0] = np.arctan2(hy, hx) * r
                    tex[hit, 1] = z[hit]
        if prims.floor_z is not None:
            t = (prims.floor_z - oz) / dz
            hit = (t > t_min) & (t < best_t)
            if hit.any():
                best_t[hit], best_s[hit] = t[hit], prims.floor_surface
                normal[hit] = (0.0, 0.0, 1.0)
                tex[hit, 0] = ox[hit] + t[hit] * dx[hit]
                tex[hit, 1] = oy[hit] + t[hit] * dy[hit]
    return Hits(best_t, best_s, normal, tex)


def laser_prims(prims: Primitives) -> Primitives:
    """Only the primitives that cross the laser plane z = 0 (the floor never does)."""
    s = (prims.seg_z[:, 0] <= 0) & (prims.seg_z[:, 1] >= 0)
    c = (prims.circ_z[:, 0] <= 0) & (prims.circ_z[:, 1] >= 0)
    return Primitives(prims.seg_a[s], prims.seg_b[s], prims.seg_z[s], prims.seg_surface[s], prims.seg_offset[s],
                      prims.circ_c[c], prims.circ_r[c], prims.circ_z[c], prims.circ_surface[c], None, -1)


def mirror(points: np.ndarray, surface: Wall | Floor) -> np.ndarray:
    """Points (N, 3) mirrored in the plane of a flat surface (a Wall's vertical plane or the Floor)."""
    p = np.array(points, dtype=float)
    if isinstance(surface, Floor):
        p[:, 2] = 2 * surface.z - p[:, 2]
        return p
    a = np.asarray(surface.start)
    e = np.asarray(surface.end) - a
    nrm = np.array([e[1], -e[0]]) / np.hypot(*e)
    dist = (p[:, :2] - a) @ nrm
    p[:, :2] -= 2 * dist[:, None] * nrm
    return p


def value_noise(u: np.ndarray, v: np.ndarray, seed: int) -> np.ndarray:
    """Smooth lattice noise in [0, 1] at (u, v) in lattice units (bilinear with smoothstep)."""
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    h00, h10, h01, h11 = _corner_hashes(iu, iv, seed)
    top = h00 * (1 - fu) + h10 * fu
    bot = h01 * (1 - fu) + h11 * fu
    return top * (1 - fv) + bot * fv


def _lattice_hash(i: np.ndarray, j: np.ndarray, seed: int) -> np.ndarray:
    """The value at lattice point (i, j): a hash of its coordinates in [0, 1)."""
    x = np.sin(i * 12.9898 + j * 78.233 + seed * 37.719) * 43758.5453
    return x - np.floor(x)


def _corner_hashes(iu: np.ndarray, iv: np.ndarray, seed: int) -> tuple[np.ndarray, ...]:
    """The hashes of the lattice corners (iu, iv), (iu + 1, iv), (iu, iv + 1), (iu + 1, iv + 1).
    Many points share a lattice cell (a texture's cell spans many pixels): where the cells'
    bounding box has fewer corners than there are points, each corner is hashed once and looked
    up; the same arithmetic on the same coordinates, so the same values."""
    if iu.size:
        u0, u1, v0, v1 = iu.min(), iu.max(), iv.min(), iv.max()
        if np.isfinite((u0, u1, v0, v1)).all() and (u1 - u0 + 2) * (v1 - v0 + 2) < iu.size:
            nu, nv = int(u1 - u0) + 2, int(v1 - v0) + 2
            table = _lattice_hash((u0 + np.arange(nu, dtype=float))[:, None], (v0 + np.arange(nv, dtype=float))[None, :],
                                  seed).ravel()
            k = (iu - u0).astype(np.intp) * nv + (iv - v0).astype(np.intp)
            return table[k], table[k + nv], table[k + 1], table[k + nv + 1]
    return (_lattice_hash(iu, iv, seed), _lattice_hash(iu + 1, iv, seed), _lattice_hash(iu, iv + 1, seed),
            _lattice_hash(iu + 1, iv + 1, seed))


def texture_factor(kind: str, texcoord: np.ndarray, scale_m: float, seed: int, depth: float = 0.3) -> np.ndarray:
    """Multiplicative reflectivity texture (mean ~1, within 1 +- depth) at surface coordinates (N, 2)."""
    s, z = texcoord[:, 0] / scale_m, texcoord[:, 1] / scale_m
    if kind == "plain":
        return np.ones_like(s)
    if kind == "noise":
        n = 0.65 * value_noise(s, z, seed) + 0.35 * value_noise(3.1 * s, 3.1 * z, seed + 1)
        return 1.0 + depth * (2 * n - 1)
    if kind == "checker":
        return 1.0 + depth * np.where((np.floor(s) + np.floor(z)) % 2 == 0, 1.0, -1.0)
    if kind == "stripes":
        return 1.0 + depth * np.where(np.floor(s) % 2 == 0, 1.0, -1.0)
    raise ValueError(f"unknown texture {kind!r}")
