/* The fast pipeline's image passes and per-column steps, and the table triangulation, one
 * compiled loop each (device/vision/fast.py, device/vision/geometry.py; issue 7).
 *
 * Why C: every per-column step is a short loop over the ~1664 columns of a frame (a few rows
 * per column). Written with numpy, each step was a dozen whole-array calls of 2-3 us of overhead
 * for under 1 us of arithmetic: ~230 calls per frame pair, three quarters of the fast pipeline's
 * time. OpenCV has no per-column line finder, and numba/Cython are not among the project's
 * dependencies; this file needs only a C compiler and the Python headers (the buffer protocol,
 * no numpy headers). The image passes replace sequences of OpenCV calls with one or two passes
 * that compute the same bytes (tests/test_vision_kernel.py compares them). It is the only
 * implementation: the numpy formulation it replaced is in the history (commit 95851ef).
 *
 * Floating-point arithmetic is IEEE double in the same order as that formulation (built with
 * -ffp-contract=off, so no fused multiply-adds change the rounding on ARM), and the moments of
 * 8-bit samples are exact integers: every pipeline's output was identical to it, bit for bit, on
 * 14 simulated scenes when porting (BENCHMARKS.md "Pipeline").
 *
 * Entry points (each checks its arguments' dtype, contiguity and shape with get_array, and its
 * sizes, and raises ValueError naming the argument):
 *   candidates(sm, padded, pad, sep, k_out, s_out)
 *   refine_com(padded, pad, k, cols, lo, hi, half_width, row, peak, argmax, valid, plateau, spread)
 *   resolve(...) -> (seen_first, seen_last)
 *   running_median(x, found, out)
 *   noise_level(lit, unlit, out)
 *   band_difference(lit, unlit, mask, padded, pad, sm, sat_min)
 *   run_length(mask, out)
 *   triangulate(rows, cols, xn, yn, top, plane, limits, codes, points, depth, status)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define BLOCK_ROWS 16
#define PLATEAU_STEP 8
/* The image-wide loops get an AVX2 clone on x86-64 (picked at load time; SSE2 otherwise): they
 * are integer loops, so the clones give identical results. NEON is ARM64's baseline. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__) /* ifunc */
#define PIXEL_LOOP __attribute__((target_clones("avx2", "default")))
#else
#define PIXEL_LOOP
#endif
#define MIN(a, b) ((a) < (b) ? (a) : (b))
#define MAX(a, b) ((a) > (b) ? (a) : (b))

typedef Py_ssize_t idx_t;

/* device.vision.measurements.ColumnStatus values written by resolve (exported as STATUS_*, tested equal) */
enum { OK = 0, NO_RETURN = 1, UNLIT = 6, REJECTED = 7 };

/* ------------------------------------------------------------------ argument checking */

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

/* ------------------------------------------------------------------ candidates */

/* The keys value << 4 | (15 - row in block) of one block of sm (16 rows, fewer if it is the
 * band's last): the largest is the block's maximum and the first row holding it. */
PIXEL_LOOP static void block_keys(const uint8_t *restrict rows, idx_t nrows, idx_t W, uint16_t *restrict key)
{
    memset(key, 0, (size_t)W * sizeof(uint16_t));
    for (idx_t r = 0; r < nrows; r++) {
        const uint8_t *line = rows + r * W;
        uint16_t low = (uint16_t)(BLOCK_ROWS - 1 - r);
        for (idx_t c = 0; c < W; c++) {
            uint16_t v = (uint16_t)((line[c] << 4) | low);
            key[c] = v > key[c] ? v : key[c];
        }
    }
}

/* best = max(best, block b's keys as value << 16 | (0xFFFF - row)), leaving out the columns whose
 * lo_block or hi_block is b (when given) */
PIXEL_LOOP static void best_over_blocks(const uint16_t *restrict key, idx_t b, const idx_t *restrict lo_block,
                                        const idx_t *restrict hi_block, idx_t W, uint32_t *restrict best)
{
    uint32_t base = 0xFFFFu - (uint32_t)(b * BLOCK_ROWS + BLOCK_ROWS - 1);
    for (idx_t c = 0; c < W; c++) {
        uint32_t g = ((uint32_t)(key[c] >> 4) << 16) | (base + (key[c] & 15u));
        if (lo_block) g = (b == lo_block[c] || b == hi_block[c]) ? 0 : g;
        best[c] = g > best[c] ? g : best[c];
    }
}

/* Rows of the largest and of the second, separated, peak per column of the smoothed difference
 * sm (n, W), n a whole number of 16-row blocks: see FastPipeline._candidates. Block maxima as
 * keys value << 4 | (15 - row in block): one unsigned max per block gives the block's maximum
 * and its first row (a loop along rows over all columns, which the compiler vectorises). */
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
    const uint8_t *P = arg(&vs, o_pad, 'u', n + 2 * pad, W, 2, 0, "padded", NULL);
    idx_t *k = P ? arg(&vs, o_k, 'i', 2 * W, 0, 1, 1, "k", NULL) : NULL;
    double *s = k ? arg(&vs, o_s, 'd', 2 * W, 0, 1, 1, "s", NULL) : NULL;
    if (!s) goto fail;
    if (n < 1 || n > 0xFFFF || pad < 1 || sep < 0 || 2 * sep + 1 > BLOCK_ROWS) {
        PyErr_Format(PyExc_ValueError, "candidates: need 1 to 65535 rows (got %zd), pad >= 1 (got %zd), sep >= 0 and "
                     "2 sep + 1 <= 16 (sep %zd)", n, pad, sep);
        goto fail;
    }
    idx_t nb = (n + BLOCK_ROWS - 1) / BLOCK_ROWS; /* the last block may be partial (a band cut by the image) */
    uint16_t *bk = PyMem_Malloc((size_t)(nb * W) * sizeof(uint16_t));
    uint32_t *best = PyMem_Malloc((size_t)(2 * W) * sizeof(uint32_t)), *best2 = best ? best + W : NULL;
    idx_t *lo_block = PyMem_Malloc((size_t)(2 * W) * sizeof(idx_t)), *hi_block = lo_block ? lo_block + W : NULL;
    if (!bk || !best || !lo_block) {
        PyMem_Free(bk), PyMem_Free(best), PyMem_Free(lo_block);
        PyErr_NoMemory();
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    /* every loop over all columns at once, without branches (the compiler vectorises them) */
    for (idx_t b = 0; b < nb; b++)
        block_keys(sm + b * BLOCK_ROWS * W, MIN(BLOCK_ROWS, n - b * BLOCK_ROWS), W, bk + b * W);
    /* over blocks as keys value << 16 | (0xFFFF - row): the largest value, then the first row */
    memset(best, 0, (size_t)(2 * W) * sizeof(uint32_t));
    for (idx_t b = 0; b < nb; b++) best_over_blocks(bk + b * W, b, NULL, NULL, W, best);
    /* the second: the same outside the (at most two) blocks within sep rows of the first */
    for (idx_t c = 0; c < W; c++) {
        idx_t k1 = 0xFFFF - (idx_t)(best[c] & 0xFFFFu);
        k[c] = k1;
        lo_block[c] = k1 - sep < 0 ? 0 : (k1 - sep) / BLOCK_ROWS;
        hi_block[c] = (k1 + sep) / BLOCK_ROWS < nb - 1 ? (k1 + sep) / BLOCK_ROWS : nb - 1;
    }
    for (idx_t b = 0; b < nb; b++) best_over_blocks(bk + b * W, b, lo_block, hi_block, W, best2);
    for (idx_t c = 0; c < W; c++) {
        idx_t k1 = k[c], k2 = 0xFFFF - (idx_t)(best2[c] & 0xFFFFu);
        int none = 0; /* no second candidate at all: k2 is a row of zeros, s2 = 0 */
        if (best2[c] <= 0xFFFFu) { /* nothing but zeros in the other blocks */
            k2 = 0;
            if (lo_block[c] == 0) { /* the first block's rows more than sep from the first */
                int m = 0;
                none = 1;
                for (idx_t r = 0; r < MIN(BLOCK_ROWS, n); r++) {
                    if (r - k1 <= sep && k1 - r <= sep) continue;
                    if (sm[r * W + c] > m) m = sm[r * W + c], k2 = r, none = 0;
                }
            }
        }
        /* each moved to the largest of the unsmoothed difference at k-1, k, k+1 (first of equals) */
        idx_t kk[2] = {k1, k2};
        if (none) k[W + c] = k2, s[W + c] = 0.0;
        for (int j = 0; j < 2 - none; j++) {
            idx_t at = (kk[j] + pad) * W + c;
            uint8_t vm = P[at - W], v0 = P[at], vp = P[at + W];
            idx_t r = (vm >= v0 && vm >= vp) ? kk[j] - 1 : (v0 >= vp ? kk[j] : kk[j] + 1);
            r = r < 0 ? 0 : r;
            k[j * W + c] = r;
            s[j * W + c] = r < n ? (double)sm[r * W + c] : 0.0; /* defensive: r == n is a pad row, never larger */
        }
    }
    Py_END_ALLOW_THREADS
    PyMem_Free(bk), PyMem_Free(best), PyMem_Free(lo_block);
    release(&vs);
    Py_RETURN_NONE;
fail:
    release(&vs);
    return NULL;
}

/* ------------------------------------------------------------------ noise level */

/* OpenCV's default border (BORDER_REFLECT_101): index -1 is 1, n is n - 2 */
static inline idx_t reflect101(idx_t i, idx_t n)
{
    if (n == 1) return 0;
    i = i < 0 ? -i : i;
    return i >= n ? 2 * (n - 1) - i : i;
}

/* Sums of the 5-column x 3-row box of every column of one row from its three lines (the rows
 * above, at and below it), borders reflected as OpenCV's default: v gets the vertical sums. */
PIXEL_LOOP static void box_sums(const uint8_t *restrict l0, const uint8_t *restrict l1, const uint8_t *restrict l2,
                                idx_t W, uint16_t *restrict v, uint16_t *restrict h)
{
    for (idx_t c = 0; c < W; c++) v[c] = (uint16_t)(l0[c] + l1[c] + l2[c]);
    for (idx_t c = 2; c < W - 2; c++) h[c] = (uint16_t)(v[c - 2] + v[c - 1] + v[c] + v[c + 1] + v[c + 2]);
    for (idx_t c = 0; c < W; c++) {
        if (c == 2 && W > 4) c = W - 2; /* the two columns at each edge */
        uint16_t sum = 0;
        for (idx_t j = c - 2; j <= c + 2; j++) sum = (uint16_t)(sum + v[reflect101(j, W)]);
        h[c] = sum;
    }
}

/* d = max(x - y, 0) of one row; returns the row's largest x */
PIXEL_LOOP static uint8_t difference_row(const uint8_t *restrict x, const uint8_t *restrict y, idx_t W,
                                         uint8_t *restrict d)
{
    uint8_t top = 0;
    for (idx_t c = 0; c < W; c++) {
        d[c] = x[c] > y[c] ? (uint8_t)(x[c] - y[c]) : 0;
        top = x[c] > top ? x[c] : top;
    }
    return top;
}

PIXEL_LOOP static void max_row(uint16_t *restrict best, const uint16_t *restrict h, idx_t W)
{
    for (idx_t c = 0; c < W; c++) best[c] = h[c] > best[c] ? h[c] : best[c];
}

/* cv2.blur(x, (5, 3)) of 8-bit x is the box sum / 15 rounded; never half-way, so (sum + 7) / 15,
 * here as a 16-bit multiply-high: x * 4370 / 2^16 exceeds x / 15 by under 0.06 for x <= 15 * 255 + 7,
 * less than the distance of x / 15 to the next integer (>= 1/15) */
static inline uint8_t box_mean(uint16_t sum) { return (uint8_t)(((uint32_t)(uint16_t)(sum + 7) * 4370u) >> 16); }

PIXEL_LOOP static void mean_row(const uint16_t *restrict h, idx_t W, uint8_t *restrict out)
{
    for (idx_t c = 0; c < W; c++) out[c] = box_mean(h[c]);
}

/* 255 on the pixels of row `at` that are saturated in the lit frame, brightened by >= sat_min
 * (d = 255 - unlit), and have such a pixel above or below them (rows `up`/`down`, NULL at the
 * band's edges): a saturated line's flat top */
PIXEL_LOOP static void saturated_pairs_row(const uint8_t *restrict a, const uint8_t *restrict b,
                                           const uint8_t *a_up, const uint8_t *b_up, const uint8_t *a_down,
                                           const uint8_t *b_down, idx_t W, uint8_t lim, uint8_t *restrict d)
{
    for (idx_t c = 0; c < W; c++) {
        uint8_t self = (a[c] == 255) & (b[c] <= lim);
        uint8_t up = a_up ? (a_up[c] == 255) & (b_up[c] <= lim) : 0;
        uint8_t down = a_down ? (a_down[c] == 255) & (b_down[c] <= lim) : 0;
        d[c] |= (uint8_t)(0u - (unsigned)(self & (up | down)));
    }
}

PIXEL_LOOP static void and_rows(uint8_t *restrict d, const uint8_t *restrict mask, idx_t n)
{
    for (idx_t i = 0; i < n; i++) d[i] &= mask[i];
}

/* noise_level(lit, unlit, out): per column, the largest 5-column x 3-row box mean of the
 * negative difference max(unlit - lit, 0) over the rows of the band: exactly
 * `cv2.blur(cv2.subtract(unlit, lit), (5, 3)).max(axis=0)`, in one pass without the two
 * intermediate images. */
static PyObject *py_noise_level(PyObject *self, PyObject *args)
{
    PyObject *o_a, *o_b, *o_out;
    if (!PyArg_ParseTuple(args, "OOO", &o_a, &o_b, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t shp[2];
    const uint8_t *A = arg(&vs, o_a, 'u', -1, -1, 2, 0, "lit", shp);
    const uint8_t *B = A ? arg(&vs, o_b, 'u', shp[0], shp[1], 2, 0, "unlit", NULL) : NULL;
    double *out = B ? arg(&vs, o_out, 'd', shp[1], 0, 1, 1, "out", NULL) : NULL;
    if (!out) goto fail;
    idx_t n = shp[0], W = shp[1];
    if (n < 1 || W < 3) {
        PyErr_Format(PyExc_ValueError, "noise_level: need >= 1 row and >= 3 columns, got %zd rows x %zd columns", n, W);
        goto fail;
    }
    uint8_t *neg = PyMem_Malloc((size_t)(3 * W)); /* the negative difference of rows r-1, r, r+1 */
    uint16_t *v = PyMem_Malloc((size_t)(3 * W) * sizeof(uint16_t)), *h = v ? v + W : NULL, *best = v ? v + 2 * W : NULL;
    if (!neg || !v) {
        PyMem_Free(neg), PyMem_Free(v);
        PyErr_NoMemory();
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    memset(best, 0, (size_t)W * sizeof(uint16_t));
    idx_t held[3] = {-1, -1, -1}; /* image row held in each slot of neg */
    for (idx_t r = 0; r < n; r++) {
        const uint8_t *line[3];
        for (int j = 0; j < 3; j++) {
            idx_t src = reflect101(r - 1 + j, n), slot = src % 3;
            if (held[slot] != src) {
                difference_row(B + src * W, A + src * W, W, neg + slot * W);
                held[slot] = src;
            }
            line[j] = neg + slot * W;
        }
        box_sums(line[0], line[1], line[2], W, v, h);
        max_row(best, h, W);
    }
    for (idx_t c = 0; c < W; c++) out[c] = (double)box_mean(best[c]);
    Py_END_ALLOW_THREADS
    PyMem_Free(neg), PyMem_Free(v);
    release(&vs);
    Py_RETURN_NONE;
fail:
    release(&vs);
    return NULL;
}

/* band_difference(lit, unlit, mask, padded, pad, sm): the band's difference image and its
 * detection copy, in two passes instead of OpenCV's six:
 *   d = max(lit - unlit, 0), except 255 on both pixels of a vertical pair that are saturated in
 *       the lit frame and brightened by >= SATURATED_LINE_MIN (a saturated line: a flat top),
 *       then d &= mask (the region of interest), stored in padded[pad : pad + n];
 *   sm = cv2.blur(d, (5, 3)) (exactly: borders reflected, rounding as OpenCV's).
 */
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
    if (!S) goto fail;
    if (n < 1 || W < 3 || pad < 0 || sat_min < 0 || sat_min > 255) {
        PyErr_Format(PyExc_ValueError, "band_difference: need >= 1 row, >= 3 columns, pad >= 0 and 0 <= sat_min <= 255, "
                     "got %zd rows x %zd columns, pad %zd, sat_min %zd", n, W, pad, sat_min);
        goto fail;
    }
    char *full = PyMem_Malloc((size_t)n); /* the lit row holds a saturated pixel */
    uint16_t *v = PyMem_Malloc((size_t)(2 * W) * sizeof(uint16_t)), *h = v ? v + W : NULL;
    if (!full || !v) {
        PyMem_Free(full), PyMem_Free(v);
        PyErr_NoMemory();
        goto fail;
    }
    int any_full = 0;
    Py_BEGIN_ALLOW_THREADS
    uint8_t *D = P + pad * W;
    for (idx_t r = 0; r < n; r++) {
        full[r] = difference_row(A + r * W, B + r * W, W, D + r * W) == 255;
        any_full |= full[r];
    }
    /* saturated pairs, before the mask: only rows next to another row with a saturated pixel */
    uint8_t lim = (uint8_t)(255 - sat_min);
    for (idx_t r = 0; any_full && r < n; r++) {
        int up = r > 0 && full[r - 1], down = r + 1 < n && full[r + 1];
        if (full[r] && (up || down))
            saturated_pairs_row(A + r * W, B + r * W, up ? A + (r - 1) * W : NULL, up ? B + (r - 1) * W : NULL,
                                down ? A + (r + 1) * W : NULL, down ? B + (r + 1) * W : NULL, W, lim, D + r * W);
    }
    and_rows(D, M, n * W);
    for (idx_t r = 0; r < n; r++) {
        box_sums(D + reflect101(r - 1, n) * W, D + r * W, D + reflect101(r + 1, n) * W, W, v, h);
        mean_row(h, W, S + r * W);
    }
    Py_END_ALLOW_THREADS
    PyMem_Free(full), PyMem_Free(v);
    release(&vs);
    Py_RETURN_NONE;
fail:
    release(&vs);
    return NULL;
}

/* run_length(mask, out): the length of the run of consecutive True elements each element
 * belongs to (0 where False). */
static PyObject *py_run_length(PyObject *self, PyObject *args)
{
    PyObject *o_m, *o_out;
    if (!PyArg_ParseTuple(args, "OO", &o_m, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t W;
    const char *m = arg(&vs, o_m, 'b', -1, 0, 1, 0, "mask", &W);
    idx_t *out = m ? arg(&vs, o_out, 'i', W, 0, 1, 1, "out", NULL) : NULL;
    if (out) {
        for (idx_t a = 0; a < W;) {
            idx_t b = a;
            while (b < W && m[b]) b++;
            for (idx_t i = a; i < b; i++) out[i] = b - a;
            if (b == a) out[a] = 0, b++;
            a = b;
        }
    }
    release(&vs);
    if (!out) return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ centre of mass */

/* numpy's maximum(x, 0) (NaN propagates), then the square root */
static inline double sqrt_pos(double x) { return sqrt((x >= 0.0 || isnan(x)) ? x : 0.0); }

/* Centre of mass over a flat top at 255 (the plateau's middle +- half its length + half). */
static void plateau_centre(const uint8_t *P, idx_t W, idx_t last, idx_t pad, idx_t k, idx_t lo, idx_t hi, idx_t c,
                           idx_t half, double *row, int *ok)
{
    idx_t end = k;
    for (;;) { /* walk to the plateau's end, PLATEAU_STEP rows at a time (as the numpy version) */
        idx_t lead = 0;
        while (lead < PLATEAU_STEP) {
            idx_t r = end + lead + 1 + pad;
            if (r >= last || P[r * W + c] != 255) break; /* the last row is a zero pad row: the same end */
            lead++;
        }
        end += lead;
        if (lead < PLATEAU_STEP) break;
    }
    idx_t mid = (k + end) / 2, span = (end - k) / 2 + half;
    double s = 0.0, s1 = 0.0;
    for (idx_t o = -span; o <= span; o++) {
        idx_t r = mid + o + pad;
        r = r < 0 ? 0 : (r > last ? last : r);
        double v = P[r * W + c];
        s += v;
        s1 += v * (double)o;
    }
    int cut = (mid - span < lo && P[(lo + pad) * W + c] > 0) || (mid + span >= hi && P[(hi - 1 + pad) * W + c] > 0);
    *row = (double)mid + s1 / s;
    *ok = s > 0 && !cut;
}

/* device.vision.peaks.refine_com_padded: the centre of mass of k +- half_width in the columns
 * `cols` of the zero-padded difference, with the refine_peaks conventions (see its docstring). */
static PyObject *py_refine_com(PyObject *self, PyObject *args)
{
    PyObject *o_pad, *o_k, *o_cols, *o_lo, *o_hi, *o_row, *o_peak, *o_arg, *o_valid, *o_plat, *o_spread;
    idx_t pad, half;
    if (!PyArg_ParseTuple(args, "OnOOOOnOOOOOO", &o_pad, &pad, &o_k, &o_cols, &o_lo, &o_hi, &half, &o_row, &o_peak,
                          &o_arg, &o_valid, &o_plat, &o_spread))
        return NULL;
    Views vs = {.n = 0};
    idx_t shp[2], m;
    const uint8_t *P = arg(&vs, o_pad, 'u', -1, -1, 2, 0, "padded", shp);
    const idx_t *kin = P ? arg(&vs, o_k, 'i', -1, 0, 1, 0, "argmax", &m) : NULL;
    const idx_t *cols = kin ? arg(&vs, o_cols, 'i', m, 0, 1, 0, "cols", NULL) : NULL;
    const idx_t *lo = cols ? arg(&vs, o_lo, 'i', m, 0, 1, 0, "row_lo", NULL) : NULL;
    const idx_t *hi = lo ? arg(&vs, o_hi, 'i', m, 0, 1, 0, "row_hi", NULL) : NULL;
    double *row = hi ? arg(&vs, o_row, 'd', m, 0, 1, 1, "row", NULL) : NULL;
    double *peak = row ? arg(&vs, o_peak, 'd', m, 0, 1, 1, "peak", NULL) : NULL;
    idx_t *argmax = peak ? arg(&vs, o_arg, 'i', m, 0, 1, 1, "argmax_out", NULL) : NULL;
    char *valid = argmax ? arg(&vs, o_valid, 'b', m, 0, 1, 1, "valid", NULL) : NULL;
    char *plateau = valid ? arg(&vs, o_plat, 'b', m, 0, 1, 1, "plateau", NULL) : NULL;
    double *spread = plateau ? arg(&vs, o_spread, 'd', m, 0, 1, 1, "spread", NULL) : NULL;
    if (!spread) goto fail;
    idx_t H = shp[0] - 2 * pad, W = shp[1];
    if (half < 1 || pad < half || pad < 2 || H < 1) {
        PyErr_Format(PyExc_ValueError, "refine_com: need half_width >= 1 and pad >= max(half_width, 2) zero rows "
                     "around an image of >= 1 row, got half_width %zd, pad %zd, %zd padded rows", half, pad, shp[0]);
        goto fail;
    }
    for (idx_t j = 0; j < m; j++) {
        if (cols[j] < 0 || cols[j] >= W || lo[j] < 0 || hi[j] > H) {
            PyErr_Format(PyExc_ValueError, "refine_com: column %zd (rows [%zd, %zd)) outside the %zdx%zd image",
                         cols[j], lo[j], hi[j], W, H);
            goto fail;
        }
    }
    idx_t last = shp[0] - 1;
    for (idx_t j = 0; j < m; j++) {
        idx_t c = cols[j], k = kin[j];
        int empty = hi[j] <= lo[j] || k < lo[j] || k >= hi[j];
        idx_t kk = empty ? 0 : k;
        const uint8_t *at = P + (kk + pad) * W + c;
        int64_t is = 0, is1 = 0, is2 = 0; /* exact: 8-bit samples, small offsets */
        for (idx_t o = -half; o <= half; o++) {
            int64_t v = at[o * W];
            is += v;
            is1 += v * o;
            is2 += v * o * o;
        }
        uint8_t f0 = at[0];
        /* an all-zero window (s == 0) gives NaN row and spread by 0 / 0, as refine_peaks */
        double s = empty ? NAN : (double)is, s1 = (double)is1, s2 = (double)is2;
        double delta = s1 / s;
        spread[j] = sqrt_pos(s2 / s - delta * delta);
        double r = (double)kk + delta;
        int ok = 1, val = f0 > 0 && !empty;
        if (val && (kk - half < lo[j] || kk + half >= hi[j])) /* cut by the interval while still lit */
            ok = !((kk - half < lo[j] && P[(lo[j] + pad) * W + c] > 0) || (kk + half >= hi[j] && P[(hi[j] - 1 + pad) * W + c] > 0));
        int plat = f0 == 255 && !empty && at[W] == 255 && at[2 * W] == 255;
        if (plat && val) plateau_centre(P, W, last, pad, k, lo[j], hi[j], c, half, &r, &ok);
        val = val && ok && isfinite(r);
        row[j] = val ? r : NAN;
        peak[j] = empty ? NAN : (double)f0;
        argmax[j] = empty ? -1 : k;
        valid[j] = (char)val;
        plateau[j] = (char)plat;
    }
    release(&vs);
    Py_RETURN_NONE;
fail:
    release(&vs);
    return NULL;
}

/* ------------------------------------------------------------------ per-column decisions */

/* Where a sub-pixel image row falls in a per-column table of n rows from image row `top` (W
 * columns): the flat indices of the two table rows around it in column c (i1 = i0 when n == 1)
 * and the weight t of the second. Returns 0 outside the table (also for NaN), with row 0. */
static inline int table_position(double row, idx_t top, idx_t n, idx_t W, idx_t c, idx_t *i0, idx_t *i1, double *t)
{
    double r = row - (double)top;
    int inside = r >= 0.0 && r <= (double)(n - 1);
    r = inside ? r : 0.0;
    idx_t r0 = (idx_t)r, cap = n - 2 > 0 ? n - 2 : 0;
    r0 = r0 < cap ? r0 : cap;
    *t = r - (double)r0;
    *i0 = r0 * W + c;
    *i1 = n > 1 ? *i0 + W : *i0;
    return inside;
}

typedef struct {
    const double *tab; /* (n, W) 1/z of each table row (device.vision.geometry.ColumnGeometry.inv_depth) */
    idx_t n, W, top;
} InvDepth;

/* ColumnGeometry.inverse_depth for one row of column c: (1/z, d(1/z)/d row), NaN outside the table */
static void inverse_depth(const InvDepth *g, double row, idx_t c, double *iz, double *slope)
{
    idx_t i0, i1;
    double t;
    if (!table_position(row, g->top, g->n, g->W, c, &i0, &i1, &t)) {
        *iz = *slope = NAN;
        return;
    }
    double a = g->tab[i0], b = g->tab[i1];
    *iz = a + (b - a) * t;
    *slope = b - a;
}

/* Median of the found values of x within +-2 of each element (NaN where not found): the middle
 * one, or the mean of the middle two. Found values must be finite (resolve's rows are). */
static void running_median(const double *x, const char *found, idx_t W, double *med)
{
    for (idx_t i = 0; i < W; i++) {
        if (!found[i]) {
            med[i] = NAN;
            continue;
        }
        if (i >= 2 && i + 2 < W && found[i - 2] && found[i - 1] && found[i + 1] && found[i + 2]) {
            /* all five: a selection network of min/max (exact, branch-free) */
            double a = x[i - 2], b = x[i - 1], e = x[i], c = x[i + 1], d = x[i + 2];
            double f = MAX(MIN(a, b), MIN(c, d)), g = MIN(MAX(a, b), MAX(c, d));
            med[i] = MAX(MIN(e, f), MIN(MAX(e, f), g));
            continue;
        }
        double w[5];
        int m = 0;
        for (idx_t j = i - 2; j <= i + 2; j++)
            if (j >= 0 && j < W && found[j]) w[m++] = x[j];
        for (int a = 1; a < m; a++) /* insertion sort: at most 5 values */
            for (int b = a; b > 0 && w[b - 1] > w[b]; b--) {
                double t = w[b];
                w[b] = w[b - 1], w[b - 1] = t;
            }
        med[i] = 0.5 * (w[(m - 1) / 2] + w[m / 2]);
    }
}

typedef struct {
    double dim_peak_fraction, own_peak_fraction, max_spread_px, jump_rel, jump_factor, min_peak;
    idx_t min_run, smooth_half, support_half, max_gap;
} Params;

/* FastPipeline's choice between two detected candidates (see FastPipeline's docstring, step 4):
 * the nearer candidate wins when it continues alone in at least half the neighbours (an
 * occlusion edge), else the farther one unless it is backed less than half as well. Rows r1, r2
 * in band coordinates (+ t0); returns 1 to take the second. */
static int choose_second(idx_t i, const double *r1, const double *r2, const char *det1, const char *det2, idx_t W,
                         idx_t h, const InvDepth *g, double top)
{
    double own[2] = {r1[i], r2[i]};
    int support[2] = {0, 0}, alone[2] = {0, 0};
    for (idx_t o = -h; o <= h; o++) {
        idx_t j = i + o;
        if (o == 0 || j < 0 || j >= W) continue;
        double tol = 1.0 + 0.5 * (double)(o < 0 ? -o : o);
        double n0 = det1[j] ? r1[j] : NAN, n1 = det2[j] ? r2[j] : NAN;
        int single = det1[j] != det2[j];
        for (int c = 0; c < 2; c++) {
            int agree = fabs(own[c] - n0) <= tol || fabs(own[c] - n1) <= tol;
            support[c] += agree;
            alone[c] += agree && single;
        }
    }
    double iz[2], slope;
    for (int c = 0; c < 2; c++) {
        inverse_depth(g, own[c] + top, i, &iz[c], &slope);
        if (isnan(iz[c])) iz[c] = INFINITY;
    }
    int far2 = iz[1] < iz[0];
    int near_alone = (far2 ? alone[0] : alone[1]) >= h;
    int take_far = far2 ? 2 * support[1] >= support[0] : 2 * support[0] >= support[1];
    return near_alone ? !far2 : (take_far ? far2 : !far2);
}

/* Weighted least-squares line through the rows within +-half columns of each column of a run
 * (FastPipeline step 5, device/vision/fast.py), evaluated at the column. Windowed sums by
 * differences of running sums, in the order of the numpy formulation it replaced. */
static void local_line_fit(double *row, const double *weight, const char *inrun, const idx_t *start, const idx_t *stop,
                           idx_t W, idx_t half, double *T /* (W + 1) * 5 */)
{
    memset(T, 0, 5 * sizeof(double));
    for (idx_t i = 0; i < W; i++) {
        double x = (double)i, w = weight[i], *p = T + 5 * i, *q = p + 5;
        q[0] = p[0] + 1.0 * w;
        q[1] = p[1] + x * w;
        q[2] = p[2] + (x * x) * w;
        q[3] = p[3] + row[i] * w;
        q[4] = p[4] + (x * row[i]) * w;
    }
    for (idx_t i = 0; i < W; i++) {
        if (!inrun[i]) continue;
        idx_t lo = i - half > start[i] ? i - half : start[i];
        idx_t hi = (i + half < stop[i] ? i + half : stop[i]) + 1;
        const double *a = T + 5 * lo, *b = T + 5 * hi;
        double x = (double)i;
        double s0 = b[0] - a[0], swx = b[1] - a[1], swxx = b[2] - a[2], swy = b[3] - a[3], swxy = b[4] - a[4];
        double sx = swx - x * s0;
        double sxx = swxx - 2.0 * x * swx + x * x * s0;
        double sy = swy;
        double sxy = swxy - x * sy;
        double det = s0 * sxx - sx * sx;
        if (s0 > 0) row[i] = det > 1e-9 ? (sxx * sy - sx * sxy) / det : sy / s0;
    }
}

/* Steps 3-5 of FastPipeline after the sub-pixel estimates: detection, the choice between two
 * candidates, continuity runs and outliers, the dim-column rule, the minimum run, the line fit,
 * gap filling and the statuses; see FastPipeline._search for the meaning of each rule. */
static PyObject *py_resolve(PyObject *self, PyObject *args)
{
    PyObject *o_k, *o_s, *o_thr, *o_noise, *o_r1, *o_p1, *o_v1, *o_sp1, *o_idx, *o_r2, *o_p2, *o_v2, *o_sp2, *o_tab;
    PyObject *o_found, *o_row, *o_peak, *o_status;
    idx_t tab_top, top, t0, t1;
    Params p;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOnnnn(ddddddnnnn)OOOO", &o_k, &o_s, &o_thr, &o_noise, &o_r1, &o_p1, &o_v1,
                          &o_sp1, &o_idx, &o_r2, &o_p2, &o_v2, &o_sp2, &o_tab, &tab_top, &top, &t0, &t1,
                          &p.dim_peak_fraction, &p.own_peak_fraction, &p.max_spread_px, &p.jump_rel, &p.jump_factor,
                          &p.min_peak, &p.min_run, &p.smooth_half, &p.support_half, &p.max_gap, &o_found, &o_row,
                          &o_peak, &o_status))
        return NULL;
    Views vs = {.n = 0};
    idx_t W, m, tshape[2];
    const double *thr = arg(&vs, o_thr, 'd', -1, 0, 1, 0, "thr", &W);
    const idx_t *k = thr ? arg(&vs, o_k, 'i', 2 * W, 0, 1, 0, "k", NULL) : NULL;
    const double *s = k ? arg(&vs, o_s, 'd', 2 * W, 0, 1, 0, "s", NULL) : NULL;
    const double *noise = s ? arg(&vs, o_noise, 'd', W, 0, 1, 0, "noise", NULL) : NULL;
    const double *c1row = noise ? arg(&vs, o_r1, 'd', W, 0, 1, 0, "row1", NULL) : NULL;
    const double *c1peak = c1row ? arg(&vs, o_p1, 'd', W, 0, 1, 0, "peak1", NULL) : NULL;
    const char *c1valid = c1peak ? arg(&vs, o_v1, 'b', W, 0, 1, 0, "valid1", NULL) : NULL;
    const double *c1spread = c1valid ? arg(&vs, o_sp1, 'd', W, 0, 1, 0, "spread1", NULL) : NULL;
    const idx_t *idx = c1spread ? arg(&vs, o_idx, 'i', -1, 0, 1, 0, "idx2", &m) : NULL;
    const double *c2row = idx ? arg(&vs, o_r2, 'd', m, 0, 1, 0, "row2", NULL) : NULL;
    const double *c2peak = c2row ? arg(&vs, o_p2, 'd', m, 0, 1, 0, "peak2", NULL) : NULL;
    const char *c2valid = c2peak ? arg(&vs, o_v2, 'b', m, 0, 1, 0, "valid2", NULL) : NULL;
    const double *c2spread = c2valid ? arg(&vs, o_sp2, 'd', m, 0, 1, 0, "spread2", NULL) : NULL;
    const double *tab = c2spread ? arg(&vs, o_tab, 'd', -1, W, 2, 0, "inv_depth", tshape) : NULL;
    char *found = tab ? arg(&vs, o_found, 'b', W, 0, 1, 1, "found", NULL) : NULL;
    double *row = found ? arg(&vs, o_row, 'd', W, 0, 1, 1, "row", NULL) : NULL;
    double *peak = row ? arg(&vs, o_peak, 'd', W, 0, 1, 1, "peak", NULL) : NULL;
    uint8_t *status = peak ? arg(&vs, o_status, 'u', W, 0, 1, 1, "status", NULL) : NULL;
    if (!status) goto fail;
    if (W < 2 || p.min_run < 1 || p.support_half < 1 || p.smooth_half < 0 || p.max_gap < 0 || t1 <= t0) {
        PyErr_Format(PyExc_ValueError, "resolve: need >= 2 columns, min_run >= 1, support_half >= 1, smooth_half >= 0, "
                     "max_gap >= 0 and t1 > t0");
        goto fail;
    }
    for (idx_t j = 0; j < m; j++) {
        if (idx[j] < 0 || idx[j] >= W || (j && idx[j] <= idx[j - 1])) {
            PyErr_Format(PyExc_ValueError, "resolve: idx2 must be increasing columns in [0, %zd)", W);
            goto fail;
        }
    }
    InvDepth g = {tab, tshape[0], W, tab_top};
    /* scratch: 7 double arrays of W, the running sums ((W + 1) x 5), 5 index and 8 flag arrays of W */
    double *buf = PyMem_Malloc((size_t)(7 * W + 5 * (W + 1)) * sizeof(double));
    idx_t *ibuf = PyMem_Malloc((size_t)(5 * W) * sizeof(idx_t));
    char *cbuf = PyMem_Malloc((size_t)(8 * W));
    if (!buf || !ibuf || !cbuf) {
        PyMem_Free(buf), PyMem_Free(ibuf), PyMem_Free(cbuf);
        PyErr_NoMemory();
        goto fail;
    }
    double *r1 = buf, *r2 = r1 + W, *v2 = r2 + W, *med = v2 + W, *step = med + W, *weight = step + W,
           *snorm = weight + W, *T = snorm + W;
    idx_t *label = ibuf, *start = label + W, *stop = start + W, *lastb = stop + W, *nextb = lastb + W;
    char *det1 = cbuf, *det2 = det1 + W, *ok2 = det2 + W, *pick2 = ok2 + W, *failed = pick2 + W, *outlier = failed + W,
         *bright = outlier + W, *line_seen = bright + W;
    const idx_t *k1 = k, *k2 = k + W;
    const double *s1 = s, *s2 = s + W;

    int two = 0;
    Py_BEGIN_ALLOW_THREADS
    /* detection: smoothed peak above threshold, the column's own peak not too dim, one line wide */
    for (idx_t i = 0; i < W; i++) {
        det1[i] = s1[i] >= thr[i] && c1peak[i] >= p.dim_peak_fraction * s1[i] && c1spread[i] <= p.max_spread_px;
        r1[i] = c1valid[i] ? c1row[i] : (double)k1[i];
        det2[i] = ok2[i] = 0;
        r2[i] = NAN;
        v2[i] = 0.0;
    }
    for (idx_t j = 0; j < m; j++) {
        idx_t i = idx[j];
        det2[i] = c2peak[j] >= p.dim_peak_fraction * s2[i] && c2spread[j] <= p.max_spread_px;
        r2[i] = c2valid[j] ? c2row[j] : (double)k2[i];
        v2[i] = c2peak[j];
        ok2[i] = c2valid[j];
        two |= det2[i];
    }
    for (idx_t i = 0; i < W; i++) pick2[i] = det2[i] && !det1[i];
    if (two) {
        /* band rows (+ t0) for the choice */
        double *b1 = med, *b2 = step; /* free until the runs below */
        for (idx_t i = 0; i < W; i++) b1[i] = r1[i] + (double)t0, b2[i] = r2[i] + (double)t0;
        for (idx_t i = 0; i < W; i++)
            if (det1[i] && det2[i]) pick2[i] = (char)choose_second(i, b1, b2, det1, det2, W, p.support_half, &g, (double)top);
    }
    double off = (double)(top + t0);
    for (idx_t i = 0; i < W; i++) {
        int measured = pick2[i] ? ok2[i] : c1valid[i];
        peak[i] = pick2[i] ? v2[i] : c1peak[i];
        row[i] = (pick2[i] ? r2[i] : r1[i]) + off;
        snorm[i] = pick2[i] ? s2[i] : s1[i];
        int f = det1[i] || det2[i];
        failed[i] = f && !measured;
        found[i] = f && measured;
    }
    /* continuity (FastPipeline._segments): 5-column running median, jump step from 1/z */
    running_median(row, found, W, med);
    for (idx_t i = 0; i < W; i++) {
        double iz, slope;
        inverse_depth(&g, med[i], i, &iz, &slope);
        double st = fabs(p.jump_rel * iz / slope);
        step[i] = isfinite(st) ? (st > 1.0 ? st : 1.0) : 1.0;
        outlier[i] = found[i] && !(fabs(row[i] - med[i]) <= step[i]);
    }
    label[0] = 1;
    for (idx_t i = 0; i + 1 < W; i++) {
        double lim = step[i + 1] < step[i] ? step[i + 1] : step[i];
        int near = fabs(row[i + 1] - row[i]) <= p.jump_factor * lim || outlier[i + 1] || outlier[i];
        int cont = found[i + 1] && found[i] && fabs(med[i + 1] - med[i]) <= lim && near;
        label[i + 1] = label[i] + !cont;
    }
    /* run limits; the dim-column rule: a column counts only between bright columns of its run */
    for (idx_t i = 0; i < W; i++) {
        start[i] = (i && label[i] == label[i - 1]) ? start[i - 1] : i;
        bright[i] = found[i] && peak[i] >= p.own_peak_fraction * snorm[i];
        lastb[i] = bright[i] ? i : (i ? lastb[i - 1] : -1);
    }
    for (idx_t i = W - 1; i >= 0; i--) {
        stop[i] = (i < W - 1 && label[i] == label[i + 1]) ? stop[i + 1] : i;
        nextb[i] = bright[i] ? i : (i < W - 1 ? nextb[i + 1] : W);
    }
    for (idx_t i = 0; i < W; i++)
        found[i] = found[i] && lastb[i] >= 0 && nextb[i] < W && label[lastb[i]] == label[i] && label[nextb[i]] == label[i];
    /* a run needs min_run columns that agree with it (outliers do not count) */
    for (idx_t a = 0; a < W; a = stop[a] + 1) {
        idx_t n = 0;
        for (idx_t i = a; i <= stop[a]; i++) n += found[i] && !outlier[i];
        if (n < p.min_run)
            for (idx_t i = a; i <= stop[a]; i++) found[i] = 0;
    }
    for (idx_t i = 0; i < W; i++) {
        status[i] = found[i] ? OK : NO_RETURN;
        if (!found[i] && (s1[i] >= thr[i] || failed[i])) status[i] = REJECTED; /* a line, not measurable */
    }
    if (p.smooth_half) {
        for (idx_t i = 0; i < W; i++) weight[i] = found[i] && !outlier[i] ? (peak[i] >= 1.0 || isnan(peak[i]) ? peak[i] : 1.0) : 0.0;
        local_line_fit(row, weight, found, start, stop, W, p.smooth_half, T);
        /* gaps of up to max_gap columns inside a surface (dark speckle grains) */
        for (idx_t i = 0; i < W; i++) {
            line_seen[i] = status[i] != NO_RETURN;
            lastb[i] = found[i] ? i : (i ? lastb[i - 1] : -1); /* now the last/next found column */
        }
        for (idx_t i = W - 1; i >= 0; i--) nextb[i] = found[i] ? i : (i < W - 1 ? nextb[i + 1] : W);
        for (idx_t i = 0; i < W; i++) {
            idx_t l = lastb[i], r = nextb[i];
            if (found[i] || l < 0 || r >= W || r - l > p.max_gap + 1) continue;
            idx_t span = r - l;
            double rl = row[l], rr = row[r];
            if (fabs(rr - rl) <= 1.0 + 0.5 * (double)span && (line_seen[i] || span == 2)) {
                row[i] = rl + (rr - rl) * ((double)(i - l) / (double)span);
                status[i] = OK; /* found after the loop: the ends of every gap are measured columns */
                peak[i] = 0.0;
            }
        }
        for (idx_t i = 0; i < W; i++) found[i] = status[i] == OK;
    } else {
        for (idx_t i = 0; i < W; i++) {
            if (found[i] && outlier[i]) status[i] = REJECTED, found[i] = 0;
        }
    }
    /* the pulse lit the "unlit" frame in this column (out of sync) */
    for (idx_t i = 0; i < W; i++) {
        double lim = 2.0 * s1[i] >= p.min_peak || isnan(s1[i]) ? 2.0 * s1[i] : p.min_peak;
        if (noise[i] >= lim && !found[i]) status[i] = UNLIT;
    }
    Py_END_ALLOW_THREADS

    /* rows (band coordinates) of the line and of runs of second candidates */
    double lo_seen = INFINITY, hi_seen = -INFINITY;
    for (idx_t i = 0; i < W; i++) {
        if (!found[i]) continue;
        double r = row[i] - (double)top;
        lo_seen = r < lo_seen ? r : lo_seen;
        hi_seen = r > hi_seen ? r : hi_seen;
    }
    if (two) {
        for (idx_t a = 0; a < W;) {
            if (!det2[a]) { a++; continue; }
            idx_t b = a;
            while (b < W && det2[b]) b++;
            if (b - a >= p.min_run)
                for (idx_t i = a; i < b; i++) {
                    double r = (double)(k2[i] + t0);
                    lo_seen = r < lo_seen ? r : lo_seen;
                    hi_seen = r > hi_seen ? r : hi_seen;
                }
            a = b;
        }
    }
    PyMem_Free(buf), PyMem_Free(ibuf), PyMem_Free(cbuf);
    release(&vs);
    if (lo_seen > hi_seen) return Py_BuildValue("nn", t1, (idx_t)-1);
    return Py_BuildValue("nn", (idx_t)floor(lo_seen), (idx_t)ceil(hi_seen));
fail:
    release(&vs);
    return NULL;
}

/* ------------------------------------------------------------------ table triangulation */

/* triangulate(rows, cols, xn, yn, top, (nx, ny, nz, distance), (min_m, max_m, eps), codes,
 *             points, depth, status): device.vision.geometry.ColumnGeometry.triangulate, the
 * normalised ray interpolated between the table's two rows around each sub-pixel row, then the
 * exact ray/plane intersection (thesis eq. 3.13, 3.17), in the order of its numpy formulation.
 * codes: the RangeStatus values (ok, invalid_pixel, beyond_horizon, too_close, too_far). */
static PyObject *py_triangulate(PyObject *self, PyObject *args)
{
    PyObject *o_rows, *o_cols, *o_xn, *o_yn, *o_pts, *o_depth, *o_status;
    idx_t top;
    double nx, ny, nz, dist, min_m, max_m, eps;
    int c_ok, c_invalid, c_beyond, c_close, c_far;
    if (!PyArg_ParseTuple(args, "OOOOn(dddd)(ddd)(iiiii)OOO", &o_rows, &o_cols, &o_xn, &o_yn, &top, &nx, &ny, &nz, &dist,
                          &min_m, &max_m, &eps, &c_ok, &c_invalid, &c_beyond, &c_close, &c_far, &o_pts, &o_depth,
                          &o_status))
        return NULL;
    Views vs = {.n = 0};
    idx_t N, tab[2];
    const double *rows = arg(&vs, o_rows, 'd', -1, 0, 1, 0, "rows", &N);
    const idx_t *cols = rows ? arg(&vs, o_cols, 'i', N, 0, 1, 0, "columns", NULL) : NULL;
    const double *xn = cols ? arg(&vs, o_xn, 'd', -1, -1, 2, 0, "xn", tab) : NULL;
    const double *yn = xn ? arg(&vs, o_yn, 'd', tab[0], tab[1], 2, 0, "yn", NULL) : NULL;
    double *pts = yn ? arg(&vs, o_pts, 'd', N, 3, 2, 1, "points", NULL) : NULL;
    double *depth = pts ? arg(&vs, o_depth, 'd', N, 0, 1, 1, "depth", NULL) : NULL;
    uint8_t *status = depth ? arg(&vs, o_status, 'u', N, 0, 1, 1, "status", NULL) : NULL;
    if (!status) goto fail;
    idx_t n = tab[0], W = tab[1];
    if (n < 1) {
        PyErr_SetString(PyExc_ValueError, "triangulate: the ray table has no rows");
        goto fail;
    }
    for (idx_t i = 0; i < N; i++) {
        if (cols[i] < 0 || cols[i] >= W) {
            PyErr_Format(PyExc_ValueError, "triangulate: column %zd outside the table's %zd columns", cols[i], W);
            goto fail;
        }
    }
    for (idx_t i = 0; i < N; i++) {
        idx_t i0, i1;
        double t;
        int inside = table_position(rows[i], top, n, W, cols[i], &i0, &i1, &t);
        double u = 1.0 - t;
        double x = xn[i0] * u + xn[i1] * t;
        double y = yn[i0] * u + yn[i1] * t;
        double denom = inside ? nx * x + ny * y + nz : NAN;
        double d = dist / denom;
        int st = !isfinite(denom) ? c_invalid : denom <= eps ? c_beyond : d < min_m ? c_close : d > max_m ? c_far : c_ok;
        d = st == c_ok ? d : NAN;
        status[i] = (uint8_t)st;
        depth[i] = d;
        pts[3 * i] = x * d;
        pts[3 * i + 1] = y * d;
        pts[3 * i + 2] = d;
    }
    release(&vs);
    Py_RETURN_NONE;
fail:
    release(&vs);
    return NULL;
}

static PyObject *py_running_median(PyObject *self, PyObject *args)
{
    PyObject *o_x, *o_found, *o_out;
    if (!PyArg_ParseTuple(args, "OOO", &o_x, &o_found, &o_out)) return NULL;
    Views vs = {.n = 0};
    idx_t W;
    const double *x = arg(&vs, o_x, 'd', -1, 0, 1, 0, "x", &W);
    const char *found = x ? arg(&vs, o_found, 'b', W, 0, 1, 0, "found", NULL) : NULL;
    double *out = found ? arg(&vs, o_out, 'd', W, 0, 1, 1, "out", NULL) : NULL;
    if (out) running_median(x, found, W, out);
    release(&vs);
    if (!out) return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"candidates", py_candidates, METH_VARARGS, "candidates(sm, padded, pad, sep, k_out, s_out)"},
    {"refine_com", py_refine_com, METH_VARARGS,
     "refine_com(padded, pad, k, cols, lo, hi, half_width, row, peak, argmax, valid, plateau, spread)"},
    {"resolve", py_resolve, METH_VARARGS, "resolve(...) -> (seen_first, seen_last); see device/vision/fast.py"},
    {"running_median", py_running_median, METH_VARARGS, "running_median(x, found, out)"},
    {"noise_level", py_noise_level, METH_VARARGS, "noise_level(lit, unlit, out)"},
    {"band_difference", py_band_difference, METH_VARARGS, "band_difference(lit, unlit, mask, padded, pad, sm, sat_min)"},
    {"run_length", py_run_length, METH_VARARGS, "run_length(mask, out)"},
    {"triangulate", py_triangulate, METH_VARARGS, "triangulate(rows, cols, xn, yn, top, plane, limits, codes, points, depth, status)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_columns",
                                    "The fast pipeline's image passes and per-column steps, and the table triangulation (device/vision/_columns.c).", -1, methods};

PyMODINIT_FUNC PyInit__columns(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m && (PyModule_AddIntConstant(m, "STATUS_OK", OK) < 0 || PyModule_AddIntConstant(m, "STATUS_NO_RETURN", NO_RETURN) < 0
              || PyModule_AddIntConstant(m, "STATUS_UNLIT", UNLIT) < 0
              || PyModule_AddIntConstant(m, "STATUS_REJECTED", REJECTED) < 0
              || PyModule_AddIntConstant(m, "BLOCK_ROWS", BLOCK_ROWS) < 0)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
