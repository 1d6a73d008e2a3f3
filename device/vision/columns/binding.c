/* device.vision._columns: the Python module around the plain C kernel of columns.h (the fast
 * pipeline's image passes and per-column steps, and the table triangulation). Thin: each entry
 * point takes numpy arrays through the buffer protocol (no numpy headers), checks their dtype,
 * contiguity and shape (ValueError naming the argument), puts them and the scalars into the
 * kernel's structs and calls it, without the GIL for the image-sized passes. The kernel's own
 * argument errors become ValueError too.
 *
 * Entry points (all outputs are caller-allocated arrays):
 *   candidates(sm, padded, pad, sep, k_out, s_out)
 *   refine_com(padded, pad, k, cols, lo, hi, half_width, row, peak, argmax, valid, plateau, spread)
 *   resolve((k, s), thr, noise, first, second, (inv_depth, inv_depth_top), (top, t0, t1), params,
 *           (found, row, peak, status)) -> (seen_first, seen_last)
 *   running_median(x, found, out)
 *   noise_level(lit, unlit, out)
 *   moved(a, b, unlit, (level, block_level, block_ratio, mean_ratio), out)
 *   band_difference(lit, unlit, mask, padded, pad, sm, sat_min)
 *   run_length(mask, out)
 *   spans(mask, join, out) -> count
 *   near_rows(lit, unlit, mask, (r0, r1, step), (c0, c1), above, below, pair)
 *   triangulate(rows, cols, xn, yn, top, plane, limits, codes, points, depth, status)
 *   scan_plane(points, rotation, origin, angle, range)
 *   scan_rays(angle, range, quality, row, grid, gap_spacings, max_jump_ratio, range_out, quality_out,
 *             row_out)
 *   scan_timing(times_ns, fallback_ns) -> (first_ns, interval_ns, residual_ns)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "columns.h"

typedef Py_ssize_t idx_t;
_Static_assert(sizeof(idx_t) == sizeof(ptrdiff_t), "numpy's intp (Py_ssize_t) must be the kernel's ptrdiff_t");
_Static_assert(sizeof(bool) == 1, "numpy's bool_ must be the kernel's bool");

/* A C-contiguous buffer of `kind` ('u': uint8, 'b': bool, 'i': intp, 'd': float64) with `ndim`
 * dimensions; shape[d] must equal want[d] where want[d] >= 0 (the actual shape is written back). */
static int get_array(PyObject *obj, Py_buffer *view, char kind, int ndim, idx_t *want, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous%s array", name, writable ? " writable" : "");
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (*f == '@' || *f == '=' || (*f == '<' && PY_LITTLE_ENDIAN)) f++;
    int ok;
    switch (kind) {
    case 'u': ok = (*f == 'B') && view->itemsize == 1; break;
    case 'b': ok = (*f == '?') && view->itemsize == 1; break;
    case 'i': ok = (*f == 'i' || *f == 'l' || *f == 'q' || *f == 'n') && view->itemsize == (idx_t)sizeof(idx_t); break;
    default: ok = (*f == 'd') && view->itemsize == 8; break;
    }
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s has dtype format '%s' (itemsize %zd), expected %s", name, f,
                     view->itemsize, kind == 'u' ? "uint8" : kind == 'b' ? "bool" : kind == 'i' ? "intp" : "float64");
        PyBuffer_Release(view);
        return -1;
    }
    if (view->ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s must have %d dimension(s), got %d", name, ndim, view->ndim);
        PyBuffer_Release(view);
        return -1;
    }
    for (int d = 0; d < ndim; d++) {
        if (want[d] >= 0 && view->shape[d] != want[d]) {
            PyErr_Format(PyExc_ValueError, "%s has length %zd along axis %d, expected %zd", name, view->shape[d], d, want[d]);
            PyBuffer_Release(view);
            return -1;
        }
        want[d] = view->shape[d];
    }
    return 0;
}

/* Up to 32 buffers acquired by one call, released together. */
typedef struct {
    Py_buffer v[32];
    int n;
} Views;

static void *arg(Views *vs, PyObject *obj, char kind, idx_t n0, idx_t n1, int ndim, int writable, const char *name,
                 idx_t *shape_out)
{
    idx_t want[2] = {n0, n1};
    if (vs->n >= (int)(sizeof vs->v / sizeof vs->v[0])) {
        PyErr_SetString(PyExc_SystemError, "_columns: too many buffers in one call");
        return NULL;
    }
    if (get_array(obj, &vs->v[vs->n], kind, ndim, want, writable, name) < 0) return NULL;
    for (int d = 0; shape_out && d < ndim; d++) shape_out[d] = want[d]; /* a 1-D argument's shape_out is a scalar */
    return vs->v[vs->n++].buf;
}

static void release(Views *vs)
{
    for (int i = 0; i < vs->n; i++) PyBuffer_Release(&vs->v[i]);
    vs->n = 0;
}

/* Releases the buffers; the kernel's error as a Python exception, else `value` (a new reference,
 * NULL for None). */
static PyObject *done(Views *vs, ColumnsResult result, const ColumnsError *err, PyObject *value)
{
    release(vs);
    if (result == COLUMNS_BAD_ARGUMENT) {
        Py_XDECREF(value);
        PyErr_SetString(PyExc_ValueError, err->message);
        return NULL;
    }
    if (result == COLUMNS_NO_MEMORY) {
        Py_XDECREF(value);
        return PyErr_NoMemory();
    }
    if (value) return value;
    Py_RETURN_NONE;
}

static PyObject *failed(Views *vs)
{
    release(vs);
    return NULL;
}

static PyObject *py_candidates(PyObject *self, PyObject *args)
{
    PyObject *o_sm, *o_pad, *o_k, *o_s;
    idx_t pad, sep;
    if (!PyArg_ParseTuple(args, "OOnnOO", &o_sm, &o_pad, &pad, &sep, &o_k, &o_s)) return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *sm = arg(&vs, o_sm, 'u', -1, -1, 2, 0, "sm", shp);
    if (!sm) return NULL;
    idx_t n = shp[0], W = shp[1];
    uint8_t *P = arg(&vs, o_pad, 'u', n + 2 * pad, W, 2, 0, "padded", NULL);
    idx_t *k = P ? arg(&vs, o_k, 'i', 2 * W, 0, 1, 1, "k", NULL) : NULL;
    double *s = k ? arg(&vs, o_s, 'd', 2 * W, 0, 1, 1, "s", NULL) : NULL;
    if (!s) return failed(&vs);
    const ColumnsPadded diff = {P, n, W, pad};
    ColumnsError err;
    ColumnsResult r;
    Py_BEGIN_ALLOW_THREADS
    r = columns_candidates(sm, &diff, sep, k, s, &err);
    Py_END_ALLOW_THREADS
    return done(&vs, r, &err, NULL);
}

static PyObject *py_noise_level(PyObject *self, PyObject *args)
{
    PyObject *o_a, *o_b, *o_out;
    if (!PyArg_ParseTuple(args, "OOO", &o_a, &o_b, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *A = arg(&vs, o_a, 'u', -1, -1, 2, 0, "lit", shp);
    const uint8_t *B = A ? arg(&vs, o_b, 'u', shp[0], shp[1], 2, 0, "unlit", NULL) : NULL;
    double *out = B ? arg(&vs, o_out, 'd', shp[1], 0, 1, 1, "out", NULL) : NULL;
    if (!out) return failed(&vs);
    ColumnsError err;
    ColumnsResult r;
    Py_BEGIN_ALLOW_THREADS
    r = columns_noise_level(A, B, shp[0], shp[1], out, &err);
    Py_END_ALLOW_THREADS
    return done(&vs, r, &err, NULL);
}

static PyObject *py_moved(PyObject *self, PyObject *args)
{
    PyObject *o_a, *o_b, *o_u, *o_out;
    ColumnsMovedParams p;
    if (!PyArg_ParseTuple(args, "OOO(dddd)O", &o_a, &o_b, &o_u, &p.level, &p.block_level, &p.block_ratio,
                          &p.mean_ratio, &o_out))
        return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *A = arg(&vs, o_a, 'u', -1, -1, 2, 0, "a", shp);
    const uint8_t *B = A ? arg(&vs, o_b, 'u', shp[0], shp[1], 2, 0, "b", NULL) : NULL;
    const uint8_t *U = B ? arg(&vs, o_u, 'u', shp[0], shp[1], 2, 0, "unlit", NULL) : NULL;
    bool *out = U ? arg(&vs, o_out, 'b', shp[1], 0, 1, 1, "out", NULL) : NULL;
    if (!out) return failed(&vs);
    ColumnsError err;
    ColumnsResult r;
    Py_BEGIN_ALLOW_THREADS
    r = columns_moved(A, B, U, shp[0], shp[1], &p, out, &err);
    Py_END_ALLOW_THREADS
    return done(&vs, r, &err, NULL);
}

static PyObject *py_band_difference(PyObject *self, PyObject *args)
{
    PyObject *o_a, *o_b, *o_mask, *o_pad, *o_sm;
    idx_t pad, sat_min;
    if (!PyArg_ParseTuple(args, "OOOOnOn", &o_a, &o_b, &o_mask, &o_pad, &pad, &o_sm, &sat_min)) return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *A = arg(&vs, o_a, 'u', -1, -1, 2, 0, "lit", shp);
    idx_t n = shp[0], W = shp[1];
    const uint8_t *B = A ? arg(&vs, o_b, 'u', n, W, 2, 0, "unlit", NULL) : NULL;
    const uint8_t *M = B ? arg(&vs, o_mask, 'u', n, W, 2, 0, "mask", NULL) : NULL;
    uint8_t *P = M ? arg(&vs, o_pad, 'u', n + 2 * pad, W, 2, 1, "padded", NULL) : NULL;
    uint8_t *S = P ? arg(&vs, o_sm, 'u', n, W, 2, 1, "sm", NULL) : NULL;
    if (!S) return failed(&vs);
    const ColumnsPadded diff = {P, n, W, pad};
    ColumnsError err;
    ColumnsResult r;
    Py_BEGIN_ALLOW_THREADS
    r = columns_band_difference(A, B, M, sat_min, &diff, S, &err);
    Py_END_ALLOW_THREADS
    return done(&vs, r, &err, NULL);
}

static PyObject *py_run_length(PyObject *self, PyObject *args)
{
    PyObject *o_m, *o_out;
    if (!PyArg_ParseTuple(args, "OO", &o_m, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t W;
    const bool *m = arg(&vs, o_m, 'b', -1, 0, 1, 0, "mask", &W);
    idx_t *out = m ? arg(&vs, o_out, 'i', W, 0, 1, 1, "out", NULL) : NULL;
    if (!out) return failed(&vs);
    columns_run_length(m, W, out);
    return done(&vs, COLUMNS_DONE, NULL, NULL);
}

/* spans(mask, join, out) -> count: columns_spans; out (>= (n + 1) // 2, 2) intp. */
static PyObject *py_spans(PyObject *self, PyObject *args)
{
    PyObject *o_m, *o_out;
    idx_t join;
    if (!PyArg_ParseTuple(args, "OnO", &o_m, &join, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t W, shp[2];
    const bool *m = arg(&vs, o_m, 'b', -1, 0, 1, 0, "mask", &W);
    idx_t *out = m ? arg(&vs, o_out, 'i', -1, 2, 2, 1, "out", shp) : NULL;
    if (!out) return failed(&vs);
    if (shp[0] < (W + 1) / 2) {
        release(&vs);
        return PyErr_Format(PyExc_ValueError, "out holds %zd spans, a mask of %zd can have %zd", shp[0], W, (W + 1) / 2);
    }
    idx_t k = columns_spans(m, W, join, out);
    release(&vs);
    return PyLong_FromSsize_t(k);
}

/* near_rows(lit, unlit, mask, (r0, r1, step), (c0, c1), above, below, pair): columns_near_rows. */
static PyObject *py_near_rows(PyObject *self, PyObject *args)
{
    PyObject *o_l, *o_u, *o_m, *o_a, *o_b, *o_p;
    idx_t r0, r1, step, c0, c1;
    if (!PyArg_ParseTuple(args, "OOO(nnn)(nn)OOO", &o_l, &o_u, &o_m, &r0, &r1, &step, &c0, &c1, &o_a, &o_b, &o_p))
        return NULL;
    if (step < 1) return PyErr_Format(PyExc_ValueError, "near_rows: step must be >= 1, got %zd", step);
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *L = arg(&vs, o_l, 'u', -1, -1, 2, 0, "lit", shp);
    const uint8_t *U = L ? arg(&vs, o_u, 'u', shp[0], shp[1], 2, 0, "unlit", NULL) : NULL;
    if (U && (!(0 <= r0 && r0 < r1 && r1 <= shp[0]) || !(0 <= c0 && c0 < c1 && c1 <= shp[1]))) {
        release(&vs); /* before the sizes below are computed from them */
        return PyErr_Format(PyExc_ValueError, "near_rows: need 0 <= r0 < r1 <= H, 0 <= c0 < c1 <= W, got rows %zd-%zd "
                            "of %zd, columns %zd-%zd of %zd", r0, r1, shp[0], c0, c1, shp[1]);
    }
    const idx_t rows_m = U ? (r1 - r0 - 1) / step + 1 : 0;
    const uint8_t *M = U ? arg(&vs, o_m, 'u', rows_m, shp[1], 2, 0, "mask", NULL) : NULL;
    const idx_t n = c1 - c0;
    uint8_t *A = M ? arg(&vs, o_a, 'u', n, 0, 1, 1, "above", NULL) : NULL;
    uint8_t *B = A ? arg(&vs, o_b, 'u', n, 0, 1, 1, "below", NULL) : NULL;
    uint8_t *P = B ? arg(&vs, o_p, 'u', n, 0, 1, 1, "pair", NULL) : NULL;
    if (!P) return failed(&vs);
    /* the kernel's loops take restrict pointers: no output may share a byte with another buffer */
    const uint8_t *bufs[6] = {A, B, P, L, U, M};
    const idx_t sizes[6] = {n, n, n, shp[0] * shp[1], shp[0] * shp[1], rows_m * shp[1]};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 6; j++)
            if (i != j && bufs[i] < bufs[j] + sizes[j] && bufs[j] < bufs[i] + sizes[i]) {
                release(&vs);
                return PyErr_Format(PyExc_ValueError, "near_rows: %s shares memory with %s",
                                    (const char *[]){"above", "below", "pair"}[i],
                                    (const char *[]){"above", "below", "pair", "lit", "unlit", "mask"}[j]);
            }
    ColumnsError err;
    ColumnsResult r = columns_near_rows(L, U, shp[0], shp[1], M, r0, r1, step, c0, c1, A, B, P, &err);
    return done(&vs, r, &err, NULL);
}

static PyObject *py_running_median(PyObject *self, PyObject *args)
{
    PyObject *o_x, *o_found, *o_out;
    if (!PyArg_ParseTuple(args, "OOO", &o_x, &o_found, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t W;
    const double *x = arg(&vs, o_x, 'd', -1, 0, 1, 0, "x", &W);
    const bool *found = x ? arg(&vs, o_found, 'b', W, 0, 1, 0, "found", NULL) : NULL;
    double *out = found ? arg(&vs, o_out, 'd', W, 0, 1, 1, "out", NULL) : NULL;
    if (!out) return failed(&vs);
    columns_running_median(x, found, W, out);
    return done(&vs, COLUMNS_DONE, NULL, NULL);
}

static PyObject *py_refine_com(PyObject *self, PyObject *args)
{
    PyObject *o_pad, *o_k, *o_cols, *o_lo, *o_hi, *o_row, *o_peak, *o_arg, *o_valid, *o_plat, *o_spread;
    idx_t pad, half;
    if (!PyArg_ParseTuple(args, "OnOOOOnOOOOOO", &o_pad, &pad, &o_k, &o_cols, &o_lo, &o_hi, &half, &o_row, &o_peak,
                          &o_arg, &o_valid, &o_plat, &o_spread))
        return NULL;
    Views vs = {.n = 0};
    idx_t shp[2], m;
    uint8_t *P = arg(&vs, o_pad, 'u', -1, -1, 2, 0, "padded", shp);
    const idx_t *k = P ? arg(&vs, o_k, 'i', -1, 0, 1, 0, "argmax", &m) : NULL;
    const idx_t *cols = k ? arg(&vs, o_cols, 'i', m, 0, 1, 0, "cols", NULL) : NULL;
    const idx_t *lo = cols ? arg(&vs, o_lo, 'i', m, 0, 1, 0, "row_lo", NULL) : NULL;
    const idx_t *hi = lo ? arg(&vs, o_hi, 'i', m, 0, 1, 0, "row_hi", NULL) : NULL;
    ColumnsPeaks out;
    out.row = hi ? arg(&vs, o_row, 'd', m, 0, 1, 1, "row", NULL) : NULL;
    out.peak = out.row ? arg(&vs, o_peak, 'd', m, 0, 1, 1, "peak", NULL) : NULL;
    out.argmax = out.peak ? arg(&vs, o_arg, 'i', m, 0, 1, 1, "argmax_out", NULL) : NULL;
    out.valid = out.argmax ? arg(&vs, o_valid, 'b', m, 0, 1, 1, "valid", NULL) : NULL;
    out.plateau = out.valid ? arg(&vs, o_plat, 'b', m, 0, 1, 1, "plateau", NULL) : NULL;
    out.spread = out.plateau ? arg(&vs, o_spread, 'd', m, 0, 1, 1, "spread", NULL) : NULL;
    if (!out.spread) return failed(&vs);
    const ColumnsPadded diff = {P, shp[0] - 2 * pad, shp[1], pad};
    ColumnsError err;
    ColumnsResult r = columns_refine_com(&diff, m, k, cols, lo, hi, half, &out, &err);
    return done(&vs, r, &err, NULL);
}

/* resolve((k, s), thr, noise, (row1, peak1, valid1, spread1), (idx2, row2, peak2, valid2, spread2),
 *         (inv_depth, inv_depth_top), (top, t0, t1), params, (found, row, peak, status))
 * -> (seen_first, seen_last): columns_resolve, one tuple per part of its arguments
 * (ColumnsResolveInput, ColumnsResolveParams' fields in order, ColumnsLine). */
static PyObject *py_resolve(PyObject *self, PyObject *args)
{
    PyObject *o_k, *o_s, *o_thr, *o_noise, *o_r1, *o_p1, *o_v1, *o_sp1, *o_idx, *o_r2, *o_p2, *o_v2, *o_sp2, *o_tab;
    PyObject *o_found, *o_row, *o_peak, *o_status;
    ColumnsResolveInput in;
    ColumnsResolveParams p;
    if (!PyArg_ParseTuple(args, "(OO)OO(OOOO)(OOOOO)(On)(nnn)(dddddddnnnn)(OOOO)", &o_k, &o_s, &o_thr, &o_noise, &o_r1,
                          &o_p1, &o_v1, &o_sp1, &o_idx, &o_r2, &o_p2, &o_v2, &o_sp2, &o_tab, &in.inv_depth.top, &in.top,
                          &in.t0, &in.t1, &p.dim_peak_fraction, &p.own_peak_fraction, &p.max_spread_px, &p.jump_rel,
                          &p.jump_factor, &p.min_peak, &p.max_range_sigma, &p.min_run, &p.smooth_half, &p.support_half,
                          &p.max_gap,
                          &o_found, &o_row, &o_peak, &o_status))
        return NULL;
    Views vs = {.n = 0};
    idx_t W, m, tshape[2];
    ColumnsPeaks *c1 = &in.first, *c2 = &in.second;
    ColumnsLine out;
    in.thr = arg(&vs, o_thr, 'd', -1, 0, 1, 0, "thr", &W);
    in.k = in.thr ? arg(&vs, o_k, 'i', 2 * W, 0, 1, 0, "k", NULL) : NULL;
    in.s = in.k ? arg(&vs, o_s, 'd', 2 * W, 0, 1, 0, "s", NULL) : NULL;
    in.noise = in.s ? arg(&vs, o_noise, 'd', W, 0, 1, 0, "noise", NULL) : NULL;
    c1->row = in.noise ? arg(&vs, o_r1, 'd', W, 0, 1, 0, "row1", NULL) : NULL;
    c1->peak = c1->row ? arg(&vs, o_p1, 'd', W, 0, 1, 0, "peak1", NULL) : NULL;
    c1->valid = c1->peak ? arg(&vs, o_v1, 'b', W, 0, 1, 0, "valid1", NULL) : NULL;
    c1->spread = c1->valid ? arg(&vs, o_sp1, 'd', W, 0, 1, 0, "spread1", NULL) : NULL;
    in.idx = c1->spread ? arg(&vs, o_idx, 'i', -1, 0, 1, 0, "idx2", &m) : NULL;
    c2->row = in.idx ? arg(&vs, o_r2, 'd', m, 0, 1, 0, "row2", NULL) : NULL;
    c2->peak = c2->row ? arg(&vs, o_p2, 'd', m, 0, 1, 0, "peak2", NULL) : NULL;
    c2->valid = c2->peak ? arg(&vs, o_v2, 'b', m, 0, 1, 0, "valid2", NULL) : NULL;
    c2->spread = c2->valid ? arg(&vs, o_sp2, 'd', m, 0, 1, 0, "spread2", NULL) : NULL;
    in.inv_depth.v = c2->spread ? arg(&vs, o_tab, 'd', -1, W, 2, 0, "inv_depth", tshape) : NULL;
    out.found = in.inv_depth.v ? arg(&vs, o_found, 'b', W, 0, 1, 1, "found", NULL) : NULL;
    out.row = out.found ? arg(&vs, o_row, 'd', W, 0, 1, 1, "row", NULL) : NULL;
    out.peak = out.row ? arg(&vs, o_peak, 'd', W, 0, 1, 1, "peak", NULL) : NULL;
    out.status = out.peak ? arg(&vs, o_status, 'u', W, 0, 1, 1, "status", NULL) : NULL;
    if (!out.status) return failed(&vs);
    c1->argmax = c2->argmax = NULL, c1->plateau = c2->plateau = NULL; /* not used by resolve */
    in.cols = W, in.m = m, in.inv_depth.rows = tshape[0], in.inv_depth.cols = tshape[1];
    ColumnsError err;
    ColumnsResult r;
    Py_BEGIN_ALLOW_THREADS
    r = columns_resolve(&in, &p, &out, &err);
    Py_END_ALLOW_THREADS
    return done(&vs, r, &err, r == COLUMNS_DONE ? Py_BuildValue("nn", out.seen_first, out.seen_last) : NULL);
}

/* triangulate(rows, cols, xn, yn, top, (nx, ny, nz, distance), (min_m, max_m, eps), codes,
 *             points, depth, status): columns_triangulate; codes: the RangeStatus values (ok,
 * invalid_pixel, beyond_horizon, too_close, too_far). */
static PyObject *py_triangulate(PyObject *self, PyObject *args)
{
    PyObject *o_rows, *o_cols, *o_xn, *o_yn, *o_pts, *o_depth, *o_status;
    ColumnsRays rays;
    ColumnsPlane pl;
    if (!PyArg_ParseTuple(args, "OOOOn(dddd)(ddd)(iiiii)OOO", &o_rows, &o_cols, &o_xn, &o_yn, &rays.top, &pl.nx, &pl.ny,
                          &pl.nz, &pl.distance, &pl.min_m, &pl.max_m, &pl.horizon_eps, &pl.ok, &pl.invalid_pixel,
                          &pl.beyond_horizon, &pl.too_close, &pl.too_far, &o_pts, &o_depth, &o_status))
        return NULL;
    Views vs = {.n = 0};
    idx_t N, tab[2];
    const double *rows = arg(&vs, o_rows, 'd', -1, 0, 1, 0, "rows", &N);
    const idx_t *cols = rows ? arg(&vs, o_cols, 'i', N, 0, 1, 0, "columns", NULL) : NULL;
    rays.xn = cols ? arg(&vs, o_xn, 'd', -1, -1, 2, 0, "xn", tab) : NULL;
    rays.yn = rays.xn ? arg(&vs, o_yn, 'd', tab[0], tab[1], 2, 0, "yn", NULL) : NULL;
    double *pts = rays.yn ? arg(&vs, o_pts, 'd', N, 3, 2, 1, "points", NULL) : NULL;
    double *depth = pts ? arg(&vs, o_depth, 'd', N, 0, 1, 1, "depth", NULL) : NULL;
    uint8_t *status = depth ? arg(&vs, o_status, 'u', N, 0, 1, 1, "status", NULL) : NULL;
    if (!status) return failed(&vs);
    rays.rows = tab[0], rays.cols = tab[1];
    ColumnsError err;
    ColumnsResult r = columns_triangulate(&rays, &pl, N, rows, cols, pts, depth, status, &err);
    return done(&vs, r, &err, NULL);
}

/* scan_plane(points, rotation, origin, angle, range): columns_scan_plane. */
static PyObject *py_scan_plane(PyObject *self, PyObject *args)
{
    PyObject *o_p, *o_r, *o_o, *o_a, *o_rng;
    if (!PyArg_ParseTuple(args, "OOOOO", &o_p, &o_r, &o_o, &o_a, &o_rng)) return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const double *pts = arg(&vs, o_p, 'd', -1, 3, 2, 0, "points", shp);
    const double *rot = pts ? arg(&vs, o_r, 'd', 3, 3, 2, 0, "rotation", NULL) : NULL;
    const double *org = rot ? arg(&vs, o_o, 'd', 3, 0, 1, 0, "origin", NULL) : NULL;
    double *ang = org ? arg(&vs, o_a, 'd', shp[0], 0, 1, 1, "angle", NULL) : NULL;
    double *rng = ang ? arg(&vs, o_rng, 'd', shp[0], 0, 1, 1, "range", NULL) : NULL;
    if (!rng) return failed(&vs);
    columns_scan_plane(shp[0], pts, rot, org, ang, rng);
    return done(&vs, COLUMNS_DONE, NULL, NULL);
}

/* scan_rays(angle, range, quality, row, grid, gap_spacings, max_jump_ratio, range_out, quality_out,
 *           row_out): columns_scan_rays. */
static PyObject *py_scan_rays(PyObject *self, PyObject *args)
{
    PyObject *o_a, *o_r, *o_q, *o_row, *o_grid, *o_rout, *o_qout, *o_rowout;
    double gap_spacings, ratio;
    if (!PyArg_ParseTuple(args, "OOOOOddOOO", &o_a, &o_r, &o_q, &o_row, &o_grid, &gap_spacings, &ratio, &o_rout,
                          &o_qout, &o_rowout))
        return NULL;
    Views vs = {.n = 0};
    idx_t N, M;
    const double *a = arg(&vs, o_a, 'd', -1, 0, 1, 0, "angle", &N);
    const double *r = a ? arg(&vs, o_r, 'd', N, 0, 1, 0, "range", NULL) : NULL;
    const double *q = r ? arg(&vs, o_q, 'd', N, 0, 1, 0, "quality", NULL) : NULL;
    const double *row = q ? arg(&vs, o_row, 'd', N, 0, 1, 0, "row", NULL) : NULL;
    const double *grid = row ? arg(&vs, o_grid, 'd', -1, 0, 1, 0, "grid", &M) : NULL;
    double *rout = grid ? arg(&vs, o_rout, 'd', M, 0, 1, 1, "range_out", NULL) : NULL;
    uint8_t *qout = rout ? arg(&vs, o_qout, 'u', M, 0, 1, 1, "quality_out", NULL) : NULL;
    double *rowout = qout ? arg(&vs, o_rowout, 'd', M, 0, 1, 1, "row_out", NULL) : NULL;
    if (!rowout) return failed(&vs);
    ColumnsError err;
    ColumnsResult res = columns_scan_rays(N, a, r, q, row, M, grid, gap_spacings, ratio, rout, qout, rowout, &err);
    return done(&vs, res, &err, NULL);
}

/* scan_timing(times_ns, fallback_ns) -> (first_ns, interval_ns, residual_ns): columns_scan_timing. */
static PyObject *py_scan_timing(PyObject *self, PyObject *args)
{
    PyObject *o_t;
    double fallback;
    if (!PyArg_ParseTuple(args, "Od", &o_t, &fallback)) return NULL;
    Views vs = {.n = 0};
    idx_t N;
    const double *t = arg(&vs, o_t, 'd', -1, 0, 1, 0, "times_ns", &N);
    if (!t) return failed(&vs);
    ColumnsError err;
    ColumnsScanTiming out;
    ColumnsResult res = columns_scan_timing(N, t, fallback, &out, &err);
    if (res != COLUMNS_DONE) return done(&vs, res, &err, NULL);
    release(&vs);
    return Py_BuildValue("(LLd)", (long long)out.first_ns, (long long)out.interval_ns, out.residual_ns);
}

static PyMethodDef methods[] = {
    {"candidates", py_candidates, METH_VARARGS, "candidates(sm, padded, pad, sep, k_out, s_out)"},
    {"refine_com", py_refine_com, METH_VARARGS,
     "refine_com(padded, pad, k, cols, lo, hi, half_width, row, peak, argmax, valid, plateau, spread)"},
    {"resolve", py_resolve, METH_VARARGS,
     "resolve((k, s), thr, noise, (row1, peak1, valid1, spread1), (idx2, row2, peak2, valid2, spread2), "
     "(inv_depth, inv_depth_top), (top, t0, t1), params, (found, row, peak, status)) -> (seen_first, seen_last)"},
    {"running_median", py_running_median, METH_VARARGS, "running_median(x, found, out)"},
    {"noise_level", py_noise_level, METH_VARARGS, "noise_level(lit, unlit, out)"},
    {"moved", py_moved, METH_VARARGS, "moved(a, b, unlit, (level, block_level, block_ratio, mean_ratio), out)"},
    {"band_difference", py_band_difference, METH_VARARGS, "band_difference(lit, unlit, mask, padded, pad, sm, sat_min)"},
    {"run_length", py_run_length, METH_VARARGS, "run_length(mask, out)"},
    {"spans", py_spans, METH_VARARGS, "spans(mask, join, out) -> count"},
    {"near_rows", py_near_rows, METH_VARARGS, "near_rows(lit, unlit, mask, (r0, r1, step), (c0, c1), above, below, pair)"},
    {"triangulate", py_triangulate, METH_VARARGS, "triangulate(rows, cols, xn, yn, top, plane, limits, codes, points, depth, status)"},
    {"scan_plane", py_scan_plane, METH_VARARGS, "scan_plane(points, rotation, origin, angle, range)"},
    {"scan_rays", py_scan_rays, METH_VARARGS,
     "scan_rays(angle, range, quality, row, grid, gap_spacings, max_jump_ratio, range_out, quality_out, row_out)"},
    {"scan_timing", py_scan_timing, METH_VARARGS, "scan_timing(times_ns, fallback_ns) -> (first_ns, interval_ns, residual_ns)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "_columns",
    .m_doc = "The fast pipeline's image passes and per-column steps, and the table triangulation "
             "(device/vision/columns/columns.h).",
    .m_size = -1,
    .m_methods = methods,
};

PyMODINIT_FUNC PyInit__columns(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m && (PyModule_AddIntConstant(m, "STATUS_OK", COLUMNS_OK) < 0
              || PyModule_AddIntConstant(m, "STATUS_NO_RETURN", COLUMNS_NO_RETURN) < 0
              || PyModule_AddIntConstant(m, "STATUS_UNLIT", COLUMNS_UNLIT) < 0
              || PyModule_AddIntConstant(m, "STATUS_REJECTED", COLUMNS_REJECTED) < 0
              || PyModule_AddIntConstant(m, "BLOCK_ROWS", COLUMNS_BLOCK_ROWS) < 0)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
