/* The fast pipeline's image passes and per-column steps, and the table triangulation, one
 * compiled loop each (device/vision/fast.py, device/vision/geometry.py; issue 7). The API and
 * its conventions are in columns.h; the Python module around it is binding.c.
 *
 * Why C: every per-column step is a short loop over the ~1664 columns of a frame (a few rows
 * per column). Written with numpy, each step was a dozen whole-array calls of 2-3 us of overhead
 * for under 1 us of arithmetic: ~230 calls per frame pair, three quarters of the fast pipeline's
 * time. OpenCV has no per-column line finder, and numba/Cython are not among the project's
 * dependencies; this needs only a C compiler (and the binding the Python headers: the buffer
 * protocol, no numpy headers). The image passes replace sequences of OpenCV calls with one or two
 * passes that compute the same bytes (tests/test_vision_kernel.py compares them). It is the only
 * implementation: the numpy formulation it replaced is in the history (commit 95851ef).
 *
 * Floating-point arithmetic is IEEE double in the same order as that formulation (built with
 * -ffp-contract=off, so no fused multiply-adds change the rounding on ARM), and the moments of
 * 8-bit samples are exact integers: every pipeline's output was identical to it, bit for bit, on
 * 14 simulated scenes when porting (BENCHMARKS.md "Pipeline").
 */
#include "columns.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK_ROWS COLUMNS_BLOCK_ROWS
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

typedef ptrdiff_t idx_t;

static ColumnsResult bad_argument(ColumnsError *err, const char *format, ...)
    __attribute__((format(printf, 2, 3)));

static ColumnsResult bad_argument(ColumnsError *err, const char *format, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, format);
        vsnprintf(err->message, sizeof err->message, format, ap);
        va_end(ap);
    }
    return COLUMNS_BAD_ARGUMENT;
}

static ColumnsResult no_memory(ColumnsError *err, const char *call)
{
    if (err) snprintf(err->message, sizeof err->message, "%s: out of memory", call);
    return COLUMNS_NO_MEMORY;
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

/* See FastPipeline._candidates. Block maxima as keys value << 4 | (15 - row in block): one
 * unsigned max per block gives the block's maximum and its first row (a loop along rows over all
 * columns, which the compiler vectorises). */
ColumnsResult columns_candidates(const uint8_t *sm, const ColumnsPadded *diff, ptrdiff_t sep, ptrdiff_t *k, double *s,
                                 ColumnsError *err)
{
    idx_t n = diff->rows, W = diff->cols, pad = diff->pad;
    const uint8_t *P = diff->px;
    if (n < 1 || n > 0xFFFF || pad < 1 || sep < 0 || 2 * sep + 1 > BLOCK_ROWS)
        return bad_argument(err, "candidates: need 1 to 65535 rows (got %td), pad >= 1 (got %td), sep >= 0 and "
                            "2 sep + 1 <= 16 (sep %td)", n, pad, sep);
    idx_t nb = (n + BLOCK_ROWS - 1) / BLOCK_ROWS; /* the last block may be partial (a band cut by the image) */
    uint16_t *bk = malloc((size_t)(nb * W) * sizeof(uint16_t));
    uint32_t *best = malloc((size_t)(2 * W) * sizeof(uint32_t)), *best2 = best ? best + W : NULL;
    idx_t *lo_block = malloc((size_t)(2 * W) * sizeof(idx_t)), *hi_block = lo_block ? lo_block + W : NULL;
    if (!bk || !best || !lo_block) {
        free(bk), free(best), free(lo_block);
        return no_memory(err, "candidates");
    }
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
    free(bk), free(best), free(lo_block);
    return COLUMNS_DONE;
}

/* ------------------------------------------------------------------ noise level, difference */

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

/* In one pass, without the two intermediate images of the OpenCV formulation. */
ColumnsResult columns_noise_level(const uint8_t *A, const uint8_t *B, ptrdiff_t n, ptrdiff_t W, double *out,
                                  ColumnsError *err)
{
    if (n < 1 || W < 3)
        return bad_argument(err, "noise_level: need >= 1 row and >= 3 columns, got %td rows x %td columns", n, W);
    uint8_t *neg = malloc((size_t)(3 * W)); /* the negative difference of rows r-1, r, r+1 */
    uint16_t *v = malloc((size_t)(3 * W) * sizeof(uint16_t)), *h = v ? v + W : NULL, *best = v ? v + 2 * W : NULL;
    if (!neg || !v) {
        free(neg), free(v);
        return no_memory(err, "noise_level");
    }
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
    free(neg), free(v);
    return COLUMNS_DONE;
}

/* acc[c] = sum over j < k of px[j * step + c], for n columns (the step-apart rows of a band). */
PIXEL_LOOP static void column_sums(uint16_t *restrict acc, const uint8_t *restrict px, idx_t step, int k, idx_t n)
{
    memset(acc, 0, (size_t)n * sizeof *acc);
    for (int j = 0; j < k; j++)
        for (idx_t c = 0; c < n; c++) acc[c] += px[j * step + c];
}

/* sum / area rounded to the nearest integer, ties to even (as OpenCV's INTER_AREA blocks and rint) */
static int32_t round_half_even(int32_t sum, int32_t area)
{
    int32_t q = sum / area, twice_rem = 2 * (sum % area);
    return q + (twice_rem > area || (twice_rem == area && (q & 1)));
}

/* Counts of integer keys below 64 x 64, in bins of 64 and of 1: a rank is found in at most 64 + 64 steps. */
typedef struct {
    idx_t coarse[64], fine[64 * 64];
} KeyHistogram;

static void key_count(KeyHistogram *h, const uint16_t *keys, idx_t n, int step)
{
    for (idx_t i = 0; i < n; i++) {
        h->coarse[keys[i] >> 6] += step;
        h->fine[keys[i]] += step;
    }
}

/* the bin of counts[] that holds the value at 0-based rank *r; *r becomes its rank within the bin */
static int rank_in(const idx_t *counts, idx_t *r)
{
    int b = 0;
    for (; *r >= counts[b]; b++) *r -= counts[b];
    return b;
}

/* the key at 0-based rank r of the counted keys */
static int key_at_rank(const KeyHistogram *h, idx_t r)
{
    int b = rank_in(h->coarse, &r);
    return 64 * b + rank_in(h->fine + 64 * b, &r);
}

/* numpy's float32 median of N values counted as whole multiples of 1 / per_level, lo and hi those at
 * ranks (N - 1) / 2 and N / 2: the middle one, or the mean of the middle two */
static float counted_median(int lo, int hi, idx_t N, int per_level)
{
    return N % 2 ? (float)lo / (float)per_level : (float)(lo + hi) / (2.0f * (float)per_level);
}

/* One pass over the rows the blocks use (half of them), and the noise pass only where a bar is
 * reached, in integers: instead of ~25 OpenCV and numpy calls. A block of 8 x 2 pixels averaged in
 * float32, as numpy had it, is its sum / 16 exactly, so |upper - lower| is a key |sum_u - sum_l| of
 * 0..4080 sixteenths and its median over 3 groups' blocks a rank in their counts (a histogram
 * slid along the groups). A last group of k < 8 columns takes the same grid, its keys
 * 8 |sum_u - sum_l| / k rounded. */
ColumnsResult columns_moved(const uint8_t *A, const uint8_t *B, const uint8_t *U, ptrdiff_t rows, ptrdiff_t W,
                            const ColumnsMovedParams *p, bool *moved, ColumnsError *err)
{
    if (rows < 8 || W < 1)
        return bad_argument(err, "moved: need >= 8 rows and >= 1 column, got %td rows x %td columns", rows, W);
    idx_t n = rows / 8, G = (W + 7) / 8;
    uint16_t *sa = malloc((size_t)(2 * W) * sizeof *sa), *sb = sa ? sa + W : NULL;
    int32_t *change = calloc((size_t)G, sizeof *change);
    uint8_t *local = calloc((size_t)G, 1);
    if (!sa || !change || !local) {
        free(sa), free(change), free(local);
        return no_memory(err, "moved");
    }
    for (idx_t i = 0; i < n; i++) {
        column_sums(sa, A + 8 * i * W, 2 * W, 4, W);
        column_sums(sb, B + 8 * i * W, 2 * W, 4, W);
        for (idx_t g = 0; g < G; g++) {
            idx_t c0 = 8 * g, c1 = MIN(c0 + 8, W);
            int32_t suma = 0, sumb = 0, area = (int32_t)(4 * (c1 - c0));
            for (idx_t c = c0; c < c1; c++) suma += sa[c], sumb += sb[c];
            int32_t d = abs(round_half_even(suma, area) - round_half_even(sumb, area));
            change[g] += d;
            local[g] = (uint8_t)MAX(local[g], d);
        }
    }
    double level = p->level * (double)n, block_level = p->block_level;
    bool reached = false;
    for (idx_t g = 0; g < G && !reached; g++) reached = change[g] > level || local[g] >= block_level;
    if (!reached) { /* no group reaches a bar, whatever the noise raises them to */
        memset(moved, 0, (size_t)W);
        free(sa), free(change), free(local);
        return COLUMNS_DONE;
    }
    uint16_t *keys = malloc((size_t)(n * G) * sizeof *keys); /* |upper - lower| in 16ths, group by group */
    KeyHistogram *within = calloc(1, sizeof *within);
    idx_t whole[256] = {0}; /* |rint(upper) - rint(lower)|: whole levels */
    if (!keys || !within) {
        free(sa), free(change), free(local), free(keys), free(within);
        return no_memory(err, "moved");
    }
    for (idx_t i = 0; i < n; i++) {
        column_sums(sa, U + 8 * i * W, 4 * W, 2, W);       /* upper: rows 8i, 8i + 4 */
        column_sums(sb, U + (8 * i + 2) * W, 4 * W, 2, W); /* lower: rows 8i + 2, 8i + 6 */
        for (idx_t g = 0; g < G; g++) {
            idx_t c0 = 8 * g, c1 = MIN(c0 + 8, W);
            int32_t sumu = 0, suml = 0, k = (int32_t)(c1 - c0);
            for (idx_t c = c0; c < c1; c++) sumu += sa[c], suml += sb[c];
            keys[g * n + i] = (uint16_t)round_half_even(8 * abs(sumu - suml), k);
            whole[abs(round_half_even(sumu, 2 * k) - round_half_even(suml, 2 * k))]++;
        }
    }
    idx_t N = n * G, lo = (N - 1) / 2, hi = N / 2; /* the median over all blocks */
    float median = counted_median(rank_in(whole, &lo), rank_in(whole, &hi), N, 1);
    double raised = p->block_ratio * (double)median; /* NaN for an infinite ratio over a median of 0 */
    if (raised > block_level) block_level = raised;   /* Python's max(): a NaN leaves the bar as it was */
    /* each group's bar from its blocks and its neighbours' (the first and last group twice) */
    float level32 = (float)level, ratio32 = (float)(p->mean_ratio * (double)n);
    key_count(within, keys, n, 2);
    key_count(within, keys + MIN(1, G - 1) * n, n, 1);
    for (idx_t g = 0; g < G; g++) {
        if (g > 0) { /* the window moves on by a group */
            key_count(within, keys + (g - 2 < 0 ? 0 : g - 2) * n, n, -1);
            key_count(within, keys + MIN(g + 1, G - 1) * n, n, 1);
        }
        float noise_bar = ratio32 * counted_median(key_at_rank(within, (3 * n - 1) / 2), key_at_rank(within, 3 * n / 2),
                                                   3 * n, 16);
        float bar = isnan(level32) || isnan(noise_bar) ? NAN : MAX(level32, noise_bar); /* np.maximum */
        bool m = (double)change[g] > (double)bar || (double)local[g] >= block_level;
        memset(moved + 8 * g, m, (size_t)(MIN(8 * g + 8, W) - 8 * g));
    }
    free(sa), free(change), free(local), free(keys), free(within);
    return COLUMNS_DONE;
}

/* In two passes instead of OpenCV's six. */
ColumnsResult columns_band_difference(const uint8_t *A, const uint8_t *B, const uint8_t *M, ptrdiff_t sat_min,
                                      const ColumnsPadded *diff, uint8_t *S, ColumnsError *err)
{
    idx_t n = diff->rows, W = diff->cols, pad = diff->pad;
    if (n < 1 || W < 3 || pad < 0 || sat_min < 0 || sat_min > 255)
        return bad_argument(err, "band_difference: need >= 1 row, >= 3 columns, pad >= 0 and 0 <= sat_min <= 255, "
                            "got %td rows x %td columns, pad %td, sat_min %td", n, W, pad, sat_min);
    bool *full = malloc((size_t)n); /* the lit row holds a saturated pixel */
    uint16_t *v = malloc((size_t)(2 * W) * sizeof(uint16_t)), *h = v ? v + W : NULL;
    if (!full || !v) {
        free(full), free(v);
        return no_memory(err, "band_difference");
    }
    bool any_full = false;
    uint8_t *D = diff->px + pad * W;
    for (idx_t r = 0; r < n; r++) {
        full[r] = difference_row(A + r * W, B + r * W, W, D + r * W) == 255;
        any_full |= full[r];
    }
    /* saturated pairs, before the mask: only rows next to another row with a saturated pixel */
    uint8_t lim = (uint8_t)(255 - sat_min);
    for (idx_t r = 0; any_full && r < n; r++) {
        bool up = r > 0 && full[r - 1], down = r + 1 < n && full[r + 1];
        if (full[r] && (up || down))
            saturated_pairs_row(A + r * W, B + r * W, up ? A + (r - 1) * W : NULL, up ? B + (r - 1) * W : NULL,
                                down ? A + (r + 1) * W : NULL, down ? B + (r + 1) * W : NULL, W, lim, D + r * W);
    }
    and_rows(D, M, n * W);
    for (idx_t r = 0; r < n; r++) {
        box_sums(D + reflect101(r - 1, n) * W, D + r * W, D + reflect101(r + 1, n) * W, W, v, h);
        mean_row(h, W, S + r * W);
    }
    free(full), free(v);
    return COLUMNS_DONE;
}

void columns_run_length(const bool *m, ptrdiff_t W, ptrdiff_t *out)
{
    for (idx_t a = 0; a < W;) {
        idx_t b = a;
        while (b < W && m[b]) b++;
        for (idx_t i = a; i < b; i++) out[i] = b - a;
        if (b == a) out[a] = 0, b++;
        a = b;
    }
}

ptrdiff_t columns_spans(const bool *m, ptrdiff_t W, ptrdiff_t join, ptrdiff_t *spans)
{
    idx_t k = 0;
    for (idx_t a = 0; a < W;) {
        if (!m[a]) {
            a++;
            continue;
        }
        idx_t b = a;
        while (b < W && m[b]) b++;
        if (k > 0 && a - spans[2 * k - 1] < join)
            spans[2 * k - 1] = b; /* fewer than `join` apart: the previous span reaches on */
        else
            spans[2 * k] = a, spans[2 * k + 1] = b, k++;
        a = b;
    }
    return k;
}

/* One row of columns_near_rows into the column maxima: a branch-free loop over restrict pointers,
 * which the compiler vectorises (saturating subtractions, byte maxima and minima). prev: the
 * previous row's unlit & mask, 0 before the first row (a pair needs two rows: min(0, x) = 0). */
static void near_rows_add(const uint8_t *restrict l, const uint8_t *restrict u, const uint8_t *restrict mk, idx_t n,
                          uint8_t *restrict above, uint8_t *restrict below, uint8_t *restrict pair,
                          uint8_t *restrict prev)
{
    for (idx_t c = 0; c < n; c++) {
        const uint8_t up = (uint8_t)((l[c] > u[c] ? l[c] - u[c] : 0) & mk[c]);
        const uint8_t down = (uint8_t)((u[c] > l[c] ? u[c] - l[c] : 0) & mk[c]);
        const uint8_t seen = u[c] & mk[c];
        above[c] = MAX(above[c], up);
        below[c] = MAX(below[c], down);
        pair[c] = MAX(pair[c], MIN(prev[c], seen));
        prev[c] = seen;
    }
}

ColumnsResult columns_near_rows(const uint8_t *lit, const uint8_t *unlit, ptrdiff_t H, ptrdiff_t W, const uint8_t *mask,
                                ptrdiff_t r0, ptrdiff_t r1, ptrdiff_t step, ptrdiff_t c0, ptrdiff_t c1, uint8_t *above,
                                uint8_t *below, uint8_t *pair, ColumnsError *err)
{
    if (!(0 <= r0 && r0 < r1 && r1 <= H) || step < 1 || !(0 <= c0 && c0 < c1 && c1 <= W))
        return bad_argument(err, "near_rows: need 0 <= r0 < r1 <= H, step >= 1, 0 <= c0 < c1 <= W, got rows %td-%td "
                            "of %td step %td, columns %td-%td of %td", r0, r1, H, step, c0, c1, W);
    const idx_t n = c1 - c0;
    uint8_t *prev = calloc((size_t)n, 1); /* the previous row's unlit & mask */
    if (!prev) return no_memory(err, "near_rows");
    memset(above, 0, (size_t)n), memset(below, 0, (size_t)n), memset(pair, 0, (size_t)n);
    for (idx_t r = r0, k = 0; r < r1; r += step, k++)
        near_rows_add(lit + r * W + c0, unlit + r * W + c0, mask + k * W + c0, n, above, below, pair, prev);
    free(prev);
    return COLUMNS_DONE;
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

/* With the refine_peaks conventions (see refine_com_padded's docstring). */
ColumnsResult columns_refine_com(const ColumnsPadded *diff, ptrdiff_t m, const ptrdiff_t *kin, const ptrdiff_t *cols,
                                 const ptrdiff_t *lo, const ptrdiff_t *hi, ptrdiff_t half, const ColumnsPeaks *out,
                                 ColumnsError *err)
{
    idx_t H = diff->rows, W = diff->cols, pad = diff->pad;
    const uint8_t *P = diff->px;
    if (half < 1 || pad < half || pad < 2 || H < 1)
        return bad_argument(err, "refine_com: need half_width >= 1 and pad >= max(half_width, 2) zero rows "
                            "around an image of >= 1 row, got half_width %td, pad %td, %td padded rows", half, pad,
                            H + 2 * pad);
    for (idx_t j = 0; j < m; j++) {
        if (cols[j] < 0 || cols[j] >= W || lo[j] < 0 || hi[j] > H)
            return bad_argument(err, "refine_com: column %td (rows [%td, %td)) outside the %tdx%td image", cols[j],
                                lo[j], hi[j], W, H);
    }
    double *row = out->row, *peak = out->peak, *spread = out->spread;
    idx_t *argmax = out->argmax;
    bool *valid = out->valid, *plateau = out->plateau;
    idx_t last = H + 2 * pad - 1;
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
        valid[j] = val;
        plateau[j] = plat;
    }
    return COLUMNS_DONE;
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

/* ColumnGeometry.inverse_depth for one row of column c: (1/z, d(1/z)/d row), NaN outside the table */
static void inverse_depth(const ColumnsInvDepth *g, double row, idx_t c, double *iz, double *slope)
{
    idx_t i0, i1;
    double t;
    if (!table_position(row, g->top, g->rows, g->cols, c, &i0, &i1, &t)) {
        *iz = *slope = NAN;
        return;
    }
    double a = g->v[i0], b = g->v[i1];
    *iz = a + (b - a) * t;
    *slope = b - a;
}

/* The middle one, or the mean of the middle two. */
void columns_running_median(const double *x, const bool *found, ptrdiff_t W, double *med)
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

/* FastPipeline's choice between two detected candidates (see FastPipeline's docstring, step 4):
 * the nearer candidate wins when it continues alone in at least half the neighbours (an
 * occlusion edge), else the farther one unless it is backed less than half as well. Rows r1, r2
 * in band coordinates (+ t0); returns 1 to take the second. */
static int choose_second(idx_t i, const double *r1, const double *r2, const bool *det1, const bool *det2, idx_t W,
                         idx_t h, const ColumnsInvDepth *g, double top)
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
static void local_line_fit(double *row, const double *weight, const bool *inrun, const idx_t *start, const idx_t *stop,
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

/* The centre of mass's row error per unit of noise level / peak (FastPipeline step 5's gate):
 * over a window of rows r = -4..4 around the line (half_width 4), noise of sigma n per pixel
 * moves it by n sqrt(sum r^2) / M = n sqrt(60) / M, M the line's sum over the window, M ~ peak
 * sqrt(2 pi) 1.3 for a line of 1.3 px RMS width (the simulated laser line; a wider one is
 * measured better per unit peak, so this errs on the safe side). The noise level (step 1: the
 * largest 5 x 3 box mean of the negative difference) stands in for n. */
#define COM_ROWS_PER_NOISE 2.4

/* A weighted least-squares line through the measured rows raw[j] of some columns j (weights w_j;
 * FastPipeline step 5), evaluated at column i, dx_j = j - i: its sums, then its value
 * v = sum_j c_j raw_j with c_j = w_j (sxx - sx dx_j) / det, and the 1 sigma of v. With
 * independent row errors of variance s_j^2 its variance is sum_j c_j^2 s_j^2 (a sandwich
 * estimator). s_j is the larger of what column j's own peak allows (com_sigma[j]: its centre of
 * mass's noise) and what it shows: its residual e_j from the line over its leverage
 * (e_j / (1 - h_j), h_j = w_j (sxx - 2 sx dx_j + s0 dx_j^2) / det: the "HC3" estimator, MacKinnon
 * and White 1985), so a line on dim columns, on columns that scatter, or resting on few columns
 * or on one bright column (h_j near 1) reports a large sigma. None (ok 0) through fewer than two
 * columns with weight. */
typedef struct {
    double s0, sx, sxx, sy, sxy;
} LineSums;

typedef struct {
    LineSums s;
    double inv_det, v, slope, var;
    int ok;
} Line;

/* The sums over columns [a, b] (none if b < a) about column i, from local_line_fit's running sums
 * T (as it takes them) */
static inline LineSums window_sums(const double *T, idx_t i, idx_t a, idx_t b)
{
    LineSums s = {0.0, 0.0, 0.0, 0.0, 0.0};
    if (b < a) return s;
    const double *p = T + 5 * a, *q = T + 5 * (b + 1);
    double x = (double)i, s0 = q[0] - p[0], swx = q[1] - p[1], swxx = q[2] - p[2], swy = q[3] - p[3], swxy = q[4] - p[4];
    s.s0 = s0, s.sx = swx - x * s0, s.sxx = swxx - 2.0 * x * swx + x * x * s0, s.sy = swy, s.sxy = swxy - x * swy;
    return s;
}

static inline LineSums sums_plus(LineSums a, LineSums b)
{
    LineSums s = {a.s0 + b.s0, a.sx + b.sx, a.sxx + b.sxx, a.sy + b.sy, a.sxy + b.sxy};
    return s;
}

static Line line_solve(LineSums s)
{
    Line l = {s, 0.0, NAN, NAN, 0.0, 0};
    double det = s.s0 * s.sxx - s.sx * s.sx;
    if (!(s.s0 > 0.0) || !(det > 1e-9 * s.s0 * s.s0)) return l; /* no column, or all weight on one */
    l.inv_det = 1.0 / det, l.ok = 1;
    l.v = (s.sxx * s.sy - s.sx * s.sxy) * l.inv_det;
    l.slope = (s.s0 * s.sxy - s.sx * s.sy) * l.inv_det;
    return l;
}

/* column j's term of the line's variance (none once a column has leverage 1) */
static inline void line_variance_add(Line *l, double w, double dx, double y, double floor2)
{
    const LineSums *s = &l->s;
    double c = w * (s->sxx - s->sx * dx) * l->inv_det, h = w * (s->sxx - 2.0 * s->sx * dx + s->s0 * dx * dx) * l->inv_det;
    if (!(h < 1.0 - 1e-9)) {
        l->ok = 0;
        return;
    }
    double e = (y - l->v - l->slope * dx) / (1.0 - h);
    l->var += c * c * MAX(e * e, floor2);
}

/* The 1 sigma (rows) of the local line fit's row at column i (fitted over columns [lo, hi] of its
 * run): the root of its mean squared error, the fit's variance (Line) plus its squared bias where
 * the line breaks at i. The lines through [lo, i] and through [i, hi] should meet at i; where a
 * surface ends at i and another begins (a step that the straight line bridges, e.g. from a bright
 * near surface into a dark far one with little peak of its own), they differ, the column's row
 * may be on either side's line, and the fit is off by up to their difference d. Its square less
 * what their noise explains (E d^2 = bias^2 + sl^2 + sr^2 for independent sides) is the squared
 * bias's estimate, 0 when negative. Where a side has no line (a run's end), the column's own
 * measurement stands for it (its row and com_sigma, also when it is an outlier left out of the
 * fit): it checks the line extrapolated to it (a surface that ended a column earlier). */
static double fit_sigma(const double *raw, const double *weight, const double *com_sigma, const double *T, idx_t i,
                        idx_t lo, idx_t hi)
{
    LineSums left = window_sums(T, i, lo, i - 1), right = window_sums(T, i, i + 1, hi), own = window_sums(T, i, i, i);
    Line f = line_solve(sums_plus(sums_plus(left, right), own));
    Line l = line_solve(sums_plus(left, own)), r = line_solve(sums_plus(right, own));
    if (!f.ok) return INFINITY;
    for (idx_t j = lo; j <= hi; j++) {
        double w = weight[j], dx = (double)(j - i), y = raw[j], floor2 = com_sigma[j] * com_sigma[j];
        if (w <= 0.0) continue; /* not in the fit (its floor may be infinite: no peak) */
        line_variance_add(&f, w, dx, y, floor2);
        if (j <= i && l.ok) line_variance_add(&l, w, dx, y, floor2);
        if (j >= i && r.ok) line_variance_add(&r, w, dx, y, floor2);
    }
    if (!f.ok) return INFINITY;
    double vl = l.ok ? l.v : raw[i], sl2 = l.ok ? l.var : com_sigma[i] * com_sigma[i];
    double vr = r.ok ? r.v : raw[i], sr2 = r.ok ? r.var : com_sigma[i] * com_sigma[i];
    double bias2 = (vl - vr) * (vl - vr) - sl2 - sr2; /* NaN where column i has no row of its own either */
    return sqrt(f.var + (bias2 > 0.0 ? bias2 : 0.0));
}

/* See FastPipeline._search for the meaning of each rule. */
ColumnsResult columns_resolve(const ColumnsResolveInput *in, const ColumnsResolveParams *params, ColumnsLine *out,
                              ColumnsError *err)
{
    const ColumnsResolveParams p = *params;
    idx_t W = in->cols, m = in->m, top = in->top, t0 = in->t0, t1 = in->t1;
    if (W < 2 || p.min_run < 1 || p.support_half < 1 || p.smooth_half < 0 || p.max_gap < 0 || !(p.max_range_sigma > 0)
        || t1 <= t0)
        return bad_argument(err, "resolve: need >= 2 columns, min_run >= 1, support_half >= 1, smooth_half >= 0, "
                            "max_gap >= 0, max_range_sigma > 0 and t1 > t0");
    const idx_t *idx = in->idx;
    for (idx_t j = 0; j < m; j++) {
        if (idx[j] < 0 || idx[j] >= W || (j && idx[j] <= idx[j - 1]))
            return bad_argument(err, "resolve: idx2 must be increasing columns in [0, %td)", W);
    }
    if (in->inv_depth.cols != W)
        return bad_argument(err, "resolve: the inverse depth table has %td columns, expected %td", in->inv_depth.cols, W);
    const ColumnsInvDepth g = in->inv_depth;
    const double *thr = in->thr, *noise = in->noise;
    const double *c1row = in->first.row, *c1peak = in->first.peak, *c1spread = in->first.spread;
    const bool *c1valid = in->first.valid;
    const double *c2row = in->second.row, *c2peak = in->second.peak, *c2spread = in->second.spread;
    const bool *c2valid = in->second.valid;
    bool *found = out->found;
    double *row = out->row, *peak = out->peak;
    uint8_t *status = out->status;
    /* scratch: 10 double arrays of W, the running sums ((W + 1) x 5), 5 index and 8 flag arrays of W */
    double *buf = malloc((size_t)(10 * W + 5 * (W + 1)) * sizeof(double));
    idx_t *ibuf = malloc((size_t)(5 * W) * sizeof(idx_t));
    bool *cbuf = malloc((size_t)(8 * W) * sizeof(bool));
    if (!buf || !ibuf || !cbuf) {
        free(buf), free(ibuf), free(cbuf);
        return no_memory(err, "resolve");
    }
    double *r1 = buf, *r2 = r1 + W, *v2 = r2 + W, *med = v2 + W, *step = med + W, *weight = step + W,
           *snorm = weight + W, *raw = snorm + W, *com_sigma = raw + W, *sigma = com_sigma + W, *T = sigma + W;
    idx_t *label = ibuf, *start = label + W, *stop = start + W, *lastb = stop + W, *nextb = lastb + W;
    bool *det1 = cbuf, *det2 = det1 + W, *ok2 = det2 + W, *pick2 = ok2 + W, *failed = pick2 + W, *outlier = failed + W,
         *bright = outlier + W, *line_seen = bright + W;
    const idx_t *k1 = in->k, *k2 = in->k + W;
    const double *s1 = in->s, *s2 = in->s + W;

    bool two = false, gate = p.smooth_half && isfinite(p.max_range_sigma); /* the gate needs the line fit */
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
            if (det1[i] && det2[i]) pick2[i] = choose_second(i, b1, b2, det1, det2, W, p.support_half, &g, (double)top);
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
    columns_running_median(row, found, W, med);
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
        status[i] = found[i] ? COLUMNS_OK : COLUMNS_NO_RETURN;
        if (!found[i] && (s1[i] >= thr[i] || failed[i])) status[i] = COLUMNS_REJECTED; /* a line, not measurable */
    }
    if (p.smooth_half) {
        for (idx_t i = 0; i < W; i++) weight[i] = found[i] && !outlier[i] ? (peak[i] >= 1.0 || isnan(peak[i]) ? peak[i] : 1.0) : 0.0;
        memcpy(raw, row, (size_t)W * sizeof(double));
        for (idx_t i = 0; gate && i < W; i++) com_sigma[i] = COM_ROWS_PER_NOISE * MAX(noise[i], 1.0) / peak[i];
        local_line_fit(row, weight, found, start, stop, W, p.smooth_half, T);
        for (idx_t i = 0; gate && i < W; i++)
            sigma[i] = found[i] ? fit_sigma(raw, weight, com_sigma, T, i, MAX(i - p.smooth_half, start[i]),
                                            MIN(i + p.smooth_half, stop[i])) : NAN;
        /* gaps of up to max_gap columns inside a surface (dark speckle grains) */
        for (idx_t i = 0; i < W; i++) {
            line_seen[i] = status[i] != COLUMNS_NO_RETURN;
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
                status[i] = COLUMNS_OK; /* found after the loop: the ends of every gap are measured columns */
                peak[i] = 0.0;
                /* the interpolation's sigma, whatever the ends' correlation: at most this */
                if (gate) sigma[i] = sigma[l] * ((double)(r - i) / (double)span) + sigma[r] * ((double)(i - l) / (double)span);
            }
        }
        for (idx_t i = 0; i < W; i++) found[i] = status[i] == COLUMNS_OK;
    } else {
        for (idx_t i = 0; i < W; i++) {
            if (found[i] && outlier[i]) status[i] = COLUMNS_REJECTED, found[i] = 0;
        }
    }
    /* the pulse lit the "unlit" frame in this column (out of sync) */
    for (idx_t i = 0; i < W; i++) {
        double lim = 2.0 * s1[i] >= p.min_peak || isnan(s1[i]) ? 2.0 * s1[i] : p.min_peak;
        if (noise[i] >= lim && !found[i]) status[i] = COLUMNS_UNLIT;
    }

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
    /* the gate: a range whose predicted 1 sigma exceeds max_range_sigma (relative) is REJECTED; the
     * range's relative change per row is that of the depth, |d(1/z)/d row| / (1/z) (the ray's
     * length changes ~1e-3 as fast). found stays: tracking follows the line that was seen. */
    if (gate) {
        for (idx_t i = 0; i < W; i++) {
            if (status[i] != COLUMNS_OK) continue;
            double iz, slope;
            inverse_depth(&g, row[i], i, &iz, &slope);
            double rel = fabs(slope / iz); /* NaN outside the table: triangulation says why */
            if (isfinite(rel) && !(sigma[i] * rel <= p.max_range_sigma)) status[i] = COLUMNS_REJECTED; /* also NaN */
        }
    }
    free(buf), free(ibuf), free(cbuf);
    if (lo_seen > hi_seen) {
        out->seen_first = t1, out->seen_last = -1;
    } else {
        out->seen_first = (idx_t)floor(lo_seen), out->seen_last = (idx_t)ceil(hi_seen);
    }
    return COLUMNS_DONE;
}

/* ------------------------------------------------------------------ table triangulation */

/* In the order of ColumnGeometry.triangulate's numpy formulation. */
ColumnsResult columns_triangulate(const ColumnsRays *rays, const ColumnsPlane *pl, ptrdiff_t N, const double *rows,
                                  const ptrdiff_t *cols, double *pts, double *depth, uint8_t *status, ColumnsError *err)
{
    idx_t n = rays->rows, W = rays->cols, top = rays->top;
    if (n < 1) return bad_argument(err, "triangulate: the ray table has no rows");
    for (idx_t i = 0; i < N; i++) {
        if (cols[i] < 0 || cols[i] >= W)
            return bad_argument(err, "triangulate: column %td outside the table's %td columns", cols[i], W);
    }
    const double *xn = rays->xn, *yn = rays->yn;
    const ColumnsPlane p = *pl;
    for (idx_t i = 0; i < N; i++) {
        idx_t i0, i1;
        double t;
        int inside = table_position(rows[i], top, n, W, cols[i], &i0, &i1, &t);
        double u = 1.0 - t;
        double x = xn[i0] * u + xn[i1] * t;
        double y = yn[i0] * u + yn[i1] * t;
        double denom = inside ? p.nx * x + p.ny * y + p.nz : NAN;
        double d = p.distance / denom;
        int st = !isfinite(denom) ? p.invalid_pixel
                 : denom <= p.horizon_eps ? p.beyond_horizon
                 : d < p.min_m ? p.too_close
                 : d > p.max_m ? p.too_far
                 : p.ok;
        d = st == p.ok ? d : NAN;
        status[i] = (uint8_t)st;
        depth[i] = d;
        pts[3 * i] = x * d;
        pts[3 * i + 1] = y * d;
        pts[3 * i + 2] = d;
    }
    return COLUMNS_DONE;
}

void columns_scan_plane(ptrdiff_t n, const double *points, const double *rotation, const double *origin, double *angle,
                        double *range)
{
    const double *r = rotation;
    for (idx_t i = 0; i < n; i++) {
        const double d0 = points[3 * i] - origin[0], d1 = points[3 * i + 1] - origin[1], d2 = points[3 * i + 2] - origin[2];
        const double q0 = (d0 * r[0] + d1 * r[1]) + d2 * r[2];
        const double q1 = (d0 * r[3] + d1 * r[4]) + d2 * r[5];
        angle[i] = atan2(q1, q0);
        range[i] = hypot(q0, q1);
    }
}

/* ---- the scan's rays (device.model.scan_frame.resample_scan's arithmetic) ---------------- */

/* The first of the n ascending values a[lo..n) that is >= g (numpy's searchsorted, side left),
 * from lo on: the grid ascends, so each search starts where the previous one ended, and a step
 * at a time (the rays and the columns are about as dense: O(n + m) in all, where a bisection
 * from lo on costs log n a ray). */
static idx_t lower_bound_from(const double *a, const idx_t *at, idx_t n, idx_t lo, double g)
{
    while (lo < n && a[at[lo]] < g) lo++;
    return lo;
}

/* order[0..k) <- the columns of the n whose angle is finite, in increasing angle, equal angles
 * in column order (device.model.scan_frame.angle_order: numpy's stable sort): the falling runs
 * reversed, then merges of the rising runs (a camera's columns come as one run, but for the few
 * where the line's row bends a column's azimuth), into tmp and back; returns k. */
static idx_t finite_angle_order(idx_t n, const double *angle, idx_t *order, idx_t *tmp)
{
    idx_t k = 0;
    for (idx_t i = 0; i < n; i++)
        if (isfinite(angle[i])) order[k++] = i;
    /* a strictly falling run reversed is a rising one, equal angles kept in column order (a run
     * that falls strictly holds none): a camera's angle falls with the column */
    for (idx_t i = 0; i < k;) {
        idx_t j = i + 1;
        while (j < k && angle[order[j]] < angle[order[j - 1]]) j++;
        for (idx_t a = i, b = j - 1; a < b; a++, b--) {
            const idx_t t = order[a];
            order[a] = order[b], order[b] = t;
        }
        i = j;
    }
    for (;;) {
        idx_t runs = 0;
        for (idx_t i = 0; i < k; runs++) {
            idx_t mid = i + 1;
            while (mid < k && angle[order[mid - 1]] <= angle[order[mid]]) mid++;
            idx_t end = mid;
            while (end < k && (end == mid || angle[order[end - 1]] <= angle[order[end]])) end++;
            idx_t a = i, b = mid, out = i;
            while (a < mid && b < end) tmp[out++] = angle[order[b]] < angle[order[a]] ? order[b++] : order[a++];
            while (a < mid) tmp[out++] = order[a++];
            while (b < end) tmp[out++] = order[b++];
            i = end;
        }
        if (k) memcpy(order, tmp, (size_t)k * sizeof *order);
        if (runs <= 1) return k;
    }
}

/* The median of the n >= 1 values x (the middle one, or the mean of the middle two as numpy's
 * median: (a + b) / 2), reordering x: a quickselect. */
static double median_in_place(double *x, idx_t n)
{
    idx_t want = n / 2, lo = 0, hi = n - 1;
    while (lo < hi) { /* x[want] <- the value of rank `want` (Hoare's partition about the middle's value) */
        const double pivot = x[lo + (hi - lo) / 2];
        idx_t i = lo, j = hi;
        while (i <= j) {
            while (x[i] < pivot) i++;
            while (pivot < x[j]) j--;
            if (i <= j) {
                const double t = x[i];
                x[i++] = x[j], x[j--] = t;
            }
        }
        if (want <= j)
            hi = j;
        else if (want >= i)
            lo = i;
        else
            break;
    }
    if (n % 2) return x[want];
    double below = x[0]; /* rank want - 1: the largest of x[0..want) (all <= x[want]) */
    for (idx_t i = 1; i < want; i++)
        if (x[i] > below) below = x[i];
    return (below + x[want]) / 2;
}

ColumnsResult columns_scan_rays(ptrdiff_t n, const double *angle, const double *range, const double *quality,
                                const double *row, ptrdiff_t m, const double *grid, double gap_spacings,
                                double max_jump_ratio, double *range_out, uint8_t *quality_out, double *row_out,
                                ColumnsError *err)
{
    if (n < 1 || m < 2 || !(gap_spacings >= 0))
        return bad_argument(err, "columns_scan_rays: need n >= 1, m >= 2 and gap_spacings >= 0, got %td, %td, %g", n, m,
                            gap_spacings);
    idx_t *order = malloc((size_t)(3 * n) * sizeof *order), *tmp = order ? order + n : NULL,
          *measured = order ? order + 2 * n : NULL;
    double *spacing = malloc((size_t)n * sizeof *spacing);
    if (!order || !spacing) {
        free(order), free(spacing);
        return no_memory(err, "columns_scan_rays");
    }
    const idx_t n_order = finite_angle_order(n, angle, order, tmp);
    if (n_order < 1) {
        free(order), free(spacing);
        return bad_argument(err, "columns_scan_rays: no column has a finite angle");
    }
    /* the largest gap bridged: gap_spacings x the median spacing of the columns' angles, the
     * grid's step with fewer than 3 columns (device.vision.measurements.bridged_gap) */
    double max_gap = grid[1] - grid[0];
    if (n_order > 2) {
        for (idx_t j = 0; j + 1 < n_order; j++) spacing[j] = angle[order[j + 1]] - angle[order[j]];
        max_gap = gap_spacings * median_in_place(spacing, n_order - 1);
    }
    free(spacing);
    /* the measured columns (finite range) in increasing angle: resample_scan's a, r */
    idx_t nm = 0;
    for (idx_t j = 0; j < n_order; j++)
        if (isfinite(range[order[j]])) measured[nm++] = order[j];
    /* each ray's range, and the quality and row of the measured column it came from: the one
     * nearer in angle of the two it was interpolated between, or the one it was taken from across
     * a jump (a ray with a range always has a row, so a time: device/scan/timing.py) */
    idx_t k = 0;
    for (idx_t i = 0; i < m; i++) {
        const double g = grid[i];
        double out = INFINITY;
        idx_t src = -1;
        if (nm > 0) {
            k = lower_bound_from(angle, measured, nm, k, g);
            const idx_t lo = k - 1 < 0 ? 0 : k - 1, hi = k < nm - 1 ? k : nm - 1;
            const double a0 = angle[measured[lo]], a1 = angle[measured[hi]];
            const double r0 = range[measured[lo]], r1 = range[measured[hi]];
            const double span = a1 - a0;
            const bool inside = k > 0 && k < nm && span <= max_gap;
            const bool smooth = fabs(r1 - r0) <= max_jump_ratio * (r0 < r1 ? r0 : r1);
            const double w = span > 0 ? (g - a0) / span : 0.0;
            const idx_t near = measured[fabs(g - a0) <= fabs(a1 - g) ? lo : hi];
            if (inside && smooth) {
                out = r0 + w * (r1 - r0), src = near;
            } else if (fabs(angle[near] - g) <= max_gap / 2) { /* across a jump: the nearer-in-angle neighbour */
                out = range[near], src = near;
            }
        }
        range_out[i] = out;
        if (src >= 0) {
            const double q = rint(quality[src]);
            quality_out[i] = q > 0 ? (q < 255 ? (uint8_t)q : 255) : 0;
            row_out[i] = row[src];
        } else {
            quality_out[i] = 0;
            row_out[i] = NAN;
        }
    }
    /* REP 117 codes (finite angle, no finite range) in the nearest cell, the first one in the
     * columns' order that says more than "no return" in a cell nothing was resampled into */
    const double step = (grid[m - 1] - grid[0]) / (double)(m - 1);
    for (idx_t j = 0; j < n; j++) {
        const double code = range[j];
        if (!isfinite(angle[j]) || isfinite(code) || code > 0) continue;
        const double cell = rint((angle[j] - grid[0]) / step);
        if (cell >= 0 && cell < (double)m && range_out[(idx_t)cell] == INFINITY) range_out[(idx_t)cell] = code;
    }
    free(order);
    return COLUMNS_DONE;
}

/* ---- the scan's timing (device/scan/timing.py scan_timing) ---------------------------------- */

ColumnsResult columns_scan_timing(ptrdiff_t n, const double *times_ns, double fallback_ns, ColumnsScanTiming *out,
                                  ColumnsError *err)
{
    const double limit = 4611686018427387904.0; /* 2^62 ns: rounds to an int64_t with room */
    idx_t count = 0, first = -1;
    double sum_i = 0, sum_y = 0;
    for (idx_t i = 0; i < n; i++) {
        if (!isfinite(times_ns[i])) continue;
        if (first < 0) first = i;
        count++, sum_i += (double)i, sum_y += times_ns[i] - times_ns[first];
    }
    if (count < 2) {
        if (!(fabs(fallback_ns) < limit))
            return bad_argument(err, "columns_scan_timing: fallback_ns %g is not a time", fallback_ns);
        *out = (ColumnsScanTiming){(int64_t)rint(fallback_ns), 0, 0.0};
        return COLUMNS_DONE;
    }
    const double t0 = times_ns[first], mean_i = sum_i / (double)count, mean_y = sum_y / (double)count;
    double sxy = 0, sxx = 0;
    for (idx_t i = first; i < n; i++) {
        if (!isfinite(times_ns[i])) continue;
        const double x = (double)i - mean_i;
        sxy += x * (times_ns[i] - t0 - mean_y), sxx += x * x;
    }
    const double slope = rint(sxy / sxx); /* sxx > 0: two rays have two indices */
    double offset = 0;
    for (idx_t i = first; i < n; i++)
        if (isfinite(times_ns[i])) offset += times_ns[i] - t0 - slope * (double)i;
    offset /= (double)count;
    double residual = 0;
    for (idx_t i = first; i < n; i++)
        if (isfinite(times_ns[i])) residual = fmax(residual, fabs(times_ns[i] - t0 - (offset + slope * (double)i)));
    const double first_ns = t0 + offset;
    if (!(fabs(first_ns) < limit) || !(fabs(slope) < limit))
        return bad_argument(err, "columns_scan_timing: the line's first ray at %g ns, %g ns a ray, is not a time",
                            first_ns, slope);
    *out = (ColumnsScanTiming){(int64_t)rint(first_ns), (int64_t)slope, residual};
    return COLUMNS_DONE;
}
