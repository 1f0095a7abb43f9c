/* Exact-coverage rasterisation of flux-carrying triangles in C: the same clipping, arithmetic and
 * lane order as the numba kernels of operators/wavefront/coverage.py (whose docstring gives the
 * method), compiled at install as part of the extension operators.kernels._simd. Pixel p spans
 * [p, p + 1] on both axes (pixel corner units); image [row = y, col = x]. Work items (rows of grid
 * cells, or blocks of listed triangles) are dealt round-robin to `lanes` images, one thread per
 * lane, so a rerun with the same lane count is bit-identical. */
#include <math.h>
#include <stdint.h>

#include "sfc_threads.h"

enum { POLYGON_CAPACITY = 48, TRIANGLE_BLOCK = 1024 };
static const double DEGENERATE_AREA = 1e-14, FAR_PX = 1e9;

/* Sutherland-Hodgman: the polygon (xs, ys)[:count] clipped to coordinate `axis` (0 = x, 1 = y)
 * <= bound (upper) or >= bound, into (ox, oy); returns its size. */
static int clip(const double *xs, const double *ys, int count, int axis, double bound, int upper, double *ox,
                double *oy) {
    if (count == 0) return 0;
    const double sign = upper ? 1.0 : -1.0;
    double sx = xs[count - 1], sy = ys[count - 1];
    double sd = sign * ((axis == 0 ? sx : sy) - bound);
    int k = 0;
    for (int i = 0; i < count; i++) {
        const double ex = xs[i], ey = ys[i];
        const double ed = sign * ((axis == 0 ? ex : ey) - bound);
        if ((ed <= 0.0) != (sd <= 0.0)) {
            const double t = sd / (sd - ed);
            if (axis == 0) {
                ox[k] = bound;
                oy[k] = sy + t * (ey - sy);
            } else {
                ox[k] = sx + t * (ex - sx);
                oy[k] = bound;
            }
            k++;
        }
        if (ed <= 0.0) {
            ox[k] = ex;
            oy[k] = ey;
            k++;
        }
        sx = ex;
        sy = ey;
        sd = ed;
    }
    return k;
}

static double polygon_area(const double *xs, const double *ys, int count) {
    double s = 0.0, jx = xs[count - 1], jy = ys[count - 1];
    for (int i = 0; i < count; i++) {
        s += jx * ys[i] - xs[i] * jy;
        jx = xs[i];
        jy = ys[i];
    }
    return 0.5 * fabs(s);
}

/* scale |T ∩ pixel| into every pixel of rows row_lo .. row_hi, columns col_lo .. col_hi (clamped),
 * T = (a, b, c) relative to the corner (col_lo, row_lo) (_deposit_clipped). */
static void deposit_clipped(double *img, int64_t n, double ax, double ay, double bx, double by, double cx, double cy,
                            int64_t col_lo, int64_t row_lo, int64_t col_hi, int64_t row_hi, double scale) {
    double tx[POLYGON_CAPACITY], ty[POLYGON_CAPACITY], sx[POLYGON_CAPACITY], sy[POLYGON_CAPACITY];
    double px[POLYGON_CAPACITY], py[POLYGON_CAPACITY];
    const int64_t first = row_lo > 0 ? row_lo : 0, last = row_hi < n - 1 ? row_hi : n - 1;
    for (int64_t row = first; row <= last; row++) {
        const double lo = (double)(row - row_lo);
        tx[0] = ax; ty[0] = ay; tx[1] = bx; ty[1] = by; tx[2] = cx; ty[2] = cy;
        int m = clip(tx, ty, 3, 1, lo, 0, px, py);
        m = clip(px, py, m, 1, lo + 1.0, 1, sx, sy);
        if (m < 3) continue;
        double smin = sx[0], smax = sx[0];
        for (int i = 1; i < m; i++) {
            smin = fmin(smin, sx[i]);
            smax = fmax(smax, sx[i]);
        }
        int64_t c_lo = col_lo + (int64_t)floor(smin);
        int64_t c_hi = col_lo + (int64_t)ceil(smax) - 1;
        if (c_lo < 0) c_lo = 0;
        if (c_hi > n - 1) c_hi = n - 1;
        if (c_hi > col_hi) c_hi = col_hi;
        if (c_hi < c_lo) continue;
        double *r = img + row * n;
        if (c_lo == c_hi && smin >= (double)(c_lo - col_lo) && smax <= (double)(c_lo - col_lo) + 1.0) {
            r[c_lo] += scale * polygon_area(sx, sy, m);
            continue;
        }
        for (int64_t col = c_lo; col <= c_hi; col++) {
            const double left = (double)(col - col_lo);
            int k = clip(sx, sy, m, 0, left, 0, px, py);
            k = clip(px, py, k, 0, left + 1.0, 1, tx, ty);
            if (k >= 3) r[col] += scale * polygon_area(tx, ty, k);
        }
    }
}

/* Flux f of the triangle (x0, y0), (x1, y1), (x2, y2) into img (n, n) by exact coverage (deposit_triangle). */
static void deposit_triangle(double *img, int64_t n, double x0, double y0, double x1, double y1, double x2, double y2,
                             double f) {
    if (f == 0.0 || !(fabs(x0) < FAR_PX && fabs(x1) < FAR_PX && fabs(x2) < FAR_PX && fabs(y0) < FAR_PX
                      && fabs(y1) < FAR_PX && fabs(y2) < FAR_PX))
        return;
    const double xmin = fmin(x0, fmin(x1, x2)), xmax = fmax(x0, fmax(x1, x2));
    const double ymin = fmin(y0, fmin(y1, y2)), ymax = fmax(y0, fmax(y1, y2));
    if (xmax <= 0.0 || ymax <= 0.0 || xmin >= (double)n || ymin >= (double)n) return;
    const double ox = floor(xmin), oy = floor(ymin);
    const double ax = x0 - ox, ay = y0 - oy, bx = x1 - ox, by = y1 - oy, cx = x2 - ox, cy = y2 - oy;
    const double area = 0.5 * fabs((bx - ax) * (cy - ay) - (by - ay) * (cx - ax));
    if (area < DEGENERATE_AREA) {
        const int64_t px = (int64_t)floor((x0 + x1 + x2) / 3.0), py = (int64_t)floor((y0 + y1 + y2) / 3.0);
        if (0 <= px && px < n && 0 <= py && py < n) img[py * n + px] += f;
        return;
    }
    const int64_t col_lo = (int64_t)ox, row_lo = (int64_t)oy;
    const int64_t col_hi = (int64_t)ceil(xmax) - 1, row_hi = (int64_t)ceil(ymax) - 1;
    if (col_hi <= col_lo && row_hi <= row_lo) {
        img[row_lo * n + col_lo] += f;
        return;
    }
    deposit_clipped(img, n, ax, ay, bx, by, cx, cy, col_lo, row_lo, col_hi, row_hi, f / area);
}

typedef struct {
    const double *vertices, *flux;  /* grid: (K, K, 2), (2, K-1, K-1); list: (T, 3, 2), (T,) */
    int64_t k, count, n, lanes;
    double *out;                    /* (lanes, n, n) */
} raster_job;

static int grid_lane(void *context, int64_t lane) {
    const raster_job *j = (const raster_job *)context;
    const int64_t k = j->k, cells = k - 1;
    double *img = j->out + lane * j->n * j->n;
    const double *v = j->vertices;
    for (int64_t i = lane; i < cells; i += j->lanes) {
        for (int64_t c = 0; c < cells; c++) {
            const double f0 = j->flux[i * cells + c], f1 = j->flux[cells * cells + i * cells + c];
            if (f0 == 0.0 && f1 == 0.0) continue;
            const double *v00 = v + 2 * (i * k + c), *v01 = v + 2 * (i * k + c + 1);
            const double *v10 = v + 2 * ((i + 1) * k + c), *v11 = v + 2 * ((i + 1) * k + c + 1);
            if (f0 != 0.0) deposit_triangle(img, j->n, v00[0], v00[1], v01[0], v01[1], v11[0], v11[1], f0);
            if (f1 != 0.0) deposit_triangle(img, j->n, v00[0], v00[1], v11[0], v11[1], v10[0], v10[1], f1);
        }
    }
    return 0;
}

static int list_lane(void *context, int64_t lane) {
    const raster_job *j = (const raster_job *)context;
    double *img = j->out + lane * j->n * j->n;
    const int64_t blocks = (j->count + TRIANGLE_BLOCK - 1) / TRIANGLE_BLOCK;
    for (int64_t b = lane; b < blocks; b += j->lanes) {
        const int64_t end = (b + 1) * TRIANGLE_BLOCK < j->count ? (b + 1) * TRIANGLE_BLOCK : j->count;
        for (int64_t t = b * TRIANGLE_BLOCK; t < end; t++) {
            const double *p = j->vertices + 6 * t;
            deposit_triangle(img, j->n, p[0], p[1], p[2], p[3], p[4], p[5], j->flux[t]);
        }
    }
    return 0;
}

/* The triangles of a vertex grid (_rasterize_grid): vertices (K, K, 2), flux (2, K-1, K-1), added
 * to out (lanes, n, n), cell row i to lane i % lanes. Returns 0, -1 on failure. */
int sfc_rasterize_grid(const double *vertices, int64_t k, const double *flux, double *out, int64_t lanes, int64_t n) {
    raster_job j = {vertices, flux, k, 0, n, lanes, out};
    return sfc_parallel(lanes, grid_lane, &j);
}

/* Listed triangles (T, 3, 2) with flux (T,) (_rasterize_list) added to out (lanes, n, n), block b
 * of TRIANGLE_BLOCK triangles to lane b % lanes. Returns 0, -1 on failure. */
int sfc_rasterize_list(const double *triangles, const double *flux, int64_t count, double *out, int64_t lanes,
                       int64_t n) {
    raster_job j = {triangles, flux, 0, count, n, lanes, out};
    return sfc_parallel(lanes, list_lane, &j);
}
