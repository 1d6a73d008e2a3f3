"""The simulator's ray caster and texture noise (device/sim/geometry.py) against plain per-ray
and per-point evaluations of the same arithmetic: the vectorised forms only skip work."""

import dataclasses

import numpy as np

from device.sim.geometry import _lattice_hash, cast, primitives, value_noise
from device.sim.scene import get_scene, scene_from_dict


def _first_hit_by_segment(o, d, prims, t_min=1e-9):
    """(t, surface, s) of one ray's first hit among the segments, one segment at a time."""
    best = (np.inf, -1, np.nan)
    for k in range(prims.seg_a.shape[0]):
        ax, ay = prims.seg_a[k]
        ex, ey = prims.seg_b[k] - prims.seg_a[k]
        denom = d[0] * ey - d[1] * ex
        if not abs(denom) > 1e-15:
            continue
        wx, wy = ax - o[0], ay - o[1]
        t, s = (wx * ey - wy * ex) / denom, (wx * d[1] - wy * d[0]) / denom
        z = o[2] + t * d[2]
        lo, hi = prims.seg_z[k]
        if t > t_min and 0 <= s <= 1 and lo <= z <= hi and t < best[0]:
            best = (t, int(prims.seg_surface[k]), s)
    return best


def test_cast_finds_each_rays_first_segment_as_a_ray_by_ray_search_does():
    rng = np.random.default_rng(3)
    prims = primitives(scene_from_dict({"name": "walls only", "wall": [
        {"from": [2.0, -1.0], "to": [2.0, 1.0]}, {"from": [3.0, -2.0], "to": [3.0, 2.0]},
        {"from": [1.0, 0.5], "to": [4.0, 0.5], "z": [-0.5, 0.2]}]}))
    n = 4000
    d = np.column_stack([rng.uniform(0.2, 1.0, n), rng.uniform(-1.0, 1.0, n), rng.uniform(-0.3, 0.3, n)])
    o = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n), rng.uniform(-0.1, 0.1, n)])
    hits = cast(o, d, prims)
    expected = [_first_hit_by_segment(o[i], d[i], prims) for i in range(n)]
    assert np.array_equal(hits.t, [e[0] for e in expected])
    assert np.array_equal(hits.surface, [e[1] for e in expected])
    assert 0.2 * n < np.count_nonzero(hits.surface >= 0) < n  # both hits and misses were tried
    # the texture coordinate along a wall is where the ray met it
    s = np.array([e[2] for e in expected])
    hit = hits.surface >= 0
    length = np.hypot(*(prims.seg_b - prims.seg_a)[hits.surface[hit]].T)
    assert np.allclose(hits.texcoord[hit, 0], s[hit] * length, rtol=0, atol=1e-12)


def test_cast_counts_a_segments_ends_and_not_a_ray_along_it_or_behind_the_origin():
    prims = primitives(scene_from_dict({"name": "one", "wall": [{"from": [2.0, -1.0], "to": [2.0, 1.0]}]}))
    o = np.zeros(3)
    d = np.array([[1.0, -0.5, 0.0],   # the wall's end at y = -1 (s = 0)
                  [1.0, 0.5, 0.0],    # its other end (s = 1)
                  [1.0, 0.5000001, 0.0],  # just past it
                  [0.0, 1.0, 0.0],    # parallel to it
                  [-1.0, 0.0, 0.0]])  # away from it
    hits = cast(o, d, prims)
    assert list(hits.surface) == [0, 0, -1, -1, -1]
    assert np.array_equal(hits.t[:2], [2.0, 2.0]) and np.all(np.isinf(hits.t[2:]))
    assert np.array_equal(hits.texcoord[:2, 0], [0.0, 2.0])


def test_cast_on_a_built_in_scene_matches_the_ray_by_ray_search():
    rng = np.random.default_rng(5)
    prims = dataclasses.replace(primitives(get_scene("office")), floor_z=None)  # its walls and boxes only
    assert prims.circ_c.shape[0] == 0 and prims.seg_a.shape[0] > 5
    n = 2000
    a = rng.uniform(-np.pi, np.pi, n)
    d = np.column_stack([np.cos(a), np.sin(a), rng.uniform(-0.2, 0.2, n)])
    o = np.array([0.05, -0.02, 0.1])
    hits = cast(o, d, prims)
    expected = [_first_hit_by_segment(o, d[i], prims) for i in range(n)]
    assert np.array_equal(hits.t, [e[0] for e in expected])
    assert np.array_equal(hits.surface, [e[1] for e in expected])


def _value_noise_point_by_point(u, v, seed):
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    h = lambda i, j: _lattice_hash(i, j, seed)  # noqa: E731
    top = h(iu, iv) * (1 - fu) + h(iu + 1, iv) * fu
    bot = h(iu, iv + 1) * (1 - fu) + h(iu + 1, iv + 1) * fu
    return top * (1 - fv) + bot * fv


def test_value_noise_looked_up_by_lattice_cell_is_the_hash_of_each_point():
    rng = np.random.default_rng(7)
    # many points in few cells (a texture seen by many pixels: the cells' hashes looked up), few
    # points over many cells (each point hashed), negative and large coordinates
    for n, span_u, span_v, at in ((5000, 30.0, 3.0, -12.5), (50, 400.0, 50.0, 0.0), (3000, 2.0, 2.0, 1.0e5),
                                  (1, 0.0, 0.0, 3.0), (0, 1.0, 1.0, 0.0)):
        u = at + rng.uniform(0, span_u, n)
        v = -at + rng.uniform(0, span_v, n)
        got = value_noise(u, v, 11)
        assert np.array_equal(got, _value_noise_point_by_point(u, v, 11))
        assert got.shape == (n,) and np.all((got >= 0) & (got <= 1))
