/* AVX2 kernels for the splat and its adjoint gather (the fixed 8 x 8 pixel box, and larger
 * footprints over each row's chord of the ellipse), for the surface jets at a packet's hits, and
 * for the adjoint of a photon's surface hit w.r.t. the 4 x 4 heights around it.
 *
 * Built as the extension module operators.kernels._simd (setup.py; optional: without a C compiler the
 * package installs and the numba kernels do this work). The numba kernels call these functions
 * by symbol name (operators/kernels/simd.py) when sfc_simd_supported() says the CPU has AVX2 and FMA.
 *
 * Same arithmetic as operators/splat/native.py, float64 throughout: the box's rows are 8
 * pixels, two 4-lane vectors. A pixel at column offset rx and row offset ry from the photon
 * (pixels) has falloff u = max(1 - ((q00 rx + 2 q01 ry) rx + q11 ry^2), 0) and Silverman weight
 * u^2. The gather keeps per-lane accumulators across the rows (rx is fixed per lane, ry per row)
 * and forms the moments in rx at the end, instead of reducing every row.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define SFC_X86 1
#define SFC_AVX2 __attribute__((target("avx2,fma")))
#endif

/* Version of the signatures of this file's, heightfield_photons.c's and mesh_events.c's functions;
 * operators/kernels/extension.py refuses a build whose version differs
 * from its own (a stale build after the sources changed: pip install -e . rebuilds it). */
int sfc_abi_version(void) { return 13; }

/* 1 when the CPU runs the AVX2 / FMA kernels below, else 0 (they must not be called). */
int sfc_simd_supported(void) {
#ifdef SFC_X86
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    return 0;
#endif
}

#ifdef SFC_X86

static inline SFC_AVX2 double sum4(__m256d v) {
    __m128d h = _mm_add_pd(_mm256_castpd256_pd128(v), _mm256_extractf128_pd(v, 1));
    return _mm_cvtsd_f64(_mm_add_sd(h, _mm_unpackhi_pd(h, h)));
}

/* Falloffs max(1 - t, 0) of the two halves of a row: lanes at column offsets rx_lo, rx_hi. */
static inline SFC_AVX2 void row_falloff(__m256d q00, __m256d rx_lo, __m256d rx_hi, double q01, double q11,
                                        double ry, __m256d *u_lo, __m256d *u_hi) {
    const __m256d one = _mm256_set1_pd(1.0), zero = _mm256_setzero_pd();
    const __m256d b = _mm256_set1_pd(2.0 * q01 * ry), e = _mm256_set1_pd(q11 * ry * ry);
    *u_lo = _mm256_max_pd(_mm256_sub_pd(one, _mm256_fmadd_pd(_mm256_fmadd_pd(q00, rx_lo, b), rx_lo, e)), zero);
    *u_hi = _mm256_max_pd(_mm256_sub_pd(one, _mm256_fmadd_pd(_mm256_fmadd_pd(q00, rx_hi, b), rx_hi, e)), zero);
}

/* The Silverman weights of the box's first `rows` rows (two vectors a row) and their sum. */
static inline SFC_AVX2 double box_weights(int64_t rows, double rx0, double ry0, double q00, double q01, double q11,
                                          __m256d w[16]) {
    const __m256d rx_lo = _mm256_add_pd(_mm256_setr_pd(0.0, 1.0, 2.0, 3.0), _mm256_set1_pd(rx0));
    const __m256d rx_hi = _mm256_add_pd(rx_lo, _mm256_set1_pd(4.0));
    const __m256d a = _mm256_set1_pd(q00);
    __m256d s = _mm256_setzero_pd();
    for (int r = 0; r < rows; r++) {
        __m256d u_lo, u_hi;
        row_falloff(a, rx_lo, rx_hi, q01, q11, ry0 + r, &u_lo, &u_hi);
        w[2 * r] = _mm256_mul_pd(u_lo, u_lo);
        w[2 * r + 1] = _mm256_mul_pd(u_hi, u_hi);
        s = _mm256_add_pd(s, _mm256_add_pd(w[2 * r], w[2 * r + 1]));
    }
    return sum4(s);
}

/* Splat one photon into the box of `rows` (at most 8) rows of 8 pixels whose first pixel is
 * img[offset] (rows `stride` elements apart), rx0 / ry0 the column / row offsets of that pixel
 * from the photon (pixels), Q = (q00, q01, q11) its footprint metric and f its flux: each pixel
 * gets f w / sum(w). */
SFC_AVX2 void sfc_splat_box8_f64(double *img, int64_t offset, int64_t stride, int64_t rows, double rx0,
                                 double ry0, double q00, double q01, double q11, double f) {
    __m256d w[16];
    double s = box_weights(rows, rx0, ry0, q00, q01, q11, w);
    if (!(s > 0.0)) return;
    const __m256d scale = _mm256_set1_pd(f / s);
    for (int r = 0; r < rows; r++) {
        double *row = img + offset + r * stride;
        _mm256_storeu_pd(row, _mm256_fmadd_pd(scale, w[2 * r], _mm256_loadu_pd(row)));
        _mm256_storeu_pd(row + 4, _mm256_fmadd_pd(scale, w[2 * r + 1], _mm256_loadu_pd(row + 4)));
    }
}

/* sfc_splat_box8_f64 into a float32 image (the weights in float64, the sums rounded once). */
SFC_AVX2 void sfc_splat_box8_f32(float *img, int64_t offset, int64_t stride, int64_t rows, double rx0,
                                 double ry0, double q00, double q01, double q11, double f) {
    __m256d w[16];
    double s = box_weights(rows, rx0, ry0, q00, q01, q11, w);
    if (!(s > 0.0)) return;
    const __m256d scale = _mm256_set1_pd(f / s);
    for (int r = 0; r < rows; r++) {
        float *row = img + offset + r * stride;
        __m128 lo = _mm256_cvtpd_ps(_mm256_mul_pd(scale, w[2 * r]));
        __m128 hi = _mm256_cvtpd_ps(_mm256_mul_pd(scale, w[2 * r + 1]));
        __m256 add = _mm256_insertf128_ps(_mm256_castps128_ps256(lo), hi, 1);
        _mm256_storeu_ps(row, _mm256_add_ps(_mm256_loadu_ps(row), add));
    }
}

/* Adds to m[0 .. 11] the raw sums of the splat adjoint over the first `rows` rows of 8 pixels of G
 * whose first pixel is g[offset] (rows `stride` apart), rx0 / ry0 the column / row offsets of that
 * pixel from the photon: m = (sum w, sum G w, and the moments sum rx^i ry^j u for (i, j) = (1, 0),
 * (2, 0), (0, 1), (1, 1), (0, 2), then the same with G u). Per-lane accumulators over the rows (rx
 * is fixed per lane, ry per row), the moments in rx formed at the end instead of reducing every
 * row. */
static inline SFC_AVX2 void box8_moments(const double *g, int64_t offset, int64_t stride, int64_t rows, double rx0,
                                         double ry0, double q00, double q01, double q11, double m[12]) {
    const __m256d rx_lo = _mm256_add_pd(_mm256_setr_pd(0.0, 1.0, 2.0, 3.0), _mm256_set1_pd(rx0));
    const __m256d rx_hi = _mm256_add_pd(rx_lo, _mm256_set1_pd(4.0));
    const __m256d a = _mm256_set1_pd(q00), zero = _mm256_setzero_pd();
    /* Per lane, over the rows: sum w, sum G w; sum u, ry u, ry^2 u; the same times G. */
    __m256d s = zero, gs = zero;
    __m256d a0l = zero, a1l = zero, a2l = zero, a0h = zero, a1h = zero, a2h = zero;
    __m256d g0l = zero, g1l = zero, g2l = zero, g0h = zero, g1h = zero, g2h = zero;
    for (int64_t r = 0; r < rows; r++) {
        const double ry = ry0 + (double)r;
        const __m256d vry = _mm256_set1_pd(ry), vry2 = _mm256_set1_pd(ry * ry);
        const double *row = g + offset + r * stride;
        __m256d ul, uh;
        row_falloff(a, rx_lo, rx_hi, q01, q11, ry, &ul, &uh);
        const __m256d gl = _mm256_mul_pd(_mm256_loadu_pd(row), ul);
        const __m256d gh = _mm256_mul_pd(_mm256_loadu_pd(row + 4), uh);
        s = _mm256_fmadd_pd(uh, uh, _mm256_fmadd_pd(ul, ul, s));
        gs = _mm256_fmadd_pd(gh, uh, _mm256_fmadd_pd(gl, ul, gs));
        a0l = _mm256_add_pd(a0l, ul);
        a1l = _mm256_fmadd_pd(vry, ul, a1l);
        a2l = _mm256_fmadd_pd(vry2, ul, a2l);
        a0h = _mm256_add_pd(a0h, uh);
        a1h = _mm256_fmadd_pd(vry, uh, a1h);
        a2h = _mm256_fmadd_pd(vry2, uh, a2h);
        g0l = _mm256_add_pd(g0l, gl);
        g1l = _mm256_fmadd_pd(vry, gl, g1l);
        g2l = _mm256_fmadd_pd(vry2, gl, g2l);
        g0h = _mm256_add_pd(g0h, gh);
        g1h = _mm256_fmadd_pd(vry, gh, g1h);
        g2h = _mm256_fmadd_pd(vry2, gh, g2h);
    }
    const __m256d rx2_lo = _mm256_mul_pd(rx_lo, rx_lo), rx2_hi = _mm256_mul_pd(rx_hi, rx_hi);
#define SFC_MOMENT(lo, hi, wlo, whi) sum4(_mm256_fmadd_pd(wlo, lo, _mm256_mul_pd(whi, hi)))
    m[0] = sum4(s);
    m[1] = sum4(gs);
    m[2] = SFC_MOMENT(a0l, a0h, rx_lo, rx_hi);
    m[3] = SFC_MOMENT(a0l, a0h, rx2_lo, rx2_hi);
    m[4] = sum4(_mm256_add_pd(a1l, a1h));
    m[5] = SFC_MOMENT(a1l, a1h, rx_lo, rx_hi);
    m[6] = sum4(_mm256_add_pd(a2l, a2h));
    m[7] = SFC_MOMENT(g0l, g0h, rx_lo, rx_hi);
    m[8] = SFC_MOMENT(g0l, g0h, rx2_lo, rx2_hi);
    m[9] = sum4(_mm256_add_pd(g1l, g1h));
    m[10] = SFC_MOMENT(g1l, g1h, rx_lo, rx_hi);
    m[11] = sum4(_mm256_add_pd(g2l, g2h));
#undef SFC_MOMENT
}

/* The gather's sums (s, sum G w, v0 .. v4, u0 .. u4), exactly as _gather_box in
 * operators/splat/native.py defines them (v_i = sum dw / dtheta_i, u_i = sum G dw / dtheta_i over
 * -2, theta = (px, py, q00, q01, q11)), from the raw sums m (box8_moments). */
static inline SFC_AVX2 void gather_sums(const double m[12], double q00, double q01, double q11, double *sums) {
    sums[0] = m[0];
    sums[1] = m[1];
    sums[2] = -2.0 * (q00 * m[2] + q01 * m[4]);
    sums[3] = -2.0 * (q01 * m[2] + q11 * m[4]);
    sums[4] = m[3];
    sums[5] = 2.0 * m[5];
    sums[6] = m[6];
    sums[7] = -2.0 * (q00 * m[7] + q01 * m[9]);
    sums[8] = -2.0 * (q01 * m[7] + q11 * m[9]);
    sums[9] = m[8];
    sums[10] = 2.0 * m[10];
    sums[11] = m[11];
}

/* The gather's sums (gather_sums) over the box of `rows` (at most 8) rows of 8 pixels of G whose
 * first pixel is g[offset] (rows `stride` apart). */
SFC_AVX2 void sfc_gather_box8(const double *g, int64_t offset, int64_t stride, int64_t rows, double rx0,
                              double ry0, double q00, double q01, double q11, double *sums) {
    double m[12];
    box8_moments(g, offset, stride, rows, rx0, ry0, q00, q01, q11, m);
    gather_sums(m, q00, q01, q11, sums);
}

/* Rows of a bounding box whose chords row_spans finds at once (a multiple of its 4 rows a vector). */
enum { SPAN_ROWS = 64 };

/* The columns lo[i] .. hi[i] (within 0 .. width - 1, as doubles) of the bounding box's rows r0 + i,
 * i < count <= SPAN_ROWS, whose pixels can hold weight, column j at offset rx0 + j and row r at
 * ry0 + r from the photon: the ellipse's chord on each row, rx = cx -+ sqrt(q00 - det Q ry^2) / q00
 * with cx = -q01 ry / q00, widened by one column on each side for rounding (four rows a vector).
 * Every pixel left out has t > 1, weight 0, and adds nothing to any sum. */
static inline SFC_AVX2 void row_spans(double rx0, double ry0, int64_t r0, int64_t count, int64_t width, double q00,
                                      double q01, double det, double lo[SPAN_ROWS], double hi[SPAN_ROWS]) {
    const __m256d lane = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0), one = _mm256_set1_pd(1.0), zero = _mm256_setzero_pd();
    const __m256d slope = _mm256_set1_pd(-q01 / q00), inv = _mm256_set1_pd(1.0 / q00), a = _mm256_set1_pd(q00);
    const __m256d d = _mm256_set1_pd(det), x0 = _mm256_set1_pd(rx0), last = _mm256_set1_pd((double)(width - 1));
    for (int64_t i = 0; i < count; i += 4) {
        const __m256d ry = _mm256_add_pd(lane, _mm256_set1_pd(ry0 + (double)(r0 + i)));
        const __m256d half = _mm256_mul_pd(_mm256_sqrt_pd(_mm256_max_pd(_mm256_fnmadd_pd(d, _mm256_mul_pd(ry, ry), a),
                                                                       zero)), inv);
        const __m256d cx = _mm256_sub_pd(_mm256_mul_pd(slope, ry), x0);
        const __m256d first = _mm256_sub_pd(_mm256_floor_pd(_mm256_sub_pd(cx, half)), one);
        const __m256d end = _mm256_add_pd(_mm256_ceil_pd(_mm256_add_pd(cx, half)), one);
        _mm256_storeu_pd(lo + i, _mm256_max_pd(first, zero));
        _mm256_storeu_pd(hi + i, _mm256_min_pd(end, last));
    }
}

/* Falloffs max(1 - t, 0) of 4 pixels of a row with terms b = 2 q01 ry, e = q11 ry^2 at column
 * offsets rx. */
static inline SFC_AVX2 __m256d falloff4(__m256d q00, __m256d rx, __m256d b, __m256d e) {
    return _mm256_max_pd(_mm256_sub_pd(_mm256_set1_pd(1.0), _mm256_fmadd_pd(_mm256_fmadd_pd(q00, rx, b), rx, e)),
                         _mm256_setzero_pd());
}

/* The gather's sums (gather_sums) over a bounding box of `rows` rows and `width` columns of G (a
 * footprint larger than the fixed box) whose first pixel is g[offset] (rows `stride` apart), rx0
 * / ry0 the offsets of that pixel from the photon: each row over its chord (row_spans) in vectors
 * of 4 pixels, so G must hold 3 columns past the box. */
SFC_AVX2 void sfc_gather_spans(const double *g, int64_t offset, int64_t stride, int64_t rows, int64_t width,
                               double rx0, double ry0, double q00, double q01, double q11, double *sums) {
    const double det = q00 * q11 - q01 * q01;
    const __m256d a = _mm256_set1_pd(q00), zero = _mm256_setzero_pd(), lane = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0);
    /* Per lane: sum w, sum G w; sum u rx, u rx^2, u ry, u rx ry, u ry^2; the same times G. */
    __m256d s = zero, gs = zero, ax = zero, axx = zero, ay = zero, axy = zero, ayy = zero;
    __m256d gx = zero, gxx = zero, gy = zero, gxy = zero, gyy = zero;
    double lo[SPAN_ROWS], hi[SPAN_ROWS];
    for (int64_t r = 0; r < rows; r++) {
        if (r % SPAN_ROWS == 0) row_spans(rx0, ry0, r, rows - r < SPAN_ROWS ? rows - r : SPAN_ROWS, width, q00, q01, det, lo, hi);
        const double ry = ry0 + (double)r;
        const __m256d b = _mm256_set1_pd(2.0 * q01 * ry), e = _mm256_set1_pd(q11 * ry * ry);
        const double *row = g + offset + r * stride;
        __m256d a0 = zero, a1 = zero, g0 = zero, g1 = zero; /* this row's sum u, u rx, G u, G u rx */
        for (int64_t j = (int64_t)lo[r % SPAN_ROWS]; j <= (int64_t)hi[r % SPAN_ROWS]; j += 4) {
            const __m256d rx = _mm256_add_pd(lane, _mm256_set1_pd(rx0 + (double)j));
            const __m256d u = falloff4(a, rx, b, e);
            const __m256d gu = _mm256_mul_pd(_mm256_loadu_pd(row + j), u);
            const __m256d ux = _mm256_mul_pd(u, rx), gux = _mm256_mul_pd(gu, rx);
            s = _mm256_fmadd_pd(u, u, s);
            gs = _mm256_fmadd_pd(gu, u, gs);
            a0 = _mm256_add_pd(a0, u);
            a1 = _mm256_add_pd(a1, ux);
            axx = _mm256_fmadd_pd(ux, rx, axx);
            g0 = _mm256_add_pd(g0, gu);
            g1 = _mm256_add_pd(g1, gux);
            gxx = _mm256_fmadd_pd(gux, rx, gxx);
        }
        const __m256d vry = _mm256_set1_pd(ry), vry2 = _mm256_set1_pd(ry * ry);
        ax = _mm256_add_pd(ax, a1);
        ay = _mm256_fmadd_pd(vry, a0, ay);
        axy = _mm256_fmadd_pd(vry, a1, axy);
        ayy = _mm256_fmadd_pd(vry2, a0, ayy);
        gx = _mm256_add_pd(gx, g1);
        gy = _mm256_fmadd_pd(vry, g0, gy);
        gxy = _mm256_fmadd_pd(vry, g1, gxy);
        gyy = _mm256_fmadd_pd(vry2, g0, gyy);
    }
    const double m[12] = {sum4(s),  sum4(gs),  sum4(ax),  sum4(axx), sum4(ay),  sum4(axy),
                          sum4(ayy), sum4(gx), sum4(gxx), sum4(gy),  sum4(gxy), sum4(gyy)};
    gather_sums(m, q00, q01, q11, sums);
}

/* One pass of splat_spans over each row's chord (row_spans) in vectors of 4 pixels: the sum of
 * the weights w, and with an image (img not NULL; float64, or float32 with f32) scale w added to
 * each of those pixels. */
static inline SFC_AVX2 double spans_pass(void *img, int f32, int64_t offset, int64_t stride, int64_t rows,
                                         int64_t width, double rx0, double ry0, double q00, double q01, double q11,
                                         double scale) {
    const double det = q00 * q11 - q01 * q01;
    const __m256d a = _mm256_set1_pd(q00), lane = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0), k = _mm256_set1_pd(scale);
    __m256d s = _mm256_setzero_pd();
    double lo[SPAN_ROWS], hi[SPAN_ROWS];
    for (int64_t r = 0; r < rows; r++) {
        if (r % SPAN_ROWS == 0) row_spans(rx0, ry0, r, rows - r < SPAN_ROWS ? rows - r : SPAN_ROWS, width, q00, q01, det, lo, hi);
        const double ry = ry0 + (double)r;
        const __m256d b = _mm256_set1_pd(2.0 * q01 * ry), e = _mm256_set1_pd(q11 * ry * ry);
        for (int64_t j = (int64_t)lo[r % SPAN_ROWS]; j <= (int64_t)hi[r % SPAN_ROWS]; j += 4) {
            const __m256d u = falloff4(a, _mm256_add_pd(lane, _mm256_set1_pd(rx0 + (double)j)), b, e);
            s = _mm256_fmadd_pd(u, u, s);
            if (img == NULL) continue;
            const __m256d w = _mm256_mul_pd(u, u);
            const int64_t at = offset + r * stride + j;
            if (f32) { /* as sfc_splat_box8_f32 */
                float *px = (float *)img + at;
                _mm_storeu_ps(px, _mm_add_ps(_mm_loadu_ps(px), _mm256_cvtpd_ps(_mm256_mul_pd(k, w))));
            } else { /* as sfc_splat_box8_f64 */
                double *px = (double *)img + at;
                _mm256_storeu_pd(px, _mm256_fmadd_pd(k, w, _mm256_loadu_pd(px)));
            }
        }
    }
    return sum4(s);
}

/* The splat of one photon of flux f over a bounding box of `rows` rows and `width` columns (a
 * footprint larger than the fixed box) into a float64 (f32 = 0) or float32 image whose first
 * pixel is img[offset] (rows `stride` apart), rx0 / ry0 the offsets of that pixel from the photon:
 * the weights' sum over each row's chord (row_spans), then f w / sum(w) onto those pixels, in
 * vectors of 4 pixels (the image must hold 3 columns past the box; they get 0). */
static SFC_AVX2 void splat_spans(void *img, int f32, int64_t offset, int64_t stride, int64_t rows, int64_t width,
                                 double rx0, double ry0, double q00, double q01, double q11, double f) {
    const double total = spans_pass(NULL, f32, offset, stride, rows, width, rx0, ry0, q00, q01, q11, 0.0);
    if (total > 0.0) spans_pass(img, f32, offset, stride, rows, width, rx0, ry0, q00, q01, q11, f / total);
}

SFC_AVX2 void sfc_splat_spans_f64(double *img, int64_t offset, int64_t stride, int64_t rows, int64_t width,
                                  double rx0, double ry0, double q00, double q01, double q11, double f) {
    splat_spans(img, 0, offset, stride, rows, width, rx0, ry0, q00, q01, q11, f);
}

SFC_AVX2 void sfc_splat_spans_f32(float *img, int64_t offset, int64_t stride, int64_t rows, int64_t width,
                                  double rx0, double ry0, double q00, double q01, double q11, double f) {
    splat_spans(img, 1, offset, stride, rows, width, rx0, ry0, q00, q01, q11, f);
}


/* Catmull-Rom cell along one grid axis at coordinate `coord` (as axis_weights in
 * operators/heightfield/catmull_rom.py): the cell index i (the patch spans nodes i-1 .. i+2) and the weight
 * vectors of the value and of the first three derivatives in scene units (zero off the grid,
 * where the surface is flat), lanes over the four nodes. */
static inline SFC_AVX2 int64_t axis_weights4(double coord, double origin, double inv_spacing, int64_t m,
                                             __m256d w[4]) {
    double g = (coord - origin) * inv_spacing;
    const int inside = 0.0 <= g && g <= (double)(m - 1);
    g = g < 0.0 ? 0.0 : (g > (double)(m - 1) ? (double)(m - 1) : g);
    int64_t i = (int64_t)g; /* g >= 0: truncation is the floor */
    if (i > m - 2) i = m - 2;
    const __m256d s = _mm256_set1_pd(g - (double)i);
    const double k1 = inside ? inv_spacing : 0.0, k2 = k1 * inv_spacing, k3 = k2 * inv_spacing;
    /* The Catmull-Rom weights and their derivatives as polynomials in s, lanes over the nodes. */
    w[0] = _mm256_fmadd_pd(_mm256_fmadd_pd(_mm256_fmadd_pd(_mm256_setr_pd(-0.5, 1.5, -1.5, 0.5), s,
                                                           _mm256_setr_pd(1.0, -2.5, 2.0, -0.5)), s,
                                           _mm256_setr_pd(-0.5, 0.0, 0.5, 0.0)), s, _mm256_setr_pd(0.0, 1.0, 0.0, 0.0));
    w[1] = _mm256_mul_pd(_mm256_set1_pd(k1),
                         _mm256_fmadd_pd(_mm256_fmadd_pd(_mm256_setr_pd(-1.5, 4.5, -4.5, 1.5), s,
                                                         _mm256_setr_pd(2.0, -5.0, 4.0, -1.0)), s,
                                         _mm256_setr_pd(-0.5, 0.0, 0.5, 0.0)));
    w[2] = _mm256_mul_pd(_mm256_set1_pd(k2), _mm256_fmadd_pd(_mm256_setr_pd(-3.0, 9.0, -9.0, 3.0), s,
                                                            _mm256_setr_pd(2.0, -5.0, 4.0, -1.0)));
    w[3] = _mm256_mul_pd(_mm256_set1_pd(k3), _mm256_setr_pd(-3.0, 9.0, -9.0, 3.0));
    return i;
}

static inline int64_t clamp_node(int64_t i, int64_t m) { return i < 0 ? 0 : (i > m - 1 ? m - 1 : i); }

/* The 4 x 4 samples around cell (ix, iy), replicated beyond the border: rows (lanes over the
 * columns) folded with the y weights, t[k] = sum_a ey[k][a] row_a for k < orders. */
static inline SFC_AVX2 void fold_rows(const double *d, int64_t m, int64_t ix, int64_t iy, const __m256d *by,
                                      int orders, __m256d *t) {
    double ey[4][4];
    for (int k = 0; k < orders; k++) {
        _mm256_storeu_pd(ey[k], by[k]);
        t[k] = _mm256_setzero_pd();
    }
    const int interior = ix >= 1 && ix + 2 <= m - 1;
    const int64_t c0 = clamp_node(ix - 1, m), c3 = clamp_node(ix + 2, m);
    for (int a = 0; a < 4; a++) {
        const double *r = d + clamp_node(iy - 1 + a, m) * m;
        const __m256d p = interior ? _mm256_loadu_pd(r + ix - 1) : _mm256_setr_pd(r[c0], r[ix], r[ix + 1], r[c3]);
        for (int k = 0; k < orders; k++) t[k] = _mm256_fmadd_pd(_mm256_set1_pd(ey[k][a]), p, t[k]);
    }
}

/* Surface jets (S_x, S_y, S_xx, S_xy, S_yy) of a packet at its hits: ray k < count from (ox, oy)
 * along dirs (rows 0, 1 of a table whose rows are `stride` elements apart) meets the surface at
 * parameter t[k]; its jet goes into rows 0 .. 4 of `jets` (rows also `stride` apart). The heights
 * d are m x m, row-major, first node at `origin` on both axes, nodes 1 / inv_spacing apart. */
SFC_AVX2 void sfc_surface_jets(const double *d, int64_t m, double origin, double inv_spacing, double ox,
                               double oy, const double *dirs, int64_t stride, const double *t, int64_t count,
                               double *jets) {
    for (int64_t k = 0; k < count; k++) {
        __m256d bx[4], by[4], rows[3];
        const int64_t ix = axis_weights4(ox + t[k] * dirs[k], origin, inv_spacing, m, bx);
        const int64_t iy = axis_weights4(oy + t[k] * dirs[stride + k], origin, inv_spacing, m, by);
        fold_rows(d, m, ix, iy, by, 3, rows);
        jets[k] = sum4(_mm256_mul_pd(rows[0], bx[1]));
        jets[stride + k] = sum4(_mm256_mul_pd(rows[1], bx[0]));
        jets[2 * stride + k] = sum4(_mm256_mul_pd(rows[0], bx[2]));
        jets[3 * stride + k] = sum4(_mm256_mul_pd(rows[1], bx[1]));
        jets[4 * stride + k] = sum4(_mm256_mul_pd(rows[2], bx[0]));
    }
}

/* Add to grad (m x m, row-major) the gradient w.r.t. the heights d (m x m) of
 * g_t t + g_sx S_x + g_sy S_y + g_sxx S_xx + g_sxy S_xy + g_syy S_yy at one photon's hit: the ray
 * along (wx, wy, wz) meets the surface at (x, y), t its ray parameter there (the hit moves with d:
 * dt/dd = B(x, y) / (wz - grad S . (wx, wy))). As hit_adjoint_patch then scatter_patch in
 * operators/heightfield/intersect_native.py; the grid's first node is at `origin` on both axes, its nodes
 * 1 / inv_spacing apart. */
SFC_AVX2 void sfc_hit_adjoint(const double *d, double *grad, int64_t m, double x, double y, double origin,
                              double inv_spacing, double wx, double wy, double wz, double g_t, double g_sx,
                              double g_sy, double g_sxx, double g_sxy, double g_syy) {
    __m256d bx[4], by[4];
    const int64_t ix = axis_weights4(x, origin, inv_spacing, m, bx);
    const int64_t iy = axis_weights4(y, origin, inv_spacing, m, by);
    double ey[4][4]; /* ey[k][a]: k-th y-derivative weight of patch row a */
    for (int k = 0; k < 3; k++) _mm256_storeu_pd(ey[k], by[k]);
    __m256d t[4];
    fold_rows(d, m, ix, iy, by, 4, t);
    /* d^(i+j) S / dx^i dy^j = <T_j, bx_i>. */
    const double sx = sum4(_mm256_mul_pd(t[0], bx[1])), sy = sum4(_mm256_mul_pd(t[1], bx[0]));
    const double sxx = sum4(_mm256_mul_pd(t[0], bx[2])), sxy = sum4(_mm256_mul_pd(t[1], bx[1]));
    const double syy = sum4(_mm256_mul_pd(t[2], bx[0])), sxxx = sum4(_mm256_mul_pd(t[0], bx[3]));
    const double sxxy = sum4(_mm256_mul_pd(t[1], bx[2])), sxyy = sum4(_mm256_mul_pd(t[2], bx[1]));
    const double syyy = sum4(_mm256_mul_pd(t[3], bx[0]));
    /* Loss change per unit of t while d is held: the hit point slides along the ray. */
    const double along = g_t + g_sx * (sxx * wx + sxy * wy) + g_sy * (sxy * wx + syy * wy)
                         + g_sxx * (sxxx * wx + sxxy * wy) + g_sxy * (sxxy * wx + sxyy * wy)
                         + g_syy * (sxyy * wx + syyy * wy);
    const double c = along / (wz - sx * wx - sy * wy);
    /* Gradient row a = ey[0][a] V0 + ey[1][a] V1 + ey[2][a] V2 (lanes over the columns). */
    const __m256d v0 = _mm256_fmadd_pd(_mm256_set1_pd(c), bx[0],
                                       _mm256_fmadd_pd(_mm256_set1_pd(g_sx), bx[1], _mm256_mul_pd(_mm256_set1_pd(g_sxx), bx[2])));
    const __m256d v1 = _mm256_fmadd_pd(_mm256_set1_pd(g_sy), bx[0], _mm256_mul_pd(_mm256_set1_pd(g_sxy), bx[1]));
    const __m256d v2 = _mm256_mul_pd(_mm256_set1_pd(g_syy), bx[0]);
    for (int a = 0; a < 4; a++) {
        const __m256d row = _mm256_fmadd_pd(_mm256_set1_pd(ey[0][a]), v0,
                                            _mm256_fmadd_pd(_mm256_set1_pd(ey[1][a]), v1,
                                                            _mm256_mul_pd(_mm256_set1_pd(ey[2][a]), v2)));
        double *r = grad + clamp_node(iy - 1 + a, m) * m;
        if (ix >= 1 && ix + 2 <= m - 1) {
            _mm256_storeu_pd(r + ix - 1, _mm256_add_pd(_mm256_loadu_pd(r + ix - 1), row));
        } else { /* replicated border nodes: columns may repeat, add one by one */
            double lanes[4];
            _mm256_storeu_pd(lanes, row);
            for (int b = 0; b < 4; b++) r[clamp_node(ix - 1 + b, m)] += lanes[b];
        }
    }
}

#else /* not x86-64: never called, sfc_simd_supported() is 0 */

void sfc_splat_box8_f64(double *img, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                        double q00, double q01, double q11, double f) {}
void sfc_splat_box8_f32(float *img, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                        double q00, double q01, double q11, double f) {}
void sfc_gather_box8(const double *g, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                     double q00, double q01, double q11, double *sums) {}
void sfc_gather_spans(const double *g, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                       double ry0, double q00, double q01, double q11, double *sums) {}
void sfc_splat_spans_f64(double *img, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                          double ry0, double q00, double q01, double q11, double f) {}
void sfc_splat_spans_f32(float *img, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                          double ry0, double q00, double q01, double q11, double f) {}
void sfc_surface_jets(const double *d, int64_t m, double origin, double inv_spacing, double ox, double oy,
                      const double *dirs, int64_t stride, const double *t, int64_t count, double *jets) {}
void sfc_hit_adjoint(const double *d, double *grad, int64_t m, double x, double y, double origin, double inv_spacing,
                     double wx, double wy, double wz, double g_t, double g_sx, double g_sy, double g_sxx,
                     double g_sxy, double g_syy) {}

#endif

static struct PyModuleDef simd_module = {
    PyModuleDef_HEAD_INIT, "_simd",
    "AVX2 splat, gather, surface-jet and hit-adjoint kernels, called from numba by symbol name (see "
    "operators/kernels/simd.py).", -1, NULL,
};

PyMODINIT_FUNC PyInit__simd(void) { return PyModule_Create(&simd_module); }
