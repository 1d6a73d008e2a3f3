/* Host unit tests of the plain C kernel (columns.h), built with AddressSanitizer and
 * UndefinedBehaviorSanitizer by `make test` (the top Makefile's kernel-test) before pytest: each
 * step on small hand-made inputs, the image passes against naive definitions, edge sizes, and
 * the argument errors. Every buffer is allocated at its exact size, so a read or write past one
 * fails the run. The same kernel through Python: tests/test_vision_kernel.py. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "columns.h"

static int checks, failures;

/* counts a check; prints where and why when it fails */
static void check(int ok, int line, const char *what, const char *format, ...) __attribute__((format(printf, 4, 5)));
static void check(int ok, int line, const char *what, const char *format, ...)
{
    checks++;
    if (ok) return;
    failures++;
    printf("FAIL test_columns.c:%d: %s: ", line, what);
    va_list ap;
    va_start(ap, format);
    vprintf(format, ap);
    va_end(ap);
    printf("\n");
}
#define CHECK(cond, ...) check((cond), __LINE__, #cond, __VA_ARGS__)

/* uniform 32-bit numbers, the same on every run (SplitMix64's upper half) */
static uint32_t rnd(void)
{
    static uint64_t state = 12345;
    uint64_t z = (state += 0x9E3779B97F4A7C15u);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9u;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBu;
    return (uint32_t)((z ^ (z >> 31)) >> 32);
}

/* exactly n bytes (at least one), zeroed: AddressSanitizer catches any access past them */
static void *alloc(size_t n)
{
    void *p = calloc(n ? n : 1, 1);
    if (!p) abort();
    return p;
}

static int near(double a, double b, double tol) { return fabs(a - b) <= tol; }

/* ------------------------------------------------------------------ naive definitions */

static ptrdiff_t reflect(ptrdiff_t i, ptrdiff_t n) /* OpenCV's BORDER_REFLECT_101: ...c b | a b c ... | b a */
{
    if (n == 1) return 0;
    if (i < 0) return -i;
    return i >= n ? 2 * (n - 1) - i : i;
}

/* cv2.blur(d, (5, 3)): the 5-column x 3-row box mean rounded to nearest (never half-way) */
static void blur(const uint8_t *d, ptrdiff_t n, ptrdiff_t W, uint8_t *out)
{
    for (ptrdiff_t r = 0; r < n; r++)
        for (ptrdiff_t c = 0; c < W; c++) {
            int sum = 0;
            for (ptrdiff_t dr = -1; dr <= 1; dr++)
                for (ptrdiff_t dc = -2; dc <= 2; dc++) sum += d[reflect(r + dr, n) * W + reflect(c + dc, W)];
            out[r * W + c] = (uint8_t)floor(sum / 15.0 + 0.5);
        }
}

static uint8_t subtract(uint8_t x, uint8_t y) { return x > y ? (uint8_t)(x - y) : 0; }

static void random_image(uint8_t *img, size_t size, int saturated_line)
{
    for (size_t i = 0; i < size; i++) {
        img[i] = (uint8_t)rnd();
        if (saturated_line) img[i] = rnd() % 10 < 3 ? 255 : img[i] / 4;
    }
}

/* ------------------------------------------------------------------ image passes */

static const ptrdiff_t SHAPES[][2] = {{1, 3}, {2, 3}, {3, 7}, {5, 5}, {16, 4}, {37, 101}};
#define N_SHAPES (sizeof SHAPES / sizeof SHAPES[0])

static void test_noise_level_is_the_largest_box_mean_of_the_negative_difference(void)
{
    for (size_t s = 0; s < N_SHAPES; s++) {
        ptrdiff_t n = SHAPES[s][0], W = SHAPES[s][1];
        uint8_t *lit = alloc((size_t)(n * W)), *unlit = alloc((size_t)(n * W)), *neg = alloc((size_t)(n * W));
        uint8_t *want = alloc((size_t)(n * W));
        double *out = alloc((size_t)W * sizeof(double));
        for (int trial = 0; trial < 3; trial++) {
            random_image(lit, (size_t)(n * W), 0);
            random_image(unlit, (size_t)(n * W), 0);
            for (ptrdiff_t i = 0; i < n * W; i++) neg[i] = subtract(unlit[i], lit[i]);
            blur(neg, n, W, want);
            CHECK(columns_noise_level(lit, unlit, n, W, out, NULL) == COLUMNS_DONE, "%tdx%td", n, W);
            for (ptrdiff_t c = 0; c < W; c++) {
                uint8_t top = 0;
                for (ptrdiff_t r = 0; r < n; r++) top = want[r * W + c] > top ? want[r * W + c] : top;
                CHECK(out[c] == top, "%tdx%td column %td: %g, want %d", n, W, c, out[c], top);
            }
        }
        free(lit), free(unlit), free(neg), free(want), free(out);
    }
}

static void test_noise_level_rounds_every_box_sum_as_opencv(void)
{
    /* 3 rows; block i (5 columns) holds 15 values summing to i, the middle row the smallest, so
     * the largest box mean in the block's middle column is the block's own: round(i / 15) */
    enum { SUMS = 15 * 255 + 1, W = 5 * SUMS };
    uint8_t *lit = alloc(3 * W), *unlit = alloc(3 * W);
    double *out = alloc(W * sizeof(double));
    for (int i = 0; i < SUMS; i++)
        for (int j = 0; j < 15; j++) { /* descending: row 0, row 2, then row 1 */
            int row = j < 5 ? 0 : j < 10 ? 2 : 1;
            unlit[row * W + 5 * i + j % 5] = (uint8_t)(i / 15 + (j < i % 15));
        }
    CHECK(columns_noise_level(lit, unlit, 3, W, out, NULL) == COLUMNS_DONE, "call");
    int wrong = 0;
    for (int i = 0; i < SUMS; i++)
        if (out[5 * i + 2] != floor(i / 15.0 + 0.5)) {
            wrong++;
            if (wrong <= 3) printf("  sum %d: %g\n", i, out[5 * i + 2]);
        }
    CHECK(wrong == 0, "%d box sums rounded otherwise", wrong);
    free(lit), free(unlit), free(out);
}

static void test_band_difference_is_the_saturation_aware_difference_and_its_blur(void)
{
    const ptrdiff_t pad = 4, sat_min = 24;
    for (size_t s = 0; s < N_SHAPES; s++) {
        ptrdiff_t n = SHAPES[s][0], W = SHAPES[s][1];
        size_t size = (size_t)(n * W);
        uint8_t *lit = alloc(size), *unlit = alloc(size), *mask = alloc(size), *sm = alloc(size);
        uint8_t *d = alloc(size), *want = alloc(size), *sat = alloc(size);
        uint8_t *padded = alloc((size_t)((n + 2 * pad) * W));
        for (int trial = 0; trial < 4; trial++) {
            random_image(lit, size, trial >= 2);
            random_image(unlit, size, 0);
            for (size_t i = 0; trial >= 2 && i < size; i++)
                if (rnd() % 10 == 0) unlit[i] = 250; /* bright unlit pixels: not part of a line */
            for (size_t i = 0; i < size; i++) mask[i] = rnd() % 10 < 8 ? 255 : 0;
            memset(padded, 77, (size_t)((n + 2 * pad) * W));
            for (size_t i = 0; i < size; i++) {
                d[i] = subtract(lit[i], unlit[i]);
                sat[i] = lit[i] == 255 && d[i] >= sat_min;
            }
            for (ptrdiff_t r = 0; r + 1 < n; r++) /* both pixels of a saturated vertical pair */
                for (ptrdiff_t c = 0; c < W; c++)
                    if (sat[r * W + c] && sat[(r + 1) * W + c]) d[r * W + c] = d[(r + 1) * W + c] = 255;
            for (size_t i = 0; i < size; i++) d[i] &= mask[i];
            blur(d, n, W, want);
            const ColumnsPadded diff = {padded, n, W, pad};
            CHECK(columns_band_difference(lit, unlit, mask, sat_min, &diff, sm, NULL) == COLUMNS_DONE, "%tdx%td", n, W);
            CHECK(memcmp(padded + pad * W, d, size) == 0, "%tdx%td trial %d: difference", n, W, trial);
            CHECK(memcmp(sm, want, size) == 0, "%tdx%td trial %d: blur", n, W, trial);
            int pads_kept = 1;
            for (ptrdiff_t i = 0; i < pad * W; i++)
                pads_kept &= padded[i] == 77 && padded[(pad + n) * W + i] == 77;
            CHECK(pads_kept, "%tdx%td: the pad rows are the caller's", n, W);
        }
        free(lit), free(unlit), free(mask), free(sm), free(d), free(want), free(sat), free(padded);
    }
}

static void test_image_passes_refuse_bad_sizes(void)
{
    uint8_t img[8] = {0}, padded[8] = {0}, sm[8];
    double out[4];
    ColumnsError err;
    CHECK(columns_noise_level(img, img, 4, 2, out, &err) == COLUMNS_BAD_ARGUMENT, "two columns");
    CHECK(strstr(err.message, "noise_level: need >= 1 row and >= 3 columns, got 4 rows x 2 columns") != NULL, "%s",
          err.message);
    CHECK(columns_noise_level(img, img, 0, 4, out, &err) == COLUMNS_BAD_ARGUMENT, "no rows");
    const ColumnsPadded diff = {padded, 2, 4, 0};
    CHECK(columns_band_difference(img, img, img, 256, &diff, sm, &err) == COLUMNS_BAD_ARGUMENT, "sat_min 256");
    CHECK(strstr(err.message, "sat_min 256") != NULL, "%s", err.message);
    const ColumnsPadded narrow = {padded, 4, 2, 0};
    CHECK(columns_band_difference(img, img, img, 24, &narrow, sm, NULL) == COLUMNS_BAD_ARGUMENT, "two columns");
}

/* ------------------------------------------------------------------ candidates */

typedef struct {
    ptrdiff_t n, W, pad;
    uint8_t *sm, *padded;
    ptrdiff_t *k;
    double *s;
} Candidates;

/* a band of n x W whose smoothed difference is also its difference (set sm, then call) */
static Candidates candidates_new(ptrdiff_t n, ptrdiff_t W)
{
    Candidates c = {n, W, 4, alloc((size_t)(n * W)), alloc((size_t)((n + 8) * W)),
                    alloc((size_t)(2 * W) * sizeof(ptrdiff_t)), alloc((size_t)(2 * W) * sizeof(double))};
    return c;
}

static ColumnsResult candidates_run(Candidates *c, ptrdiff_t sep, ColumnsError *err)
{
    memcpy(c->padded + c->pad * c->W, c->sm, (size_t)(c->n * c->W));
    const ColumnsPadded diff = {c->padded, c->n, c->W, c->pad};
    return columns_candidates(c->sm, &diff, sep, c->k, c->s, err);
}

static void candidates_free(Candidates *c) { free(c->sm), free(c->padded), free(c->k), free(c->s); }

/* rows x W bands a, b and unlit of `level`, each at its exact size; moved into `out` (W) */
static ColumnsResult moved_of(const uint8_t *a, const uint8_t *b, const uint8_t *u, ptrdiff_t rows, ptrdiff_t W,
                              bool *out)
{
    const ColumnsMovedParams p = {.level = 0.9, .block_level = 3.0, .block_ratio = 5.0, .mean_ratio = 1.5};
    ColumnsError err;
    return columns_moved(a, b, u, rows, W, &p, out, &err);
}

static void test_moved_marks_the_groups_whose_blocks_changed(void)
{
    enum { ROWS = 16, W = 20 }; /* 2 blocks of rows; groups of columns 0-7, 8-15 and 16-19 */
    uint8_t *a = alloc(ROWS * W), *b = alloc(ROWS * W);
    bool *out = alloc(W);
    memset(a, 100, ROWS * W), memset(b, 100, ROWS * W);
    CHECK(moved_of(a, b, a, ROWS, W, out) == COLUMNS_DONE, "%s", "a still band");
    int any = 0;
    for (int c = 0; c < W; c++) any |= out[c];
    CHECK(!any, "%s", "nothing moved in a still band");
    /* one block of group 1 brighter by 3 levels (its block_level) on the rows the blocks read */
    for (int r = 8; r < 16; r += 2)
        for (int c = 8; c < 16; c++) b[r * W + c] = 103;
    CHECK(moved_of(a, b, a, ROWS, W, out) == COLUMNS_DONE, "%s", "one block changed");
    for (int c = 0; c < W; c++) CHECK(out[c] == (c >= 8 && c < 16), "column %d: %d", c, out[c]);
    /* the odd rows are not read: a change there alone moves nothing */
    memset(b, 100, ROWS * W);
    for (int r = 1; r < ROWS; r += 2)
        for (int c = 0; c < W; c++) b[r * W + c] = 200;
    CHECK(moved_of(a, b, a, ROWS, W, out) == COLUMNS_DONE, "%s", "odd rows changed");
    any = 0;
    for (int c = 0; c < W; c++) any |= out[c];
    CHECK(!any, "%s", "the rows between the blocks' rows are not read");
    /* the last, partial group (columns 16-19) is averaged over its own 4 columns */
    memset(b, 100, ROWS * W);
    for (int r = 0; r < 8; r += 2)
        for (int c = 16; c < W; c++) b[r * W + c] = 104;
    CHECK(moved_of(a, b, a, ROWS, W, out) == COLUMNS_DONE, "%s", "the partial group changed");
    for (int c = 0; c < W; c++) CHECK(out[c] == (c >= 16), "column %d: %d", c, out[c]);
    free(a), free(b), free(out);
}

static void test_moved_raises_the_bars_by_the_unlit_bands_noise(void)
{
    enum { ROWS = 8, W = 16 }; /* one block row, two groups */
    uint8_t *a = alloc(ROWS * W), *b = alloc(ROWS * W), *u = alloc(ROWS * W);
    bool *out = alloc(W);
    memset(a, 50, ROWS * W), memset(b, 50, ROWS * W);
    for (int r = 0; r < ROWS; r += 2)
        for (int c = 0; c < 8; c++) b[r * W + c] = 56; /* group 0: a block 6 levels brighter */
    /* unlit: its rows 0 and 4 at 52, 2 and 6 at 50 in both groups: the noise's median is 2 levels,
     * so block_level becomes 5 x 2 = 10 and the mean's bar 1.5 x 1 x 2 = 3 */
    memset(u, 50, ROWS * W);
    for (int r = 0; r < ROWS; r += 4)
        for (int c = 0; c < W; c++) u[r * W + c] = 52;
    CHECK(moved_of(a, b, u, ROWS, W, out) == COLUMNS_DONE, "%s", "a noisy unlit band");
    /* group 0 changed by 6: above the mean's bar of 3, under the block's 10 */
    for (int c = 0; c < W; c++) CHECK(out[c] == (c < 8), "column %d: %d", c, out[c]);
    for (int r = 0; r < ROWS; r += 4)
        for (int c = 0; c < W; c++) u[r * W + c] = 54; /* the noise's median 4: bars 20 and 6 */
    CHECK(moved_of(a, b, u, ROWS, W, out) == COLUMNS_DONE, "%s", "a noisier unlit band");
    for (int c = 0; c < W; c++) CHECK(!out[c], "column %d: %d (6 levels is not above a bar of 6)", c, out[c]);
    free(a), free(b), free(u), free(out);
}

static void test_moved_refuses_bad_sizes(void)
{
    uint8_t px[8 * 4] = {0};
    bool out[4];
    const ColumnsMovedParams p = {0.9, 3.0, 5.0, 1.5};
    ColumnsError err;
    CHECK(columns_moved(px, px, px, 7, 4, &p, out, &err) == COLUMNS_BAD_ARGUMENT
          && strstr(err.message, "moved: need >= 8 rows and >= 1 column, got 7 rows x 4 columns"), "%s", err.message);
    CHECK(columns_moved(px, px, px, 8, 0, &p, out, &err) == COLUMNS_BAD_ARGUMENT, "%s", err.message);
}

static void test_candidates_find_the_largest_and_a_separated_second_peak(void)
{
    Candidates c = candidates_new(64, 6);
    for (ptrdiff_t col = 0; col < 6; col++) {
        c.sm[20 * 6 + col] = 50; /* the line */
        c.sm[22 * 6 + col] = 40; /* its flank: too close to be a second line */
        c.sm[45 * 6 + col] = 30; /* a ghost */
    }
    CHECK(candidates_run(&c, 5, NULL) == COLUMNS_DONE, "call");
    for (ptrdiff_t col = 0; col < 6; col++)
        CHECK(c.k[col] == 20 && c.k[6 + col] == 45 && c.s[col] == 50 && c.s[6 + col] == 30,
              "column %td: %td %td %g %g", col, c.k[col], c.k[6 + col], c.s[col], c.s[6 + col]);
    candidates_free(&c);
}

static void test_candidates_take_the_first_of_equal_rows_and_the_unsmoothed_maximum(void)
{
    Candidates c = candidates_new(40, 3);
    c.sm[5 * 3 + 0] = c.sm[30 * 3 + 0] = 90; /* equal maxima: the first row wins, the other is second */
    c.sm[10 * 3 + 1] = 60;                   /* the smoothed maximum at 10 ... */
    CHECK(candidates_run(&c, 5, NULL) == COLUMNS_DONE, "call");
    CHECK(c.k[0] == 5 && c.k[3] == 30 && c.s[3] == 90, "equal maxima: %td %td", c.k[0], c.k[3]);
    c.padded[(4 + 11) * 3 + 1] = 61; /* ... moved to the unsmoothed maximum at 11, with sm's value there */
    const ColumnsPadded diff = {c.padded, c.n, c.W, c.pad};
    CHECK(columns_candidates(c.sm, &diff, 5, c.k, c.s, NULL) == COLUMNS_DONE, "call");
    CHECK(c.k[1] == 11 && c.s[1] == 0, "moved: %td %g", c.k[1], c.s[1]);
    candidates_free(&c);
}

static void test_candidates_in_a_band_whose_last_block_is_partial(void)
{
    Candidates c = candidates_new(21, 3); /* one whole block and 5 rows */
    for (ptrdiff_t col = 0; col < 3; col++) c.sm[19 * 3 + col] = 60;
    c.sm[4 * 3 + 1] = 20;
    CHECK(candidates_run(&c, 5, NULL) == COLUMNS_DONE, "call");
    CHECK(c.k[0] == 19 && c.k[1] == 19 && c.k[2] == 19, "first: %td %td %td", c.k[0], c.k[1], c.k[2]);
    CHECK(c.k[4] == 4 && c.s[4] == 20, "second in the first block: %td %g", c.k[4], c.s[4]);
    CHECK(c.k[3] == 0 && c.s[3] == 0 && c.k[5] == 0 && c.s[5] == 0, "no second: row 0, peak 0");
    candidates_free(&c);
}

static void test_no_second_candidate_on_the_flank_of_a_line_near_the_band_top(void)
{
    Candidates c = candidates_new(32, 2);
    const uint8_t profile[5] = {40, 80, 90, 80, 40};
    for (int r = 0; r < 5; r++) c.sm[(1 + r) * 2] = c.sm[(1 + r) * 2 + 1] = profile[r];
    CHECK(candidates_run(&c, 5, NULL) == COLUMNS_DONE, "call");
    CHECK(c.k[0] == 3 && c.k[1] == 3 && c.s[2] == 0 && c.s[3] == 0, "%td %td %g %g", c.k[0], c.k[1], c.s[2], c.s[3]);
    candidates_free(&c);
}

static void test_candidates_in_a_one_row_band(void)
{
    Candidates c = candidates_new(1, 3);
    c.sm[1] = 7;
    CHECK(candidates_run(&c, 0, NULL) == COLUMNS_DONE, "call");
    CHECK(c.k[0] == 0 && c.k[1] == 0 && c.s[1] == 7 && c.s[0] == 0, "%td %g", c.k[1], c.s[1]);
    CHECK(c.s[3] == 0 && c.s[4] == 0 && c.s[5] == 0, "no second");
    candidates_free(&c);
}

static void test_candidates_refuse_bad_sizes(void)
{
    Candidates c = candidates_new(16, 4);
    ColumnsError err;
    for (int i = 0; i < 8; i++) c.k[i] = -5, c.s[i] = -5.0;
    CHECK(candidates_run(&c, 8, &err) == COLUMNS_BAD_ARGUMENT, "sep 8: 17 rows > one block");
    CHECK(strstr(err.message, "sep >= 0 and 2 sep + 1 <= 16 (sep 8)") != NULL, "%s", err.message);
    CHECK(candidates_run(&c, -1, NULL) == COLUMNS_BAD_ARGUMENT, "sep -1");
    c.pad = 0;
    CHECK(candidates_run(&c, 5, &err) == COLUMNS_BAD_ARGUMENT, "pad 0");
    c.pad = 4, c.n = 0;
    CHECK(candidates_run(&c, 5, &err) == COLUMNS_BAD_ARGUMENT, "no rows");
    CHECK(strstr(err.message, "need 1 to 65535 rows (got 0)") != NULL, "%s", err.message);
    CHECK(c.k[0] == -5 && c.s[7] == -5.0, "nothing written");
    candidates_free(&c);
}

/* ------------------------------------------------------------------ centre of mass */

typedef struct {
    ptrdiff_t m;
    double *row, *peak, *spread;
    ptrdiff_t *argmax;
    bool *valid, *plateau;
} Peaks;

static Peaks peaks_new(ptrdiff_t m)
{
    Peaks p = {m, alloc((size_t)m * sizeof(double)), alloc((size_t)m * sizeof(double)), alloc((size_t)m * sizeof(double)),
               alloc((size_t)m * sizeof(ptrdiff_t)), alloc((size_t)m), alloc((size_t)m)};
    return p;
}

static ColumnsPeaks peaks_view(Peaks *p)
{
    ColumnsPeaks v = {p->row, p->peak, p->argmax, p->valid, p->plateau, p->spread};
    return v;
}

static void peaks_free(Peaks *p) { free(p->row), free(p->peak), free(p->spread), free(p->argmax), free(p->valid), free(p->plateau); }

/* one column per profile: image rows 0..n-1, the padded buffer exactly (n + 2 pad) x W */
static void test_refine_com_profiles(void)
{
    enum { n = 40, W = 6, pad = 4, half = 4 };
    uint8_t *P = alloc((n + 2 * pad) * W);
#define PX(r, c) P[((r) + pad) * W + (c)]
    const uint8_t sym[5] = {10, 50, 100, 50, 10};
    for (int i = 0; i < 5; i++) PX(3 + i, 0) = sym[i]; /* symmetric around 5 */
    PX(10, 1) = 100, PX(11, 1) = 50;                   /* skewed: centre 10 + 50 / 150 */
    for (int r = 10; r <= 15; r++) PX(r, 2) = 255;     /* a saturated plateau of 6 rows: centre 12.5 */
    for (int r = 10; r <= 29; r++) PX(r, 3) = 255;     /* of 20 rows (several plateau steps): 19.5 */
    /* column 4: all zero (the window's 0 / 0) */
    PX(37, 5) = PX(38, 5) = PX(39, 5) = 200; /* at the image's last rows */
    ptrdiff_t k[6] = {5, 10, 10, 10, 20, 38}, cols[6] = {0, 1, 2, 3, 4, 5};
    ptrdiff_t lo[6] = {0, 0, 0, 0, 0, 0}, hi[6] = {n, n, n, n, n, n};
    Peaks out = peaks_new(6);
    ColumnsPeaks view = peaks_view(&out);
    const ColumnsPadded diff = {P, n, W, pad};
    CHECK(columns_refine_com(&diff, 6, k, cols, lo, hi, half, &view, NULL) == COLUMNS_DONE, "call");
    CHECK(out.row[0] == 5.0 && out.valid[0] && out.peak[0] == 100 && out.argmax[0] == 5 && !out.plateau[0],
          "symmetric: %.17g", out.row[0]);
    CHECK(near(out.spread[0], sqrt((2 * 10 * 4 + 2 * 50 * 1) / 220.0), 1e-15), "symmetric spread %g", out.spread[0]);
    CHECK(out.row[1] == 10.0 + 50.0 / 150.0 && out.valid[1], "skewed: %.17g", out.row[1]);
    CHECK(out.row[2] == 12.5 && out.plateau[2] && out.valid[2] && out.peak[2] == 255, "plateau: %.17g", out.row[2]);
    CHECK(out.row[3] == 19.5 && out.plateau[3] && out.valid[3], "long plateau: %.17g", out.row[3]);
    CHECK(isnan(out.row[4]) && isnan(out.spread[4]) && !out.valid[4] && out.peak[4] == 0 && out.argmax[4] == 20,
          "all zero: row %g spread %g peak %g", out.row[4], out.spread[4], out.peak[4]);
    /* rows 37..39 and the zero pad: cut by the image's end while lit (hi = n) */
    CHECK(isnan(out.row[5]) && !out.valid[5] && out.peak[5] == 200, "cut at the bottom: %g", out.row[5]);
    peaks_free(&out);
    free(P);
#undef PX
}

static void test_refine_com_intervals(void)
{
    /* an empty interval, a candidate outside its interval, a line cut by its interval's end, the
     * same line in an interval that ends where the line is dark, a line lit at the interval's
     * first row (the image's: the window reaches the pad rows) */
    enum { n = 10, W = 4, pad = 4, half = 4 };
    uint8_t *P = alloc((n + 2 * pad) * W);
    P[(pad + 8) * W + 2] = P[(pad + 9) * W + 2] = 100;
    P[(pad + 4) * W + 3] = 100, P[(pad + 5) * W + 3] = 100;
    P[(pad + 0) * W + 0] = 30;
    ptrdiff_t k[5] = {3, 12, 9, 4, 0}, cols[5] = {0, 1, 2, 3, 0};
    ptrdiff_t lo[5] = {5, 0, 0, 2, 0}, hi[5] = {5, 10, 10, 8, 10};
    Peaks out = peaks_new(5);
    ColumnsPeaks view = peaks_view(&out);
    const ColumnsPadded diff = {P, n, W, pad};
    CHECK(columns_refine_com(&diff, 5, k, cols, lo, hi, half, &view, NULL) == COLUMNS_DONE, "call");
    CHECK(out.argmax[0] == -1 && out.argmax[1] == -1 && isnan(out.peak[0]) && isnan(out.peak[1]), "empty: no candidate");
    CHECK(!out.valid[0] && !out.valid[1] && isnan(out.row[0]) && isnan(out.row[1]), "empty: no estimate");
    CHECK(out.argmax[2] == 9 && out.peak[2] == 100 && !out.valid[2] && isnan(out.row[2]), "cut: %g", out.row[2]);
    CHECK(out.valid[3] && out.row[3] == 4.5, "window past a dark interval end: %g", out.row[3]);
    CHECK(!out.valid[4] && isnan(out.row[4]) && out.argmax[4] == 0 && out.peak[4] == 30, "cut at the top: %g",
          out.row[4]);
    peaks_free(&out);
    free(P);
}

static void test_refine_com_refuses_bad_sizes(void)
{
    uint8_t *P = alloc(20 * 4);
    ptrdiff_t k[1] = {0}, cols[1] = {4}, lo[1] = {0}, hi[1] = {1};
    Peaks out = peaks_new(1);
    ColumnsPeaks view = peaks_view(&out);
    out.row[0] = -7.0;
    ColumnsError err;
    const ColumnsPadded diff = {P, 12, 4, 4};
    CHECK(columns_refine_com(&diff, 1, k, cols, lo, hi, 4, &view, &err) == COLUMNS_BAD_ARGUMENT, "column 4");
    CHECK(strstr(err.message, "column 4 (rows [0, 1)) outside the 4x12 image") != NULL, "%s", err.message);
    cols[0] = 0, hi[0] = 13;
    CHECK(columns_refine_com(&diff, 1, k, cols, lo, hi, 4, &view, NULL) == COLUMNS_BAD_ARGUMENT, "hi past the image");
    hi[0] = 1;
    const ColumnsPadded thin = {P, 18, 4, 1};
    CHECK(columns_refine_com(&thin, 1, k, cols, lo, hi, 4, &view, &err) == COLUMNS_BAD_ARGUMENT, "pad 1");
    CHECK(strstr(err.message, "pad >= max(half_width, 2)") != NULL && strstr(err.message, "20 padded rows") != NULL,
          "%s", err.message);
    CHECK(columns_refine_com(&diff, 1, k, cols, lo, hi, 0, &view, NULL) == COLUMNS_BAD_ARGUMENT, "half_width 0");
    CHECK(out.row[0] == -7.0, "nothing written");
    peaks_free(&out);
    free(P);
}

/* ------------------------------------------------------------------ resolve */

enum { RW = 40, TABLE_ROWS = 200, TABLE_TOP = 100, BAND_TOP = 150 };

/* Steps 3-5 on RW columns of a band from image row 150, rows [0, 64) searched; 1/z from a table
 * of image rows 100..299, 0.1 + 0.01 x table row (larger rows nearer). Columns start empty. */
typedef struct {
    ptrdiff_t *k, *idx;
    double *s, *thr, *noise, *table;
    Peaks first, second;
    ColumnsResolveInput in;
    ColumnsResolveParams params;
    bool *found;
    double *row, *peak;
    uint8_t *status;
    ColumnsLine line;
} Scene;

static Scene *scene_new(ptrdiff_t smooth_half)
{
    Scene *sc = alloc(sizeof *sc);
    sc->k = alloc(2 * RW * sizeof(ptrdiff_t));
    sc->idx = alloc(RW * sizeof(ptrdiff_t));
    sc->s = alloc(2 * RW * sizeof(double));
    sc->thr = alloc(RW * sizeof(double));
    sc->noise = alloc(RW * sizeof(double));
    sc->table = alloc(TABLE_ROWS * RW * sizeof(double));
    sc->first = peaks_new(RW);
    sc->second = peaks_new(RW);
    sc->found = alloc(RW);
    sc->row = alloc(RW * sizeof(double));
    sc->peak = alloc(RW * sizeof(double));
    sc->status = alloc(RW);
    for (ptrdiff_t i = 0; i < RW; i++) {
        sc->thr[i] = 10.0;
        sc->first.row[i] = sc->second.row[i] = NAN;
        sc->first.spread[i] = sc->second.spread[i] = 1.0;
    }
    for (ptrdiff_t r = 0; r < TABLE_ROWS; r++)
        for (ptrdiff_t c = 0; c < RW; c++) sc->table[r * RW + c] = 0.1 + 0.01 * (double)r;
    ColumnsResolveInput in = {RW, sc->k, sc->s, sc->thr, sc->noise, peaks_view(&sc->first), 0, sc->idx,
                              peaks_view(&sc->second), {sc->table, TABLE_ROWS, RW, TABLE_TOP}, BAND_TOP, 0, 64};
    sc->in = in;
    ColumnsResolveParams p = {0.1, 0.5, 2.5, 0.08, 3.0, 3.0, 0.015, 5, smooth_half, 4, 3};
    sc->params = p;
    ColumnsLine line = {sc->found, sc->row, sc->peak, sc->status, 0, 0};
    sc->line = line;
    return sc;
}

static void scene_free(Scene *sc)
{
    free(sc->k), free(sc->idx), free(sc->s), free(sc->thr), free(sc->noise), free(sc->table);
    peaks_free(&sc->first), peaks_free(&sc->second);
    free(sc->found), free(sc->row), free(sc->peak), free(sc->status), free(sc);
}

/* the first candidate of column i: a line at band row r, amplitude v (smoothed and own) */
static void first_line(Scene *sc, ptrdiff_t i, double r, double v)
{
    sc->k[i] = (ptrdiff_t)floor(r + 0.5), sc->s[i] = v;
    sc->first.row[i] = r, sc->first.peak[i] = v, sc->first.valid[i] = true;
}

/* a second candidate in column i (columns in increasing order) */
static void second_line(Scene *sc, ptrdiff_t i, double r, double v)
{
    ptrdiff_t j = sc->in.m++;
    sc->idx[j] = i;
    sc->k[RW + i] = (ptrdiff_t)floor(r + 0.5), sc->s[RW + i] = v;
    sc->second.row[j] = r, sc->second.peak[j] = v, sc->second.valid[j] = true;
}

static ColumnsResult scene_resolve(Scene *sc) { return columns_resolve(&sc->in, &sc->params, &sc->line, NULL); }

static double image_row(double band_row) { return band_row + BAND_TOP; }

static void test_resolve_measures_a_straight_line_as_it_is(void)
{
    for (ptrdiff_t smooth = 0; smooth <= 6; smooth += 6) {
        Scene *sc = scene_new(smooth);
        for (ptrdiff_t i = 0; i < RW; i++) first_line(sc, i, 20.25 + 0.125 * (double)i, 100.0);
        CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
        int all = 1;
        for (ptrdiff_t i = 0; i < RW; i++)
            all &= sc->found[i] && sc->status[i] == COLUMNS_OK && sc->peak[i] == 100.0
                   && near(sc->row[i], image_row(20.25 + 0.125 * (double)i), 1e-6);
        CHECK(all, "smooth_half %td", smooth);
        CHECK(sc->line.seen_first == 20 && sc->line.seen_last == 26, "seen %td..%td", sc->line.seen_first,
              sc->line.seen_last);
        scene_free(sc);
    }
}

static void test_resolve_without_a_line(void)
{
    Scene *sc = scene_new(6);
    sc->in.t1 = 48;
    for (ptrdiff_t i = 0; i < RW; i++) sc->s[i] = 2.0, sc->first.peak[i] = 2.0; /* below the threshold */
    sc->noise[7] = 5.0;                                                          /* >= 2 s and >= min_peak */
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int none = 1;
    for (ptrdiff_t i = 0; i < RW; i++) none &= !sc->found[i] && sc->status[i] == (i == 7 ? COLUMNS_UNLIT : COLUMNS_NO_RETURN);
    CHECK(none, "no return, and unlit where the unlit frame was brighter");
    CHECK(sc->line.seen_first == 48 && sc->line.seen_last == -1, "seen (t1, -1): %td %td", sc->line.seen_first,
          sc->line.seen_last);
    scene_free(sc);
}

static void test_resolve_keeps_runs_of_min_run_columns(void)
{
    Scene *sc = scene_new(0);
    for (ptrdiff_t i = 2; i < 6; i++) first_line(sc, i, 30.0, 100.0);   /* 4 columns: too short */
    for (ptrdiff_t i = 10; i < 15; i++) first_line(sc, i, 30.0, 100.0); /* 5: a line */
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    for (ptrdiff_t i = 2; i < 6; i++)
        CHECK(!sc->found[i] && sc->status[i] == COLUMNS_REJECTED, "column %td: a line, not measurable", i);
    for (ptrdiff_t i = 10; i < 15; i++) CHECK(sc->found[i] && sc->row[i] == image_row(30.0), "column %td", i);
    CHECK(sc->status[0] == COLUMNS_NO_RETURN && sc->status[20] == COLUMNS_NO_RETURN, "elsewhere no return");
    scene_free(sc);
}

static void test_resolve_separates_surfaces_at_a_depth_jump(void)
{
    Scene *sc = scene_new(6);
    for (ptrdiff_t i = 0; i < RW; i++) first_line(sc, i, i < 20 ? 10.0 + 0.01 * (double)i : 45.0, 100.0);
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int kept = 1;
    for (ptrdiff_t i = 0; i < RW; i++)
        kept &= sc->found[i] && near(sc->row[i], image_row(i < 20 ? 10.0 + 0.01 * (double)i : 45.0), 1e-6);
    CHECK(kept, "the fit never pulls a column towards the other surface");
    scene_free(sc);
}

static void test_resolve_outliers(void)
{
    /* one column 10 rows off a line (the jump step there is 0.08 x 0.9 / 0.01 = 7.2 rows) */
    for (ptrdiff_t smooth = 0; smooth <= 6; smooth += 6) {
        Scene *sc = scene_new(smooth);
        for (ptrdiff_t i = 0; i < RW; i++) first_line(sc, i, i == 15 ? 40.0 : 30.0, 100.0);
        CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
        if (smooth) /* left out of the fit, reports the fit */
            CHECK(sc->found[15] && sc->status[15] == COLUMNS_OK && near(sc->row[15], image_row(30.0), 1e-6),
                  "fit: %g", sc->row[15]);
        else
            CHECK(!sc->found[15] && sc->status[15] == COLUMNS_REJECTED, "no fit: rejected");
        CHECK(sc->found[14] && sc->found[16] && near(sc->row[16], image_row(30.0), 1e-6), "neighbours");
        scene_free(sc);
    }
}

static void test_resolve_fills_short_gaps_where_the_line_was_seen(void)
{
    /* runs of >= 5 columns with gaps of 1 dark column (6), 2 dark columns (12, 13), 3 columns where
     * the line is seen but too wide (19..21), and 4 such columns (27..30) */
    Scene *sc = scene_new(6);
    for (ptrdiff_t i = 0; i < RW; i++) first_line(sc, i, 30.0 + 0.5 * (double)i, 100.0);
    const ptrdiff_t dark[3] = {6, 12, 13}, wide[7] = {19, 20, 21, 27, 28, 29, 30};
    for (int j = 0; j < 3; j++) sc->s[dark[j]] = 2.0, sc->first.peak[dark[j]] = 2.0;
    for (int j = 0; j < 7; j++) sc->first.spread[wide[j]] = 3.0;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->found[6] && sc->status[6] == COLUMNS_OK && sc->peak[6] == 0.0 && near(sc->row[6], image_row(33.0), 1e-6),
          "one column: %g", sc->row[6]);
    CHECK(!sc->found[12] && !sc->found[13] && sc->status[12] == COLUMNS_NO_RETURN && sc->status[13] == COLUMNS_NO_RETURN,
          "two dark columns: not filled");
    for (ptrdiff_t i = 19; i <= 21; i++)
        CHECK(sc->found[i] && sc->status[i] == COLUMNS_OK && sc->peak[i] == 0.0
              && near(sc->row[i], image_row(30.0 + 0.5 * (double)i), 1e-6), "seen gap column %td: %g", i, sc->row[i]);
    for (ptrdiff_t i = 27; i <= 30; i++)
        CHECK(!sc->found[i] && sc->status[i] == COLUMNS_REJECTED, "longer than max_gap: column %td", i);
    int measured = 1;
    for (ptrdiff_t i = 0; i < RW; i++)
        if (!(i == 6 || (i >= 12 && i <= 13) || (i >= 19 && i <= 21) || (i >= 27 && i <= 30)))
            measured &= sc->found[i] && sc->peak[i] == 100.0 && near(sc->row[i], image_row(30.0 + 0.5 * (double)i), 1e-6);
        else
            measured &= sc->peak[i] != 100.0 || !sc->found[i];
    CHECK(measured, "the other columns measured");
    scene_free(sc);
}

static void test_resolve_counts_dim_columns_only_between_bright_ones(void)
{
    Scene *sc = scene_new(0);
    for (ptrdiff_t i = 0; i < RW; i++) first_line(sc, i, 30.0, i == 0 || i == 20 ? 20.0 : 100.0);
    for (ptrdiff_t i = 0; i < RW; i++) sc->s[i] = 100.0; /* own peak 20 < 0.5 x the smoothed 100 */
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(!sc->found[0] && sc->status[0] == COLUMNS_REJECTED, "a dim column at a run's end");
    CHECK(sc->found[20], "a dim column inside a run");
    scene_free(sc);
}

static void test_resolve_prefers_the_farther_of_two_continuous_lines(void)
{
    /* a glossy floor's mirror image (row 50, nearer) beside the line (row 30) in every column,
     * brighter than the line in columns 10..19: the line is kept everywhere */
    Scene *sc = scene_new(0);
    for (ptrdiff_t i = 0; i < RW; i++) {
        int ghost_brighter = i >= 10 && i < 20;
        first_line(sc, i, ghost_brighter ? 50.0 : 30.0, ghost_brighter ? 120.0 : 100.0);
        second_line(sc, i, ghost_brighter ? 30.0 : 50.0, ghost_brighter ? 100.0 : 80.0);
    }
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int line = 1;
    for (ptrdiff_t i = 0; i < RW; i++) line &= sc->found[i] && sc->row[i] == image_row(30.0);
    CHECK(line, "the farther line in every column");
    CHECK(sc->line.seen_first == 30 && sc->line.seen_last == 50, "seen includes the ghost's run: %td..%td",
          sc->line.seen_first, sc->line.seen_last);
    scene_free(sc);
}

static void test_resolve_keeps_the_nearer_line_at_an_occlusion_edge(void)
{
    /* an object (row 50) in columns 0..10 in front of a wall (row 30) seen in columns 10..39:
     * in column 10 the nearer line continues alone on its side, so it wins */
    Scene *sc = scene_new(0);
    for (ptrdiff_t i = 0; i <= 10; i++) first_line(sc, i, 50.0, 100.0);
    for (ptrdiff_t i = 11; i < RW; i++) first_line(sc, i, 30.0, 100.0);
    second_line(sc, 10, 30.0, 90.0);
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->found[10] && sc->row[10] == image_row(50.0), "column 10: %g", sc->row[10]);
    /* the same column with the object's line alone in only 3 neighbours: the farther wins */
    sc->first.row[6] = sc->first.peak[6] = sc->s[6] = 0.0, sc->first.valid[6] = false;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->row[10] == image_row(30.0), "column 10 without the occlusion: %g", sc->row[10]);
    scene_free(sc);
}

/* 1/z = iz + 0.022 (image row - image_row(30)): a range that changes by 0.022 / iz per row at the
 * line (6.7 % per row at 3 m, as the device's geometry far away; 2.2 % at 1 m) */
static void scene_depth(Scene *sc, double iz)
{
    for (ptrdiff_t r = 0; r < TABLE_ROWS; r++)
        for (ptrdiff_t c = 0; c < RW; c++)
            sc->table[r * RW + c] = iz + 0.022 * ((double)(r + TABLE_TOP) - image_row(30.0));
}

/* a dim line (peak 4, noise level 1.5) in columns [a, b) at band row r + the speckle's scatter
 * (+-0.3 rows, alternating) */
static void dim_line(Scene *sc, ptrdiff_t a, ptrdiff_t b, double r)
{
    for (ptrdiff_t i = a; i < b; i++) {
        first_line(sc, i, r + (i % 2 ? 0.3 : -0.3), 4.0);
        sc->thr[i] = 3.0, sc->noise[i] = 1.5;
    }
}

static void test_resolve_rejects_a_dim_line_that_a_fit_bridges_to_a_bright_one(void)
{
    /* at 3 m: a bright surface (peak 60) in columns 0..19 at band row 30, a dark one 1.1 rows
     * lower (7 % nearer: less than the 8 % that separates surfaces) in columns 20..39. Without
     * the gate, the fit carries the bright line into the dark columns: more than 5 % off */
    Scene *sc = scene_new(6);
    scene_depth(sc, 1.0 / 3.0);
    for (ptrdiff_t i = 0; i < 20; i++) first_line(sc, i, 30.0, 60.0);
    dim_line(sc, 20, RW, 31.1);
    sc->params.max_range_sigma = INFINITY;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->status[20] == COLUMNS_OK && fabs(sc->row[20] - image_row(31.1)) * 0.066 > 0.05,
          "without the gate column 20 is a gross error: row %g", sc->row[20]);
    sc->params.max_range_sigma = 0.015;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int trusted = 1, bright = 1;
    for (ptrdiff_t i = 0; i < RW; i++) {
        double truth = image_row(i < 20 ? 30.0 : 31.1);
        if (sc->status[i] == COLUMNS_OK) trusted &= fabs(sc->row[i] - truth) * 0.066 <= 0.05;
        else trusted &= sc->status[i] == COLUMNS_REJECTED && sc->found[i]; /* seen, not trusted */
    }
    for (ptrdiff_t i = 0; i < 15; i++) bright &= sc->status[i] == COLUMNS_OK;
    CHECK(trusted, "every range within 5 %%, the others REJECTED");
    CHECK(sc->status[20] == COLUMNS_REJECTED && sc->status[21] == COLUMNS_REJECTED, "the bridged columns");
    CHECK(bright, "the bright surface away from the edge is kept");
    scene_free(sc);
}

static void test_resolve_rejects_a_runs_end_that_its_own_row_contradicts(void)
{
    /* at 3 m: a line (peak 20) in columns 0..19 ends; column 20, in the shadow behind it, shows a
     * weak peak 1.5 rows off (an outlier: left out of the fit, it would report the fit, a range
     * where there is none) */
    Scene *sc = scene_new(6);
    scene_depth(sc, 1.0 / 3.0);
    for (ptrdiff_t i = 0; i < 20; i++) first_line(sc, i, 30.0, 20.0), sc->thr[i] = 3.0, sc->noise[i] = 1.0;
    first_line(sc, 20, 31.5, 3.0);
    sc->thr[20] = 3.0, sc->noise[20] = 1.0;
    sc->params.max_range_sigma = INFINITY;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->status[20] == COLUMNS_OK && near(sc->row[20], image_row(30.0), 1e-6), "without the gate: the fit, %g",
          sc->row[20]);
    sc->params.max_range_sigma = 0.015;
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    CHECK(sc->status[20] == COLUMNS_REJECTED, "REJECTED: %d", sc->status[20]);
    CHECK(sc->status[10] == COLUMNS_OK, "the line itself is kept");
    scene_free(sc);
}

static void test_resolve_keeps_a_dim_line_near_by(void)
{
    /* the same dim line at 1 m, where a row is worth 2.2 %: its fit is good to ~0.6 % */
    Scene *sc = scene_new(6);
    scene_depth(sc, 1.0);
    dim_line(sc, 0, RW, 30.0);
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int kept = 1;
    for (ptrdiff_t i = 0; i < RW; i++) kept &= sc->status[i] == COLUMNS_OK && fabs(sc->row[i] - image_row(30.0)) < 0.3;
    CHECK(kept, "every column measured");
    /* at 3 m the same line is not good to 5 %: REJECTED */
    scene_depth(sc, 1.0 / 3.0);
    CHECK(scene_resolve(sc) == COLUMNS_DONE, "call");
    int rejected = 1;
    for (ptrdiff_t i = 0; i < RW; i++) rejected &= sc->status[i] == COLUMNS_REJECTED;
    CHECK(rejected, "at 3 m: every column REJECTED");
    scene_free(sc);
}

static void test_resolve_refuses_bad_arguments(void)
{
    Scene *sc = scene_new(6);
    ColumnsError err;
    sc->row[0] = -3.0;
    sc->params.min_run = 0;
    CHECK(columns_resolve(&sc->in, &sc->params, &sc->line, &err) == COLUMNS_BAD_ARGUMENT, "min_run 0");
    CHECK(strstr(err.message, "resolve: need >= 2 columns") != NULL, "%s", err.message);
    sc->params.min_run = 5, sc->params.max_range_sigma = 0.0;
    CHECK(scene_resolve(sc) == COLUMNS_BAD_ARGUMENT, "max_range_sigma 0");
    sc->params.max_range_sigma = NAN;
    CHECK(scene_resolve(sc) == COLUMNS_BAD_ARGUMENT, "max_range_sigma NaN");
    sc->params.max_range_sigma = 0.015, sc->in.t1 = 0;
    CHECK(scene_resolve(sc) == COLUMNS_BAD_ARGUMENT, "t1 <= t0");
    sc->in.t1 = 64, sc->in.cols = 1, sc->in.inv_depth.cols = 1;
    CHECK(scene_resolve(sc) == COLUMNS_BAD_ARGUMENT, "one column");
    sc->in.cols = RW, sc->in.inv_depth.cols = RW;
    second_line(sc, 5, 30.0, 50.0);
    second_line(sc, 5, 31.0, 50.0);
    CHECK(columns_resolve(&sc->in, &sc->params, &sc->line, &err) == COLUMNS_BAD_ARGUMENT, "repeated column");
    CHECK(strstr(err.message, "idx2 must be increasing columns in [0, 40)") != NULL, "%s", err.message);
    sc->in.m = 0, sc->in.inv_depth.cols = RW - 1;
    CHECK(scene_resolve(sc) == COLUMNS_BAD_ARGUMENT, "a table of other columns");
    CHECK(sc->row[0] == -3.0, "nothing written");
    scene_free(sc);
}

static void test_running_median(void)
{
    const double x[7] = {5.0, 1.0, 4.0, 2.0, 3.0, 9.0, 7.0};
    const bool all[7] = {1, 1, 1, 1, 1, 1, 1}, some[7] = {1, 0, 1, 1, 0, 1, 1};
    double med[7];
    columns_running_median(x, all, 7, med);
    CHECK(med[2] == 3.0 && med[3] == 3.0 && med[4] == 4.0, "five: %g %g %g", med[2], med[3], med[4]);
    CHECK(med[0] == 4.0 && med[1] == 3.0 && med[6] == 7.0, "edges: %g %g %g", med[0], med[1], med[6]);
    columns_running_median(x, some, 7, med);
    CHECK(isnan(med[1]) && isnan(med[4]), "not found: NaN");
    CHECK(med[2] == 4.0 && med[3] == 4.0 && med[5] == 7.0, "found neighbours: %g %g %g", med[2], med[3], med[5]);
    CHECK(med[0] == 4.5 && med[6] == 8.0, "the mean of the middle two: %g %g", med[0], med[6]);
}

static void test_run_length(void)
{
    const bool mask[9] = {1, 1, 0, 1, 0, 0, 1, 1, 1};
    const ptrdiff_t want[9] = {2, 2, 0, 1, 0, 0, 3, 3, 3};
    ptrdiff_t *out = alloc(9 * sizeof(ptrdiff_t));
    columns_run_length(mask, 9, out);
    CHECK(memcmp(out, want, sizeof want) == 0, "%td %td %td ... %td", out[0], out[1], out[2], out[8]);
    columns_run_length(mask, 0, out); /* nothing to read or write */
    free(out);
}

/* ------------------------------------------------------------------ triangulation */

static void test_triangulate_statuses_and_interpolation(void)
{
    /* a 3-row x 2-column ray table from image row 10; the plane y = 0.1 (a laser below the camera),
     * depths in [0.5, 1.5] */
    const double xn[6] = {-0.5, 0.5, -0.5, 0.5, -0.5, 0.5}, yn[6] = {0.0, 0.0, 0.05, 0.05, 0.25, 0.25};
    const ColumnsRays rays = {xn, yn, 3, 2, 10};
    const ColumnsPlane plane = {0.0, 1.0, 0.0, 0.1, 0.5, 1.5, 1e-6, 0, 1, 2, 3, 4};
    const double rows[6] = {11.0, 11.5, 12.0, 10.0, 9.99, NAN};
    const ptrdiff_t cols[6] = {1, 0, 0, 0, 0, 1};
    double *pts = alloc(18 * sizeof(double)), *depth = alloc(6 * sizeof(double));
    uint8_t *status = alloc(6);
    CHECK(columns_triangulate(&rays, &plane, 6, rows, cols, pts, depth, status, NULL) == COLUMNS_DONE, "call");
    CHECK(status[0] == 4 && isnan(depth[0]) && isnan(pts[2]), "y 0.05: 2 m, too far: %d", status[0]);
    double y = 0.05 * 0.5 + 0.25 * 0.5; /* halfway between the table's rows 1 and 2 */
    CHECK(status[1] == 0 && depth[1] == 0.1 / y && pts[3] == -0.5 * depth[1] && pts[4] == y * depth[1]
          && pts[5] == depth[1], "between rows: %d %.17g", status[1], depth[1]);
    CHECK(status[2] == 3 && isnan(depth[2]), "the last row, y 0.25: 0.4 m, too close: %d", status[2]);
    CHECK(status[3] == 2 && isnan(depth[3]), "y 0: beyond the horizon: %d", status[3]);
    CHECK(status[4] == 1 && status[5] == 1, "outside the table, NaN: invalid pixel: %d %d", status[4], status[5]);
    free(pts), free(depth), free(status);
}

static void test_triangulate_rounds_each_operation(void)
{
    /* against the same formula with every product rounded on its own (volatile): a kernel built
     * without -ffp-contract=off fuses them on ARM64 and differs here */
    enum { T = 4, C = 3, N = 500 };
    double xn[T * C], yn[T * C];
    for (int i = 0; i < T * C; i++) xn[i] = (double)rnd() / 4294967296.0 - 0.5, yn[i] = 0.1 + (double)rnd() / 4294967296.0;
    const ColumnsRays rays = {xn, yn, T, C, 0};
    const ColumnsPlane plane = {0.013, 0.9, 0.1, 0.07, 0.0, 1e9, 1e-9, 0, 1, 2, 3, 4};
    double *rows = alloc(N * sizeof(double)), *pts = alloc(3 * N * sizeof(double)), *depth = alloc(N * sizeof(double));
    ptrdiff_t *cols = alloc(N * sizeof(ptrdiff_t));
    uint8_t *status = alloc(N);
    for (int i = 0; i < N; i++) rows[i] = (double)rnd() / 4294967296.0 * (T - 1), cols[i] = (ptrdiff_t)(rnd() % C);
    CHECK(columns_triangulate(&rays, &plane, N, rows, cols, pts, depth, status, NULL) == COLUMNS_DONE, "call");
    int same = 1;
    for (int i = 0; i < N; i++) {
        ptrdiff_t r0 = (ptrdiff_t)rows[i] < T - 2 ? (ptrdiff_t)rows[i] : T - 2, a = r0 * C + cols[i], b = a + C;
        volatile double t = rows[i] - (double)r0, u = 1.0 - t;
        volatile double xa = xn[a] * u, xb = xn[b] * t, ya = yn[a] * u, yb = yn[b] * t;
        volatile double x = xa + xb, y = ya + yb;
        volatile double px = plane.nx * x, py = plane.ny * y;
        volatile double dx = px + py, denom = dx + plane.nz, d = plane.distance / denom;
        volatile double X = x * d, Y = y * d;
        same &= status[i] == 0 && depth[i] == d && pts[3 * i] == X && pts[3 * i + 1] == Y && pts[3 * i + 2] == d;
    }
    CHECK(same, "every product and sum rounded once, in the numpy order");
    free(rows), free(pts), free(depth), free(cols), free(status);
}

static void test_triangulate_refuses_bad_arguments(void)
{
    const double xn[4] = {0}, yn[4] = {0};
    const ColumnsPlane plane = {0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 1e-9, 0, 1, 2, 3, 4};
    const double rows[1] = {0.0};
    const ptrdiff_t cols[1] = {5};
    double pts[3], depth[1] = {-1.0};
    uint8_t status[1];
    ColumnsError err;
    const ColumnsRays rays = {xn, yn, 2, 2, 0}, empty = {xn, yn, 0, 2, 0};
    CHECK(columns_triangulate(&rays, &plane, 1, rows, cols, pts, depth, status, &err) == COLUMNS_BAD_ARGUMENT, "col");
    CHECK(strstr(err.message, "column 5 outside the table's 2 columns") != NULL, "%s", err.message);
    CHECK(columns_triangulate(&empty, &plane, 0, rows, cols, pts, depth, status, &err) == COLUMNS_BAD_ARGUMENT, "rows");
    CHECK(strstr(err.message, "the ray table has no rows") != NULL, "%s", err.message);
    CHECK(depth[0] == -1.0, "nothing written");
}

/* Columns at angles j / 1000 rad in a random order (every run length, down to one column a
 * run), ranges 2 + angle: each ray inside them interpolates 2 + its angle from the two columns
 * around it, whatever order they came in, and has the row of the nearer one. */
static void test_scan_rays_orders_shuffled_columns_by_angle(void)
{
    const ptrdiff_t sizes[] = {1, 2, 3, 4, 5, 8, 33, 64, 3000};
    for (size_t t = 0; t < sizeof sizes / sizeof sizes[0]; t++) {
        const ptrdiff_t n = sizes[t], m = 97;
        double *angle = alloc((size_t)n * sizeof *angle), *range = alloc((size_t)n * sizeof *range);
        double *quality = alloc((size_t)n * sizeof *quality), *row = alloc((size_t)n * sizeof *row);
        double *grid = alloc((size_t)m * sizeof *grid), *rout = alloc((size_t)m * sizeof *rout);
        double *rowout = alloc((size_t)m * sizeof *rowout);
        uint8_t *qout = alloc((size_t)m);
        for (ptrdiff_t j = 0; j < n; j++) angle[j] = (double)j / 1000;
        for (ptrdiff_t j = n - 1; j > 0; j--) { /* Fisher-Yates */
            const ptrdiff_t k = (ptrdiff_t)(rnd() % (uint32_t)(j + 1));
            const double a = angle[j];
            angle[j] = angle[k], angle[k] = a;
        }
        for (ptrdiff_t j = 0; j < n; j++) range[j] = 2 + angle[j], quality[j] = 100, row[j] = angle[j] * 1000;
        const double top = n > 1 ? (double)(n - 1) / 1000 : 1e-3;
        for (ptrdiff_t i = 0; i < m; i++) grid[i] = top * (double)i / (double)(m - 1);
        CHECK(columns_scan_rays(n, angle, range, quality, row, m, grid, 3.0, 0.05, rout, qout, rowout, NULL)
                  == COLUMNS_DONE, "n %td", n);
        int wrong = 0;
        for (ptrdiff_t i = 0; i < m; i++) {
            if (n <= 2) { /* fewer than 3 columns bridge one grid step: a ray on a column or beyond */
                const int on = i == 0 || (n == 2 && i == m - 1);
                wrong += on ? !(rout[i] == 2 + grid[i] && rowout[i] == (double)(i > 0)) : !(rout[i] == INFINITY && isnan(rowout[i]));
                continue;
            }
            const double at = grid[i] * 1000, lo = floor(at), below = at - lo, above = lo + 1 - at;
            const int row_ok = fabs(below - above) < 1e-9 ? (near(rowout[i], lo, 1e-9) || near(rowout[i], lo + 1, 1e-9))
                                                          : near(rowout[i], below <= above ? lo : lo + 1, 1e-9);
            wrong += !near(rout[i], 2 + grid[i], 1e-12) || !row_ok || qout[i] != 100;
        }
        CHECK(wrong == 0, "n %td: %d of %td rays wrong", n, wrong, m);
        free(angle), free(range), free(quality), free(row), free(grid), free(rout), free(rowout), free(qout);
    }
}

static void test_scan_rays_refuses_bad_arguments(void)
{
    double nan3[3] = {NAN, NAN, NAN}, z[3] = {0, 0, 0}, grid[2] = {0, 1}, out[2], rows[2];
    uint8_t q[2];
    ColumnsError err;
    CHECK(columns_scan_rays(3, nan3, z, z, z, 2, grid, 3.0, 0.05, out, q, rows, &err) == COLUMNS_BAD_ARGUMENT, "%s",
          "no finite angle");
    CHECK(strstr(err.message, "no column has a finite angle") != NULL, "%s", err.message);
    CHECK(columns_scan_rays(3, z, z, z, z, 1, grid, 3.0, 0.05, out, q, rows, &err) == COLUMNS_BAD_ARGUMENT, "%s",
          "one ray");
    CHECK(columns_scan_rays(0, z, z, z, z, 2, grid, 3.0, 0.05, out, q, rows, &err) == COLUMNS_BAD_ARGUMENT, "%s",
          "no column");
    CHECK(columns_scan_rays(3, z, z, z, z, 2, grid, -1.0, 0.05, out, q, rows, &err) == COLUMNS_BAD_ARGUMENT, "%s",
          "a negative gap");
}

static void test_scan_timing_line_fallback_and_rounding(void)
{
    enum { N = 1640 };
    static double t[N];
    const double t0 = 2592000123456789.0; /* a clock 30 days on */
    for (int i = 0; i < N; i++) t[i] = i % 7 == 3 ? NAN : t0 + 1718.0 * i;
    ColumnsScanTiming out;
    CHECK(columns_scan_timing(N, t, 0, &out, NULL) == COLUMNS_DONE, "%s", "a line");
    CHECK(out.first_ns == 2592000123456789 && out.interval_ns == 1718 && out.residual_ns == 0.0,
          "first %lld, interval %lld, residual %g", (long long)out.first_ns, (long long)out.interval_ns, out.residual_ns);
    for (int i = 0; i < N; i++) t[i] = i == 5 ? 100.0 : INFINITY; /* one time: the fallback */
    CHECK(columns_scan_timing(N, t, 2.5, &out, NULL) == COLUMNS_DONE && out.first_ns == 2 && out.interval_ns == 0,
          "fallback 2.5 -> %lld (ties to even: 2)", (long long)out.first_ns);
    double two[2] = {10.0, 13.5}; /* slope 3.5 -> 4 (ties to even), then the offset: mean(10, 9.5) */
    CHECK(columns_scan_timing(2, two, 0, &out, NULL) == COLUMNS_DONE && out.interval_ns == 4 && out.first_ns == 10
              && out.residual_ns == 0.25,
          "interval %lld, first %lld, residual %g", (long long)out.interval_ns, (long long)out.first_ns, out.residual_ns);
    ColumnsError err;
    CHECK(columns_scan_timing(1, two, NAN, &out, &err) == COLUMNS_BAD_ARGUMENT, "%s", "a NaN fallback");
    CHECK(strstr(err.message, "fallback_ns") != NULL, "%s", err.message);
}

static void test_spans(void)
{
    const bool m[] = {1, 1, 0, 0, 1, 0, 0, 0, 1, 1};
    ptrdiff_t sp[10] = {0};
    CHECK(columns_spans(m, 10, 3, sp) == 2 && sp[0] == 0 && sp[1] == 5 && sp[2] == 8 && sp[3] == 10,
          "join 3: %td-%td, %td-%td", sp[0], sp[1], sp[2], sp[3]);
    CHECK(columns_spans(m, 10, 1, sp) == 3 && sp[2] == 4 && sp[3] == 5, "join 1: %td-%td", sp[2], sp[3]);
    CHECK(columns_spans(m, 10, 4, sp) == 1 && sp[0] == 0 && sp[1] == 10, "join 4: %td-%td", sp[0], sp[1]);
    CHECK(columns_spans(m, 0, 4, sp) == 0, "%s", "no columns");
    const bool alt[] = {1, 0, 1, 0, 1}; /* the most spans a mask can have: (n + 1) / 2 */
    const ptrdiff_t k = columns_spans(alt, 5, 0, sp);
    CHECK(k == 3 && sp[4] == 4 && sp[5] == 5, "alternating: %td spans", k);
}

/* Against a direct reading of columns_near_rows' definition, on random frames at each step. */
static void test_near_rows_definition(void)
{
    enum { H = 23, W = 9 };
    uint8_t lit[H * W], unlit[H * W], mask[H * W], above[W], below[W], pair[W];
    for (int trial = 0; trial < 50; trial++) {
        for (int i = 0; i < H * W; i++) lit[i] = (uint8_t)rnd(), unlit[i] = rnd() % 4 ? (uint8_t)rnd() : 255;
        for (int i = 0; i < H * W; i++) mask[i] = rnd() % 3 ? 255 : 0;
        const ptrdiff_t step = 1 + trial % 3, r0 = trial % 5, r1 = r0 + 1 + (ptrdiff_t)(rnd() % (uint32_t)(H - r0));
        const ptrdiff_t c0 = trial % 4, c1 = c0 + 1 + (ptrdiff_t)(rnd() % (uint32_t)(W - c0));
        CHECK(columns_near_rows(lit, unlit, H, W, mask, r0, r1, step, c0, c1, above, below, pair, NULL) == COLUMNS_DONE,
              "trial %d", trial);
        int wrong = 0;
        for (ptrdiff_t c = c0; c < c1; c++) {
            int a = 0, b = 0, p = 0, last = -1;
            for (ptrdiff_t r = r0, k = 0; r < r1; r += step, k++) {
                const int l = lit[r * W + c], u = unlit[r * W + c], mk = mask[k * W + c];
                const int up = (l > u ? l - u : 0) & mk, down = (u > l ? u - l : 0) & mk, seen = u & mk;
                a = up > a ? up : a, b = down > b ? down : b;
                if (last >= 0 && (last < seen ? last : seen) > p) p = last < seen ? last : seen;
                last = u & mk;
            }
            wrong += above[c - c0] != a || below[c - c0] != b || pair[c - c0] != p;
        }
        CHECK(wrong == 0, "trial %d: %d columns wrong", trial, wrong);
    }
    ColumnsError err;
    CHECK(columns_near_rows(lit, unlit, H, W, mask, 5, 5, 2, 0, 1, above, below, pair, &err) == COLUMNS_BAD_ARGUMENT,
          "%s", "no rows");
    CHECK(strstr(err.message, "rows 5-5 of 23") != NULL, "%s", err.message);
    CHECK(columns_near_rows(lit, unlit, H, W, mask, 0, 5, 2, 3, 10, above, below, pair, &err) == COLUMNS_BAD_ARGUMENT,
          "%s", "columns beyond the frame");
}

static void test_scan_plane(void)
{
    /* the scan frame: x forward = camera z, y left = camera -x, origin 0.1 m along camera y */
    const double rot[9] = {0, 0, 1, -1, 0, 0, 0, -1, 0}, origin[3] = {0, 0.1, 0};
    const double pts[9] = {0, 0.1, 2, -2, 0.1, 2, NAN, NAN, NAN};
    double angle[3], range[3];
    columns_scan_plane(3, pts, rot, origin, angle, range);
    CHECK(angle[0] == 0 && range[0] == 2, "ahead: %g rad, %g m", angle[0], range[0]);
    CHECK(near(angle[1], M_PI / 4, 1e-15) && near(range[1], 2 * sqrt(2), 1e-15), "left: %g rad, %g m", angle[1], range[1]);
    CHECK(isnan(angle[2]) && isnan(range[2]), "%s", "NaN stays NaN");
}

static void (*const TESTS[])(void) = {
    test_noise_level_is_the_largest_box_mean_of_the_negative_difference,
    test_noise_level_rounds_every_box_sum_as_opencv,
    test_band_difference_is_the_saturation_aware_difference_and_its_blur,
    test_image_passes_refuse_bad_sizes,
    test_moved_marks_the_groups_whose_blocks_changed,
    test_moved_raises_the_bars_by_the_unlit_bands_noise,
    test_moved_refuses_bad_sizes,
    test_candidates_find_the_largest_and_a_separated_second_peak,
    test_candidates_take_the_first_of_equal_rows_and_the_unsmoothed_maximum,
    test_candidates_in_a_band_whose_last_block_is_partial,
    test_no_second_candidate_on_the_flank_of_a_line_near_the_band_top,
    test_candidates_in_a_one_row_band,
    test_candidates_refuse_bad_sizes,
    test_refine_com_profiles,
    test_refine_com_intervals,
    test_refine_com_refuses_bad_sizes,
    test_resolve_measures_a_straight_line_as_it_is,
    test_resolve_without_a_line,
    test_resolve_keeps_runs_of_min_run_columns,
    test_resolve_separates_surfaces_at_a_depth_jump,
    test_resolve_outliers,
    test_resolve_fills_short_gaps_where_the_line_was_seen,
    test_resolve_counts_dim_columns_only_between_bright_ones,
    test_resolve_prefers_the_farther_of_two_continuous_lines,
    test_resolve_keeps_the_nearer_line_at_an_occlusion_edge,
    test_resolve_rejects_a_dim_line_that_a_fit_bridges_to_a_bright_one,
    test_resolve_rejects_a_runs_end_that_its_own_row_contradicts,
    test_resolve_keeps_a_dim_line_near_by,
    test_resolve_refuses_bad_arguments,
    test_running_median,
    test_run_length,
    test_triangulate_statuses_and_interpolation,
    test_triangulate_rounds_each_operation,
    test_triangulate_refuses_bad_arguments,
    test_scan_rays_orders_shuffled_columns_by_angle,
    test_scan_rays_refuses_bad_arguments,
    test_scan_timing_line_fallback_and_rounding,
    test_spans,
    test_near_rows_definition,
    test_scan_plane,
};

int main(void)
{
    for (size_t i = 0; i < sizeof TESTS / sizeof TESTS[0]; i++) TESTS[i]();
    printf("kernel unit tests: %d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
