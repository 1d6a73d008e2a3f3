/* The fast pipeline's per-column kernel as plain C: its image passes, the per-column steps 3-5
 * of device/vision/fast.py and the table triangulation of device/vision/geometry.py (issues 7, 14).
 * No Python here: every function works on pointers and sizes, row-major and contiguous, and
 * checks the values it is given (not the buffers' lengths, which only the caller knows).
 * device/vision/columns/binding.c is the Python module device.vision._columns around it;
 * device/vision/columns/test/test_columns.c tests it on its own (`make test`).
 *
 * Build with -ffp-contract=off (setup.py and the Makefile do): no fused multiply-adds, so the
 * doubles round alike on x86-64 and ARM64, in the order of the numpy formulation the kernel
 * replaced (bit-identical pipeline output, tools/golden_scenes.py).
 *
 * Types: indices and sizes are ptrdiff_t (numpy's intp); flags are bool (numpy's bool_, 0 or 1);
 * images are uint8_t rows x cols. Every function with an `err` returns COLUMNS_DONE, or
 * COLUMNS_BAD_ARGUMENT / COLUMNS_NO_MEMORY having written no output and, if `err` is not NULL, a
 * message naming the call and the argument into err->message. */
#ifndef LASERPI_COLUMNS_H
#define LASERPI_COLUMNS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Rows per block of the candidate search (device.vision.fast.BLOCK_ROWS, tested equal). */
#define COLUMNS_BLOCK_ROWS 16

/* device.vision.measurements.ColumnStatus values that columns_resolve writes (tested equal). */
enum { COLUMNS_OK = 0, COLUMNS_NO_RETURN = 1, COLUMNS_UNLIT = 6, COLUMNS_REJECTED = 7 };

typedef enum { COLUMNS_DONE = 0, COLUMNS_BAD_ARGUMENT = 1, COLUMNS_NO_MEMORY = 2 } ColumnsResult;

typedef struct {
    char message[256];
} ColumnsError;

/* A band's difference image (rows x cols) stored with `pad` rows above and below it: image row r
 * is px + (pad + r) * cols, the buffer holds rows + 2 pad rows. The pad rows are the caller's
 * (zero where columns_candidates and columns_refine_com read them). */
typedef struct {
    uint8_t *px;
    ptrdiff_t rows, cols, pad;
} ColumnsPadded;

/* Sub-pixel estimates of m candidates, each array of m (device.vision.peaks.ColumnPeaks):
 * row (NaN where not valid), peak (the difference at the candidate's row), argmax (that row, -1
 * for an empty interval), valid, plateau (a flat top at 255 over >= 3 rows), spread (RMS width). */
typedef struct {
    double *row, *peak;
    ptrdiff_t *argmax;
    bool *valid, *plateau;
    double *spread;
} ColumnsPeaks;

/* Per-column tables of `rows` x `cols` values for image rows top .. top + rows - 1
 * (device.vision.geometry.ColumnGeometry): 1/z of each pixel's ray on the laser plane, and the
 * rays' normalised coordinates xn, yn. */
typedef struct {
    const double *v;
    ptrdiff_t rows, cols, top;
} ColumnsInvDepth;

typedef struct {
    const double *xn, *yn;
    ptrdiff_t rows, cols, top;
} ColumnsRays;

/* FastParams' fields that steps 3-5 use (device/vision/fast.py). */
typedef struct {
    double dim_peak_fraction, own_peak_fraction, max_spread_px, jump_rel, jump_factor, min_peak, max_range_sigma;
    ptrdiff_t min_run, smooth_half, support_half, max_gap;
} ColumnsResolveParams;

/* What steps 3-5 start from, for a band of `cols` columns: the two candidates of each column
 * (k: rows, first the W first ones then the W second ones; s: their smoothed peaks), the
 * detection threshold and noise level (W each), the first candidates' estimates (W), the m
 * second candidates that were refined (columns idx, increasing; estimates of m), the 1/z table,
 * and where the searched rows [t0, t1) of the band lie in the band (which starts at image row
 * `top`). The estimates are only read. */
typedef struct {
    ptrdiff_t cols;
    const ptrdiff_t *k;
    const double *s, *thr, *noise;
    ColumnsPeaks first;
    ptrdiff_t m;
    const ptrdiff_t *idx;
    ColumnsPeaks second;
    ColumnsInvDepth inv_depth;
    ptrdiff_t top, t0, t1;
} ColumnsResolveInput;

/* The line that steps 3-5 find, W columns each: found, row (image rows), peak (0 where a gap
 * was filled), status (COLUMNS_*; found also where the range gate then REJECTED the column:
 * the line was seen there); seen_first / seen_last: the first and last band row of the line or
 * of a run of second candidates, (t1, -1) if none. */
typedef struct {
    bool *found;
    double *row, *peak;
    uint8_t *status;
    ptrdiff_t seen_first, seen_last;
} ColumnsLine;

/* The laser plane n . p = distance (camera frame), the depth limits, and the RangeStatus codes
 * (device.model.triangulation) that columns_triangulate writes. */
typedef struct {
    double nx, ny, nz, distance;
    double min_m, max_m, horizon_eps;
    int ok, invalid_pixel, beyond_horizon, too_close, too_far;
} ColumnsPlane;

/* Step 1, noise: per column, the largest 5-column x 3-row box mean of max(unlit - lit, 0) over
 * the rows x cols band: `cv2.blur(cv2.subtract(unlit, lit), (5, 3)).max(axis=0)` exactly, in
 * one pass. Needs rows >= 1, cols >= 3. out: cols. */
ColumnsResult columns_noise_level(const uint8_t *lit, const uint8_t *unlit, ptrdiff_t rows, ptrdiff_t cols, double *out,
                                  ColumnsError *err);

/* Step 0's bars (FastParams' moved_level, moved_block_level, moved_block_ratio, moved_mean_ratio). */
typedef struct {
    double level, block_level, block_ratio, mean_ratio;
} ColumnsMovedParams;

/* Step 0, motion (FastPipeline._moved, whose comments give the reasons): which of the cols
 * columns of the rows x cols bands a and b (the unlit neighbours) moved between them. With
 * n = rows / 8 and the columns in groups of 8 (the last group holds what is left), each group's
 * n blocks of 4 rows (rows 8i, 8i+2, 8i+4, 8i+6) are averaged in each band and rounded half to
 * even; a group moved where the sum over its blocks of |block a - block b| exceeds level x n,
 * or one block's |difference| reaches block_level. Only where some group reaches a bar are the
 * bars raised by the sensor noise of `unlit` (the unlit frame's own band): its blocks of rows
 * 8i, 8i+4 ("upper") and 8i+2, 8i+6 ("lower") averaged; block_level at least block_ratio x the
 * median over all blocks of |rint(upper) - rint(lower)|, and a group's level at least
 * mean_ratio x n x the median of |upper - lower| (in 16ths of a level: exact for 8 columns, and
 * rounded to them for a last group of fewer) over its blocks and its two neighbour groups' (the
 * first and last group standing in for their missing neighbour), in numpy's float32 arithmetic (the
 * block's bar in double, as Python's max(): a NaN product leaves it). For a multiple of 8 columns, the bytes of the OpenCV and numpy formulation it
 * replaced (INTER_AREA blocks; tests/test_vision_kernel.py). Needs rows >= 8, cols >= 1. */
ColumnsResult columns_moved(const uint8_t *a, const uint8_t *b, const uint8_t *unlit, ptrdiff_t rows, ptrdiff_t cols,
                            const ColumnsMovedParams *params, bool *moved, ColumnsError *err);

/* Step 1, difference: d = max(lit - unlit, 0), 255 on both pixels of a vertical pair saturated
 * in the lit frame and brightened by >= sat_min (a saturated line's flat top), then d &= mask,
 * into the image rows of `diff` (its pad rows untouched); sm = cv2.blur(d, (5, 3)) exactly.
 * lit, unlit, mask, sm: diff->rows x diff->cols. Needs rows >= 1, cols >= 3, pad >= 0,
 * 0 <= sat_min <= 255. */
ColumnsResult columns_band_difference(const uint8_t *lit, const uint8_t *unlit, const uint8_t *mask, ptrdiff_t sat_min,
                                      const ColumnsPadded *diff, uint8_t *sm, ColumnsError *err);

/* Step 2: per column of the smoothed difference sm (diff->rows x diff->cols), the row of its
 * largest value and of the largest more than `sep` rows from it (first of equals), each moved
 * to the largest of the unsmoothed difference at k-1, k, k+1; k[c], s[c] the first, k[W + c],
 * s[W + c] the second (s: sm there; 0 with row 0 if there is no second). Through 16-row block
 * maxima; the last block may be partial. Needs 1 to 65535 rows, pad >= 1 zero rows,
 * 0 <= 2 sep + 1 <= 16. k, s: 2 cols. */
ColumnsResult columns_candidates(const uint8_t *sm, const ColumnsPadded *diff, ptrdiff_t sep, ptrdiff_t *k, double *s,
                                 ColumnsError *err);

/* Step 2, sub-pixel: device.vision.peaks.refine_com_padded, the centre of mass of rows
 * k[j] +- half_width in column cols[j] of the difference, within rows [lo[j], hi[j]) (zeros
 * elsewhere, diff's pad rows zero), for j < m; a flat top at 255 by the plateau's middle. An
 * all-zero window gives NaN (0 / 0) row and spread, as refine_peaks. Needs half_width >= 1,
 * pad >= max(half_width, 2), rows >= 1, each column in the image, 0 <= lo, hi <= rows. */
ColumnsResult columns_refine_com(const ColumnsPadded *diff, ptrdiff_t m, const ptrdiff_t *k, const ptrdiff_t *cols,
                                 const ptrdiff_t *lo, const ptrdiff_t *hi, ptrdiff_t half_width, const ColumnsPeaks *out,
                                 ColumnsError *err);

/* Steps 3-5 (FastPipeline._search): detection, the choice between two candidates, continuity
 * runs and outliers, the dim-column rule, the minimum run, the local line fit, gap filling, the
 * range uncertainty gate and the statuses. Needs cols >= 2, min_run >= 1, support_half >= 1,
 * smooth_half >= 0, max_gap >= 0, max_range_sigma > 0 (may be infinite: no gate), t1 > t0, idx
 * increasing columns, an inv_depth table of `cols` columns. */
ColumnsResult columns_resolve(const ColumnsResolveInput *in, const ColumnsResolveParams *params, ColumnsLine *out,
                              ColumnsError *err);

/* Step 6: sub-pixel rows (n, one per column cols[i]) -> points (n x 3), depth, status: the ray
 * interpolated between the table's two rows around the row, then its intersection with the
 * plane (thesis eq. 3.13, 3.17), as ColumnGeometry.triangulate. Rows outside the table (or NaN)
 * are invalid_pixel. Needs a table of >= 1 row, each column in it. */
ColumnsResult columns_triangulate(const ColumnsRays *rays, const ColumnsPlane *plane, ptrdiff_t n,
                                  const double *rows, const ptrdiff_t *cols, double *points, double *depth,
                                  uint8_t *status, ColumnsError *err);

/* Camera-frame points (n x 3, NaN: none) -> (angle, range) in the scan frame
 * (device.model.scan_frame.to_scan_plane): q = rotation (p - origin), angle = atan2(q1, q0),
 * range = hypot(q0, q1). Each q_k summed as (d0 r_k0 + d1 r_k1) + d2 r_k2, rounded at every
 * operation: numpy's matmul goes through BLAS, whose fused multiply-adds differ in the last bit
 * from machine to machine. rotation: 3 x 3 row-major, origin: 3. */
void columns_scan_plane(ptrdiff_t n, const double *points, const double *rotation, const double *origin, double *angle,
                        double *range);

/* The median of the found values of x within +-2 of each of n elements, NaN where not found
 * (the middle one or the mean of the middle two); found values must be finite. */
void columns_running_median(const double *x, const bool *found, ptrdiff_t n, double *med);

/* The length of the run of true elements each of n elements belongs to (0 where false). */
void columns_run_length(const bool *mask, ptrdiff_t n, ptrdiff_t *out);

/* [start, end) of the runs of true elements of mask (n), runs fewer than `join` elements apart
 * joined into one span with the false ones between them (FastPipeline's _spans): spans[2 i],
 * spans[2 i + 1] for i < the count returned, at most (n + 1) / 2. */
ptrdiff_t columns_spans(const bool *mask, ptrdiff_t n, ptrdiff_t join, ptrdiff_t *spans);

/* Step 7, the rows nearer than the range (FastPipeline.process): rows r0, r0 + step, ... < r1
 * of the frames lit and unlit (H x W), in columns [c0, c1), each row masked by the same row of
 * mask (one row per such row, W columns: 255 where the row is nearer than the column's range,
 * 0 elsewhere). Per column: above = the largest max(lit - unlit, 0) & mask, below = the largest
 * max(unlit - lit, 0) & mask, pair = the largest min(unlit & mask) of two such rows in a row (0
 * with one row): `cv2.bitwise_and(cv2.subtract(la, ua), mask).max(axis=0)`, the same of ua - la,
 * and `np.minimum(u[:-1], u[1:]).max(axis=0, initial=0)` of u = ua & mask. Needs
 * 0 <= r0 < r1 <= H, step >= 1, 0 <= c0 < c1 <= W. above, below, pair: c1 - c0, sharing no byte
 * with each other or the inputs. */
ColumnsResult columns_near_rows(const uint8_t *lit, const uint8_t *unlit, ptrdiff_t H, ptrdiff_t W, const uint8_t *mask,
                                ptrdiff_t r0, ptrdiff_t r1, ptrdiff_t step, ptrdiff_t c0, ptrdiff_t c1, uint8_t *above,
                                uint8_t *below, uint8_t *pair, ColumnsError *err);

/* One frame's columns (n of them: angle, range with REP 117 codes, quality, row) on a scan's m
 * ascending uniform angles `grid` (device/scan/pipeline.py ScanPipeline). The columns with a
 * finite angle are taken in increasing angle, equal angles in column order
 * (device.model.scan_frame.angle_order), and bridged across at most gap_spacings x the median
 * spacing of their angles (the grid's step with fewer than 3 such columns:
 * device.vision.measurements.bridged_gap). range_out: the columns' ranges resampled as
 * device.model.scan_frame.resample_scan does (never across a depth jump of max_jump_ratio; its
 * arithmetic in its order, so bit for bit); quality_out and row_out: the quality (rounded,
 * clipped to 0..255) and row of the measured column (finite range) each ray with a finite range
 * came from (of the two it was interpolated between the one nearer in angle), 0 and NaN at the
 * others. Needs n >= 1 with a finite angle, m >= 2, gap_spacings >= 0. */
ColumnsResult columns_scan_rays(ptrdiff_t n, const double *angle, const double *range, const double *quality,
                                const double *row, ptrdiff_t m, const double *grid, double gap_spacings,
                                double max_jump_ratio, double *range_out, uint8_t *quality_out, double *row_out,
                                ColumnsError *err);

/* A scan's timing (device/scan/timing.py scan_timing): the least-squares line
 * first_ns + i interval_ns through the n rays' times (CLOCK_MONOTONIC ns; not finite: none),
 * its slope rounded to whole ns first and then its offset, and the largest |time - line| of the
 * rays with one; with fewer than two such rays first_ns = fallback_ns rounded, interval 0,
 * residual 0. Rounding is to nearest, ties to even (Python's round), of the slope's quotient as
 * computed (an exact half ns may come out either side of it). The sums are taken relative
 * to the first ray's time and the rays' mean index (no digits lost to a clock's ~1e15 ns).
 * Needs a finite first_ns within +-2^62 ns. */
typedef struct {
    int64_t first_ns, interval_ns;
    double residual_ns;
} ColumnsScanTiming;

ColumnsResult columns_scan_timing(ptrdiff_t n, const double *times_ns, double fallback_ns, ColumnsScanTiming *out,
                                  ColumnsError *err);

#endif
