/* One photon's maths, shared by the height-field kernels (heightfield_photons.c) and the mesh-scene
 * kernels (mesh_events.c): scene constants, 3-vectors, the Catmull-Rom height surface with its hit
 * search and hit adjoint, ray optics with photon differentials and their adjoints, the footprint
 * metric. The numba functions they match are named in heightfield_photons.c's header. Every
 * function is static: each file that includes this header compiles its own copy, for its own CPU
 * target. */
#ifndef SFC_PHOTON_OPTICS_H
#define SFC_PHOTON_OPTICS_H

#include <math.h>
#include <stdint.h>

/* Scene constants, field for field the ctypes structure in operators/heightfield/trace_compiled.py:
 * FusedScene (operators/heightfield/kernels_native.py) followed by the constants the numba kernels
 * import from Python modules. */
typedef struct {
    double light_x, light_y, light_z, half, base, spacing, zlo, zstart, zhi, slope_x, slope_y;
    int64_t per_channel;
    double flux_scale, radius, receiver_z, receiver_half, to_px, min_px, max_px;
    int64_t fresnel, simd, clear_walls;
    double aim_half;            /* half width of the square on z = base the photons aim at (operators/emission.py) */
    double r2_u, r2_v;          /* emission's R2 sequence steps (operators/emission.py) */
    double grazing;             /* optics.reference.GRAZING */
    double max_differential_px; /* splat.splat.MAX_DIFFERENTIAL_PX */
    double settle;              /* intersect_native.SETTLE */
    int64_t max_march_steps, newton_iterations;
    double far_px;              /* splat.native.FAR_PX */
    double fold_limit;          /* heightfield.side_walls.FOLD_LIMIT */
    double beside;              /* heightfield.side_walls.BESIDE */
} sfc_scene;

typedef struct { double x, y, z; } vec3;

/* Helpers are inlined into the loops over a packet, so that those vectorise across photons. */
#define SFC_INLINE __attribute__((always_inline))

static const vec3 UP = {0.0, 0.0, 1.0};
static const vec3 ZERO = {0.0, 0.0, 0.0};

static inline SFC_INLINE vec3 v3(double x, double y, double z) { vec3 r = {x, y, z}; return r; }
static inline SFC_INLINE double dot(vec3 a, vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline SFC_INLINE vec3 axpy(double s, vec3 x, vec3 y) { return v3(s * x.x + y.x, s * x.y + y.y, s * x.z + y.z); }
static inline SFC_INLINE vec3 scale3(double s, vec3 x) { return v3(s * x.x, s * x.y, s * x.z); }
static inline SFC_INLINE vec3 add3(vec3 a, vec3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline SFC_INLINE double dmin(double a, double b) { return a < b ? a : b; }
static inline SFC_INLINE double dmax(double a, double b) { return a > b ? a : b; }
static inline SFC_INLINE int64_t imin(int64_t a, int64_t b) { return a < b ? a : b; }
static inline SFC_INLINE int64_t imax(int64_t a, int64_t b) { return a > b ? a : b; }

static inline SFC_INLINE double away_from_zero(const sfc_scene *sc, double x) {
    const double raised = x < 0.0 ? -sc->grazing : sc->grazing;
    return fabs(x) < sc->grazing ? raised : x;
}
static inline SFC_INLINE double passes(const sfc_scene *sc, double x) { return fabs(x) < sc->grazing ? 0.0 : 1.0; }

/* ---------------------------------------------------------------- Catmull-Rom surface */


/* Cell index i, offset s in [0, 1], d/dcoord scale k (1 / spacing on the grid, 0 off it). The
 * index in 32 bits: double-to-int32 conversions vectorise with AVX2 (to int64 they need AVX-512). */
static inline SFC_INLINE int cell(double coord, double origin, double spacing, int m, double *s, double *k) {
    double g = (coord - origin) / spacing;
    const int inside = (0.0 <= g) & (g <= (double)(m - 1));
    g = dmin(dmax(g, 0.0), (double)(m - 1));
    const int floor_g = (int)floor(g);
    const int i = floor_g < m - 2 ? floor_g : m - 2;
    *s = g - (double)i;
    *k = inside ? 1.0 / spacing : 0.0;
    return i;
}

static inline SFC_INLINE int node(int i, int m) { return i < 0 ? 0 : (i > m - 1 ? m - 1 : i); }

/* Catmull-Rom weights at s (a) and their s-derivatives times k (b). */
static inline SFC_INLINE void basis(double s, double k, double a[4], double b[4]) {
    const double s2 = s * s, s3 = s2 * s;
    a[0] = 0.5 * (-s3 + 2.0 * s2 - s);
    a[1] = 0.5 * (3.0 * s3 - 5.0 * s2 + 2.0);
    a[2] = 0.5 * (-3.0 * s3 + 4.0 * s2 + s);
    a[3] = 0.5 * (s3 - s2);
    b[0] = k * 0.5 * (-3.0 * s2 + 4.0 * s - 1.0);
    b[1] = k * 0.5 * (9.0 * s2 - 10.0 * s);
    b[2] = k * 0.5 * (-9.0 * s2 + 8.0 * s + 1.0);
    b[3] = k * 0.5 * (3.0 * s2 - 2.0 * s);
}

static inline SFC_INLINE void curvature_basis(double s, double k2, double c[4]) {
    c[0] = k2 * (-3.0 * s + 2.0);
    c[1] = k2 * (9.0 * s - 5.0);
    c[2] = k2 * (-9.0 * s + 4.0);
    c[3] = k2 * (3.0 * s - 1.0);
}

/* (S, S_x, S_y) at (x, y). */
static inline SFC_INLINE void surface_gradient(const double *d, int64_t m, double x, double y, double origin, double spacing,
                                    double *value, double *slope_x, double *slope_y) {
    double sx, kx, sy, ky, a[4], b[4], e[4], f[4];
    const int mm = (int)m;
    const int ix = cell(x, origin, spacing, mm, &sx, &kx);
    const int iy = cell(y, origin, spacing, mm, &sy, &ky);
    basis(sx, kx, a, b);
    basis(sy, ky, e, f);
    const int c0 = node(ix - 1, mm), c3 = node(ix + 2, mm);
    double val = 0.0, gx = 0.0, gy = 0.0;
    for (int r = 0; r < 4; r++) {
        const double *row = d + node(iy - 1 + r, mm) * mm;
        const double d0 = row[c0], d1 = row[ix], d2 = row[ix + 1], d3 = row[c3];
        const double v = a[0] * d0 + a[1] * d1 + a[2] * d2 + a[3] * d3;
        val += e[r] * v;
        gx += e[r] * (b[0] * d0 + b[1] * d1 + b[2] * d2 + b[3] * d3);
        gy += f[r] * v;
    }
    *value = val;
    *slope_x = gx;
    *slope_y = gy;
}

/* Surface jet (S_x, S_y, S_xx, S_xy, S_yy) at (x, y) into jet[0 .. 4]. */
static inline SFC_INLINE void surface_jet_at(const double *d, int64_t m, double x, double y, double origin, double spacing,
                                  double jet[5]) {
    double sx, kx, sy, ky, a[4], b[4], c[4], e[4], f[4], g[4];
    const int mm = (int)m;
    const int ix = cell(x, origin, spacing, mm, &sx, &kx);
    const int iy = cell(y, origin, spacing, mm, &sy, &ky);
    basis(sx, kx, a, b);
    curvature_basis(sx, kx * kx, c);
    basis(sy, ky, e, f);
    curvature_basis(sy, ky * ky, g);
    const int n0 = node(ix - 1, mm), n3 = node(ix + 2, mm);
    double s_x = 0.0, s_y = 0.0, s_xx = 0.0, s_xy = 0.0, s_yy = 0.0;
    for (int r = 0; r < 4; r++) {
        const double *row = d + node(iy - 1 + r, mm) * mm;
        const double d0 = row[n0], d1 = row[ix], d2 = row[ix + 1], d3 = row[n3];
        const double v = a[0] * d0 + a[1] * d1 + a[2] * d2 + a[3] * d3;
        const double vx = b[0] * d0 + b[1] * d1 + b[2] * d2 + b[3] * d3;
        const double vxx = c[0] * d0 + c[1] * d1 + c[2] * d2 + c[3] * d3;
        s_x += e[r] * vx;
        s_xx += e[r] * vxx;
        s_y += f[r] * v;
        s_xy += f[r] * vx;
        s_yy += g[r] * v;
    }
    jet[0] = s_x;
    jet[1] = s_y;
    jet[2] = s_xx;
    jet[3] = s_xy;
    jet[4] = s_yy;
}

/* Row k of the weight table (k-th s-derivative of the Catmull-Rom weights times scale). */
static inline SFC_INLINE void fill_basis(double s, int k, double scale, double w[4][4]) {
    const double s2 = s * s, s3 = s2 * s;
    if (k == 0) {
        w[0][0] = 0.5 * (-s3 + 2.0 * s2 - s);
        w[0][1] = 0.5 * (3.0 * s3 - 5.0 * s2 + 2.0);
        w[0][2] = 0.5 * (-3.0 * s3 + 4.0 * s2 + s);
        w[0][3] = 0.5 * (s3 - s2);
    } else if (k == 1) {
        w[1][0] = scale * 0.5 * (-3.0 * s2 + 4.0 * s - 1.0);
        w[1][1] = scale * 0.5 * (9.0 * s2 - 10.0 * s);
        w[1][2] = scale * 0.5 * (-9.0 * s2 + 8.0 * s + 1.0);
        w[1][3] = scale * 0.5 * (3.0 * s2 - 2.0 * s);
    } else if (k == 2) {
        w[2][0] = scale * (-3.0 * s + 2.0);
        w[2][1] = scale * (9.0 * s - 5.0);
        w[2][2] = scale * (-9.0 * s + 4.0);
        w[2][3] = scale * (3.0 * s - 1.0);
    } else {
        w[3][0] = scale * -3.0;
        w[3][1] = scale * 9.0;
        w[3][2] = scale * -9.0;
        w[3][3] = scale * 3.0;
    }
}

/* Weight tables of derivative orders 0 .. 3 at coord (axis_weights); returns the cell index. */
static inline SFC_INLINE int axis_weights(double coord, double origin, double spacing, int m, double w[4][4]) {
    double s, k;
    const int i = cell(coord, origin, spacing, m, &s, &k);
    const int inside = k != 0.0;  /* cell's scale is 0 off the grid */
    double scale = 1.0;
    for (int order = 0; order < 4; order++) {
        fill_basis(s, order, inside ? scale : 0.0, w);
        scale /= spacing;
    }
    return i;
}

static inline SFC_INLINE double contract(const double p[4][4], const double wx[4][4], int kx, const double wy[4][4], int ky) {
    double acc = 0.0;
    for (int a = 0; a < 4; a++)
        acc += wy[ky][a] * (wx[kx][0] * p[a][0] + wx[kx][1] * p[a][1] + wx[kx][2] * p[a][2] + wx[kx][3] * p[a][3]);
    return acc;
}

/* Add to grad the gradient w.r.t. d of g_t t + <g_jet, jet> at the hit (x, y) of the ray along w
 * (hit_adjoint_patch, then scatter_patch, in operators/heightfield/intersect_native.py). */
static void hit_adjoint_scalar(const double *d, double *grad, int64_t m, double x, double y, double origin,
                               double spacing, vec3 w, const double g[6]) {
    double wx[4][4], wy[4][4], p[4][4];
    const int mm = (int)m;
    const int ix = axis_weights(x, origin, spacing, mm, wx);
    const int iy = axis_weights(y, origin, spacing, mm, wy);
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++) p[a][b] = d[node(iy - 1 + a, mm) * mm + node(ix - 1 + b, mm)];
    const double sx = contract(p, wx, 1, wy, 0), sy = contract(p, wx, 0, wy, 1);
    const double sxx = contract(p, wx, 2, wy, 0), sxy = contract(p, wx, 1, wy, 1), syy = contract(p, wx, 0, wy, 2);
    const double sxxx = contract(p, wx, 3, wy, 0), sxxy = contract(p, wx, 2, wy, 1);
    const double sxyy = contract(p, wx, 1, wy, 2), syyy = contract(p, wx, 0, wy, 3);
    const double g_t = g[0], g_sx = g[1], g_sy = g[2], g_sxx = g[3], g_sxy = g[4], g_syy = g[5];
    const double along = g_t + g_sx * (sxx * w.x + sxy * w.y) + g_sy * (sxy * w.x + syy * w.y)
                         + g_sxx * (sxxx * w.x + sxxy * w.y) + g_sxy * (sxxy * w.x + sxyy * w.y)
                         + g_syy * (sxyy * w.x + syyy * w.y);
    const double c = along / (w.z - sx * w.x - sy * w.y);
    for (int a = 0; a < 4; a++) {
        double *row = grad + node(iy - 1 + a, mm) * mm;
        for (int b = 0; b < 4; b++)
            row[node(ix - 1 + b, mm)] += wy[0][a] * (c * wx[0][b] + g_sx * wx[1][b] + g_sxx * wx[2][b])
                                                + wy[1][a] * (g_sy * wx[0][b] + g_sxy * wx[1][b])
                                                + wy[2][a] * g_syy * wx[0][b];
    }
}

/* The AVX2 surface jets and hit adjoint of simd_kernels.c: the kernels here call them only where
 * the scene's `simd` is set (the CPU has AVX2 and FMA). */
void sfc_surface_jets(const double *d, int64_t m, double origin, double inv_spacing, double ox, double oy,
                      const double *dirs, int64_t stride, const double *t, int64_t count, double *jets);
void sfc_hit_adjoint(const double *d, double *grad, int64_t m, double x, double y, double origin, double inv_spacing,
                     double wx, double wy, double wz, double g_t, double g_sx, double g_sy, double g_sxx,
                     double g_sxy, double g_syy);

/* hit_adjoint_scalar's sum into grad, by the AVX2 kernel where sc->simd. */
static inline SFC_INLINE void hit_adjoint(const sfc_scene *sc, const double *d, double *grad, int64_t m, double x,
                                          double y, vec3 w, const double g[6]) {
    if (sc->simd)
        sfc_hit_adjoint(d, grad, m, x, y, -sc->half, 1.0 / sc->spacing, w.x, w.y, w.z, g[0], g[1], g[2], g[3], g[4],
                        g[5]);
    else
        hit_adjoint_scalar(d, grad, m, x, y, -sc->half, sc->spacing, w, g);
}

/* The surface's jet at the point (x, y) (surface_jet_at), by the AVX2 kernel where sc->simd (its
 * ray from (x, y) with no length lands on the point itself). */
static inline SFC_INLINE void surface_jet(const sfc_scene *sc, const double *d, int64_t m, double x, double y,
                                          double jet[5]) {
    if (sc->simd) {
        static const double along[2] = {0.0, 0.0}, at = 0.0;
        sfc_surface_jets(d, m, -sc->half, 1.0 / sc->spacing, x, y, along, 1, &at, 1, jet);
    } else {
        surface_jet_at(d, m, x, y, -sc->half, sc->spacing, jet);
    }
}

/* ---------------------------------------------------------------- hit search */

static inline SFC_INLINE int needs_march(vec3 w, double slope_x, double slope_y) {
    return !(slope_x * fabs(w.x) + slope_y * fabs(w.y) < fabs(w.z));
}

/* Height of the ray o + t w above the surface at t, and its t-derivative. */
static inline SFC_INLINE void gap_at(const double *d, int64_t m, const sfc_scene *sc, vec3 o, vec3 w, double t, double *g,
                          double *slope) {
    double s, sx, sy;
    surface_gradient(d, m, o.x + t * w.x, o.y + t * w.y, -sc->half, sc->spacing, &s, &sx, &sy);
    *g = o.z + t * w.z - sc->base - s;
    *slope = w.z - sx * w.x - sy * w.y;
}

/* One safeguarded Newton step inside the bracket; returns whether the step fell below `settle`. */
static inline SFC_INLINE int newton_update(double *t, double g, double slope, double *lo, double *hi, double settle) {
    if (g > 0.0) *lo = *t; else *hi = *t;
    const double t_new = slope != 0.0 ? *t - g / slope : 0.5 * (*lo + *hi);
    if (!(*lo <= t_new && t_new <= *hi)) {
        *t = 0.5 * (*lo + *hi);
        return 0;
    }
    const int settled = fabs(t_new - *t) <= settle;
    *t = t_new;
    return settled;
}

/* The first hit of the ray o + t w on the surface: its t (solve_hit). */
static double solve_hit(const double *d, int64_t m, const sfc_scene *sc, vec3 o, vec3 w) {
    const double oz = o.z;
    const double t_a = (sc->zhi - oz) / w.z, t_b = (sc->zlo - oz) / w.z;
    const double travel = sqrt(w.x * w.x + w.y * w.y) * (t_b - t_a);
    int64_t steps = (int64_t)dmin(dmax(ceil(travel / (0.5 * sc->spacing)), 1.0), (double)sc->max_march_steps);
    if (!needs_march(w, sc->slope_x, sc->slope_y)) steps = 1;
    const double dt = (t_b - t_a) / (double)steps;
    double lo = t_a, hi = t_b, g = 0.0, slope = 0.0;
    int known = 0;
    for (int64_t k = 1; k < steps; k++) {
        const double t_k = t_a + (double)k * dt;
        gap_at(d, m, sc, o, w, t_k, &g, &slope);
        if (g <= 0.0) {
            hi = t_k;
            known = 1;
            break;
        }
        lo = t_k;
    }
    double t = known ? hi : dmin(dmax((sc->zstart - oz) / w.z, lo), hi);
    const double z_scale = fabs(oz) + fabs(sc->zhi) + 1.0, tol = 1e-12 * z_scale, settle = sc->settle * z_scale;
    for (int64_t it = 0; it < sc->newton_iterations; it++) {
        if (!known) gap_at(d, m, sc, o, w, t, &g, &slope);
        known = 0;
        if (fabs(g) <= tol) break;
        if (newton_update(&t, g, slope, &lo, &hi, settle)) break;
    }
    return t;
}

/* ---------------------------------------------------------------- hit search of a packet */

enum { SEARCH_LANES = 128 }; /* the most rays one lockstep search takes */

/* A lockstep hit search's work space (solve_hits): per ray the bracket, whether it still iterates,
 * its gap and slope at t and its tolerances. */
typedef struct {
    double lo[SEARCH_LANES], hi[SEARCH_LANES], active[SEARCH_LANES], gap[SEARCH_LANES], slope[SEARCH_LANES];
    double tol[SEARCH_LANES], settle[SEARCH_LANES];
} search_state;

/* Gap and slope of every ray k < count at t[k], converged or not (packet_gaps): a branch-free
 * loop over independent surface evaluations, which GCC vectorises with gathers (restrict: the
 * heights and the scene are not written here). */
static void packet_gaps(const double *restrict d, int64_t m, const sfc_scene *restrict sc,
                        const double (*restrict o)[SEARCH_LANES], const double (*restrict w)[SEARCH_LANES],
                        const double *restrict t, int64_t count, double *restrict gap, double *restrict slope) {
    for (int64_t k = 0; k < count; k++)
        gap_at(d, m, sc, v3(o[0][k], o[1][k], o[2][k]), v3(w[0][k], w[1][k], w[2][k]), t[k], &gap[k], &slope[k]);
}

/* Hits t[k] of the rays k < count from o[.][k] along w[.][k] (rows x, y, z): each ray that needs
 * a march is searched on its own (solve_hit), the others iterate Newton in lockstep, so that the
 * core overlaps their surface evaluations; every ray takes solve_hit's steps. */
static void solve_hits(const double *d, int64_t m, const sfc_scene *sc, const double (*o_rows)[SEARCH_LANES],
                       const double (*w_rows)[SEARCH_LANES], int64_t count, double *t, search_state *st) {
    for (int64_t k = 0; k < count; k++) {
        const vec3 o = v3(o_rows[0][k], o_rows[1][k], o_rows[2][k]), w = v3(w_rows[0][k], w_rows[1][k], w_rows[2][k]);
        const double z_scale = fabs(o.z) + fabs(sc->zhi) + 1.0;
        st->tol[k] = 1e-12 * z_scale;
        st->settle[k] = sc->settle * z_scale;
        if (needs_march(w, sc->slope_x, sc->slope_y)) {
            t[k] = solve_hit(d, m, sc, o, w);
            st->active[k] = 0.0;
        } else {
            st->lo[k] = (sc->zhi - o.z) / w.z;
            st->hi[k] = (sc->zlo - o.z) / w.z;
            st->active[k] = 1.0;
            t[k] = dmin(dmax((sc->zstart - o.z) / w.z, st->lo[k]), st->hi[k]);
        }
    }
    for (int64_t it = 0; it < sc->newton_iterations; it++) {
        packet_gaps(d, m, sc, o_rows, w_rows, t, count, st->gap, st->slope);
        int64_t iterating = 0;
        for (int64_t k = 0; k < count; k++) {
            if (st->active[k] == 0.0) continue;
            int settled = fabs(st->gap[k]) <= st->tol[k];
            if (!settled)
                settled = newton_update(&t[k], st->gap[k], st->slope[k], &st->lo[k], &st->hi[k], st->settle[k]);
            if (settled) st->active[k] = 0.0; else iterating++;
        }
        if (iterating == 0) break;
    }
}

/* ---------------------------------------------------------------- optics */

/* Move a photon dist along w onto a surface with normal n (transfer). */
static inline SFC_INLINE void transfer(const sfc_scene *sc, vec3 p, vec3 dpu, vec3 dpv, vec3 w, vec3 dwu, vec3 dwv, double dist,
                            vec3 n, vec3 *p1, vec3 *dpu1, vec3 *dpv1) {
    const vec3 mu = axpy(dist, dwu, dpu), mv = axpy(dist, dwv, dpv);
    const double den = away_from_zero(sc, dot(w, n));
    *p1 = axpy(dist, w, p);
    *dpu1 = axpy(-dot(mu, n) / den, w, mu);
    *dpv1 = axpy(-dot(mv, n) / den, w, mv);
}

typedef struct { vec3 g_dpu, g_dpv, g_w, g_dwu, g_dwv, g_n; double g_dist; } transfer_grads;

static inline SFC_INLINE transfer_grads transfer_adjoint(const sfc_scene *sc, vec3 dpu, vec3 dpv, vec3 w, vec3 dwu, vec3 dwv,
                                              double dist, vec3 n, vec3 g_p, vec3 g_dpu, vec3 g_dpv) {
    transfer_grads r;
    const vec3 mu = axpy(dist, dwu, dpu), mv = axpy(dist, dwv, dpv);
    const double wn = dot(w, n), den = away_from_zero(sc, wn);
    const double ddu = -dot(mu, n) / den, ddv = -dot(mv, n) / den;
    const double g_ddu = dot(g_dpu, w), g_ddv = dot(g_dpv, w);
    vec3 g_w = axpy(dist, g_p, axpy(ddu, g_dpu, scale3(ddv, g_dpv)));
    const vec3 g_mu = axpy(-g_ddu / den, n, g_dpu), g_mv = axpy(-g_ddv / den, n, g_dpv);
    vec3 g_n = axpy(-g_ddu / den, mu, scale3(-g_ddv / den, mv));
    const double g_wn = -(g_ddu * ddu + g_ddv * ddv) / den * passes(sc, wn);
    r.g_w = axpy(g_wn, n, g_w);
    r.g_n = axpy(g_wn, w, g_n);
    r.g_dist = dot(g_p, w) + dot(g_mu, dwu) + dot(g_mv, dwv);
    r.g_dpu = g_mu;
    r.g_dpv = g_mv;
    r.g_dwu = scale3(dist, g_mu);
    r.g_dwv = scale3(dist, g_mv);
    return r;
}

/* Snell refraction with differentials, eta = n_incident / n_transmitted; returns k (<= 0: TIR). */
static inline SFC_INLINE double refract(vec3 w, vec3 dwu, vec3 dwv, vec3 n, vec3 dnu, vec3 dnv, double eta, vec3 *w1, vec3 *dwu1,
                             vec3 *dwv1, double *ci_out, double *ct_out) {
    const double ci = -dot(w, n);
    const double k = 1.0 - eta * eta * (1.0 - ci * ci);
    const double ct = sqrt(dmax(k, 1e-12));
    const double a = eta * ci - ct;
    const double dciu = -dot(dwu, n) - dot(w, dnu), dciv = -dot(dwv, n) - dot(w, dnv);
    const double bu = eta * dciu - eta * eta * ci * dciu / ct, bv = eta * dciv - eta * eta * ci * dciv / ct;
    *w1 = axpy(a, n, scale3(eta, w));
    *dwu1 = axpy(a, dnu, axpy(bu, n, scale3(eta, dwu)));
    *dwv1 = axpy(a, dnv, axpy(bv, n, scale3(eta, dwv)));
    *ci_out = ci;
    *ct_out = ct;
    return k;
}

/* The adjoint of one refracted differential's b-term (_refract_differential_adjoint). */
static inline SFC_INLINE void refract_differential_adjoint(vec3 w, vec3 dw, vec3 n, vec3 dn, double eta, double ci, double ct,
                                                vec3 g_dw1, vec3 *g_dw, vec3 *g_dn, vec3 *g_n, vec3 *g_w, double *g_ci,
                                                double *g_ct) {
    const double e2 = eta * eta;
    const double dci = -dot(dw, n) - dot(w, dn);
    const double dct = e2 * ci * dci / ct;
    const double g_b = dot(g_dw1, n);
    const vec3 gn = axpy(eta * dci - dct, g_dw1, *g_n);
    const double g_dct = -g_b;
    const double g_dci = eta * g_b + g_dct * e2 * ci / ct;
    *g_ci += g_dct * e2 * dci / ct;
    *g_ct -= g_dct * dct / ct;
    *g_dw = axpy(-g_dci, n, *g_dw);
    *g_dn = axpy(-g_dci, w, *g_dn);
    *g_n = axpy(-g_dci, dw, gn);
    *g_w = axpy(-g_dci, dn, *g_w);
}

typedef struct { vec3 g_w, g_dwu, g_dwv, g_n, g_dnu, g_dnv; } refract_grads;

static inline SFC_INLINE refract_grads refract_adjoint(vec3 w, vec3 dwu, vec3 dwv, vec3 n, vec3 dnu, vec3 dnv, double eta,
                                            vec3 g_w1, vec3 g_dwu1, vec3 g_dwv1, double g_ci, double g_ct) {
    refract_grads r;
    const double ci = -dot(w, n);
    const double k = 1.0 - eta * eta * (1.0 - ci * ci);
    const double ct = sqrt(dmax(k, 1e-12));
    const double a = eta * ci - ct, e2 = eta * eta;
    r.g_w = scale3(eta, g_w1);
    double g_a = dot(g_w1, n);
    r.g_n = scale3(a, g_w1);
    r.g_dwu = scale3(eta, g_dwu1);
    r.g_dwv = scale3(eta, g_dwv1);
    r.g_dnu = scale3(a, g_dwu1);
    r.g_dnv = scale3(a, g_dwv1);
    g_a += dot(g_dwu1, dnu) + dot(g_dwv1, dnv);
    refract_differential_adjoint(w, dwu, n, dnu, eta, ci, ct, g_dwu1, &r.g_dwu, &r.g_dnu, &r.g_n, &r.g_w, &g_ci, &g_ct);
    refract_differential_adjoint(w, dwv, n, dnv, eta, ci, ct, g_dwv1, &r.g_dwv, &r.g_dnv, &r.g_n, &r.g_w, &g_ci, &g_ct);
    g_ci += eta * g_a;
    g_ct -= g_a;
    const double g_k = k >= 1e-12 ? 0.5 * g_ct / ct : 0.0;
    g_ci += g_k * 2.0 * e2 * ci;
    r.g_w = axpy(-g_ci, n, r.g_w);
    r.g_n = axpy(-g_ci, w, r.g_n);
    return r;
}

static inline SFC_INLINE double fresnel(double ci, double ct, double eta) {
    const double rs = (eta * ci - ct) / (eta * ci + ct), rp = (ci - eta * ct) / (ci + eta * ct);
    return 1.0 - 0.5 * (rs * rs + rp * rp);
}

static inline SFC_INLINE void fresnel_adjoint(double ci, double ct, double eta, double g_t, double *g_ci, double *g_ct) {
    const double ss = eta * ci + ct, sp = ci + eta * ct;
    const double g_rs = -g_t * (eta * ci - ct) / ss, g_rp = -g_t * (ci - eta * ct) / sp;
    *g_ci = g_rs * 2.0 * eta * ct / (ss * ss) + g_rp * 2.0 * eta * ct / (sp * sp);
    *g_ct = -g_rs * 2.0 * eta * ci / (ss * ss) - g_rp * 2.0 * eta * ci / (sp * sp);
}

static inline SFC_INLINE vec3 height_field_normal(double sx, double sy) {
    const double inv = 1.0 / sqrt(1.0 + sx * sx + sy * sy);
    return v3(-sx * inv, -sy * inv, inv);
}

static inline SFC_INLINE void height_field_normal_adjoint(double sx, double sy, vec3 g_n, double *g_sx, double *g_sy) {
    const double inv = 1.0 / sqrt(1.0 + sx * sx + sy * sy);
    const double g_inv = -g_n.x * sx - g_n.y * sy + g_n.z;
    const double c = -g_inv * inv * inv * inv;
    *g_sx = -g_n.x * inv + c * sx;
    *g_sy = -g_n.y * inv + c * sy;
}

static inline SFC_INLINE vec3 normal_differential(double sxx, double sxy, double syy, vec3 n, vec3 dp) {
    const vec3 r = v3(-(sxx * dp.x + sxy * dp.y), -(sxy * dp.x + syy * dp.y), 0.0);
    return scale3(n.z, axpy(-dot(r, n), n, r));
}

/* Adjoint of normal_differential: adds to g_sxx, g_sxy, g_syy; returns g_n, g_dp. */
static inline SFC_INLINE void normal_differential_adjoint(double sxx, double sxy, double syy, vec3 n, vec3 dp, vec3 g_dn,
                                               double *g_sxx, double *g_sxy, double *g_syy, vec3 *g_n_out,
                                               vec3 *g_dp) {
    const vec3 r = v3(-(sxx * dp.x + sxy * dp.y), -(sxy * dp.x + syy * dp.y), 0.0);
    const double s = dot(r, n);
    const vec3 q = axpy(-s, n, r);
    const vec3 g_q = scale3(n.z, g_dn);
    const double g_s = -dot(g_q, n);
    const vec3 g_r = axpy(g_s, n, g_q);
    vec3 g_n = axpy(g_s, r, scale3(-s, g_q));
    g_n.z += dot(g_dn, q);
    *g_n_out = g_n;
    *g_dp = v3(-g_r.x * sxx - g_r.y * sxy, -g_r.x * sxy - g_r.y * syy, 0.0);
    *g_sxx += -g_r.x * dp.x;
    *g_sxy += -g_r.x * dp.y - g_r.y * dp.x;
    *g_syy += -g_r.y * dp.y;
}

static inline SFC_INLINE double bound(const sfc_scene *sc, double x) {
    return dmin(dmax(x, -sc->max_differential_px), sc->max_differential_px);
}
static inline SFC_INLINE double inside_bound(const sfc_scene *sc, double x) {
    return ((-sc->max_differential_px <= x) & (x <= sc->max_differential_px)) ? 1.0 : 0.0;
}

/* Metric (q00, q01, q11) of the footprint spanned by Du = (ux, uy), Dv = (vx, vy) (pixels). */
static inline SFC_INLINE void footprint_metric(const sfc_scene *sc, double ux, double uy, double vx, double vy, double q[3]) {
    const double r0 = sc->min_px, rmax = sc->max_px;
    ux = bound(sc, ux);
    uy = bound(sc, uy);
    vx = bound(sc, vx);
    vy = bound(sc, vy);
    const double b00 = ux * ux + vx * vx, b01 = ux * uy + vx * vy, b11 = uy * uy + vy * vy;
    const double major = 0.5 * (b00 + b11) + sqrt(0.25 * (b00 - b11) * (b00 - b11) + b01 * b01 + 1e-300);
    const double r2 = r0 * r0;
    const double s = dmin((rmax * rmax - r2) / dmax(major, 1e-300), 1.0);
    const double a00 = b00 * s, a01 = b01 * s, a11 = b11 * s;
    const double det = dmax(a00 * a11 - a01 * a01, 0.0) + r2 * (a00 + a11) + r2 * r2;
    q[0] = (a11 + r2) / det;
    q[1] = -a01 / det;
    q[2] = (a00 + r2) / det;
}

static inline SFC_INLINE void footprint_metric_adjoint(const sfc_scene *sc, double ux, double uy, double vx, double vy,
                                            double g00, double g01, double g11, double g[4]) {
    const double r0 = sc->min_px, rmax = sc->max_px;
    const double mux = inside_bound(sc, ux), muy = inside_bound(sc, uy);
    const double mvx = inside_bound(sc, vx), mvy = inside_bound(sc, vy);
    ux = bound(sc, ux);
    uy = bound(sc, uy);
    vx = bound(sc, vx);
    vy = bound(sc, vy);
    const double b00 = ux * ux + vx * vx, b01 = ux * uy + vx * vy, b11 = uy * uy + vy * vy;
    const double root = sqrt(0.25 * (b00 - b11) * (b00 - b11) + b01 * b01 + 1e-300);
    const double major = 0.5 * (b00 + b11) + root;
    const double r2 = r0 * r0;
    const double ratio = (rmax * rmax - r2) / dmax(major, 1e-300);
    const double s = dmin(ratio, 1.0);
    const double a00 = b00 * s, a01 = b01 * s, a11 = b11 * s;
    const double e = a00 * a11 - a01 * a01;
    const double det = dmax(e, 0.0) + r2 * (a00 + a11) + r2 * r2;
    const double q00 = (a11 + r2) / det, q01 = -a01 / det, q11 = (a00 + r2) / det;
    const double g_det = -(g00 * q00 + g01 * q01 + g11 * q11) / det;
    const double pos = e >= 0.0 ? 1.0 : 0.0;
    const double g_a00 = g11 / det + g_det * (r2 + pos * a11);
    const double g_a11 = g00 / det + g_det * (r2 + pos * a00);
    const double g_a01 = -g01 / det - g_det * pos * 2.0 * a01;
    double g_b00 = s * g_a00, g_b01 = s * g_a01, g_b11 = s * g_a11;
    /* Where the cut-off scales the footprint: its gradient through the major axis (a select). */
    const int scaled = (ratio <= 1.0) & (major >= 1e-300);
    const double g_major = scaled ? -(g_a00 * b00 + g_a01 * b01 + g_a11 * b11) * s / major : 0.0;
    const double half_diff = 0.25 * (b00 - b11) / root;
    g_b00 += g_major * (0.5 + half_diff);
    g_b11 += g_major * (0.5 - half_diff);
    g_b01 += g_major * b01 / root;
    g[0] = (2.0 * ux * g_b00 + uy * g_b01) * mux;
    g[1] = (2.0 * uy * g_b11 + ux * g_b01) * muy;
    g[2] = (2.0 * vx * g_b00 + vy * g_b01) * mvx;
    g[3] = (2.0 * vy * g_b11 + vx * g_b01) * mvy;
}

#endif
