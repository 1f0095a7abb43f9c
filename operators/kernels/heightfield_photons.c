/* The fused height-field photon kernels in C: emission, surface hit, optics with photon
 * differentials, splat (render) and, for the gradient, the splat adjoint back through the optics
 * into the heights (vjp). Part of the compiled extension operators.kernels._simd (setup.py), so
 * they are compiled once, at install, and a run starts tracing at once.
 *
 * The same arithmetic, step for step, as the numba kernels they stand in for (float64 throughout,
 * only the images may be float32):
 *   emission ............ emit in operators/heightfield/kernels_native.py
 *   surface, hit search . surface_gradient / surface_jet_at in operators/heightfield/catmull_rom.py,
 *                         solve_hit / solve_hits in operators/heightfield/intersect_native.py
 *   optics .............. refract_top, below_top, splat_arguments in kernels_native.py, with
 *                         operators/optics/native.py (refract, transfer, Fresnel, footprint metric)
 *   splat, gather ....... splat_photon, gather_photon_simd in operators/splat/native.py
 *   adjoint ............. optics_adjoint, vjp_range in operators/heightfield/adjoint_native.py
 * With `simd` set (only where sfc_simd_supported()), the AVX2 functions of simd_kernels.c do the
 * fixed 8 x 8 splat box, its gather, both over each row's chord for larger footprints, the surface
 * jets and the hit adjoint, as in the numba kernels.
 * The numba kernels stay the fallback (no C compiler at install) and the reference the tests
 * compare these with.
 *
 * Compiled twice (setup.py): for the baseline x86-64 (or any other CPU) and, through
 * heightfield_photons_avx2.c, for AVX2 and FMA; the host calls the second where the CPU has them.
 * The loops over a packet's optics are written branch-free so that GCC vectorises them across
 * photons, as LLVM does in the numba kernels.
 *
 * The per-photon maths (surface, hit search, optics) is in photon_optics.h, shared with the
 * mesh-scene kernels (mesh_events.c).
 *
 * Threads: the host passes `threads` images (or gradients); this file starts that many POSIX
 * threads, which take fixed shares of the blocks of BLOCK photons (thread t: blocks t, t +
 * threads, ...) and accumulate into their own image, summed by the host: the same sums in every
 * run. The aimed rays, one output per ray, take blocks from a shared counter.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sfc_threads.h"

/* The exported functions' names: heightfield_photons_avx2.c compiles this file again for AVX2 and
 * FMA, with the suffix _avx2. */
#ifndef SFC_EXPORT
#define SFC_EXPORT(name) name
#endif

/* The AVX2 splat and gather kernels of simd_kernels.c (called only when the scene's `simd` is set;
 * the jets' and hit adjoint's are declared in photon_optics.h). */
void sfc_splat_box8_f64(double *img, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                        double q00, double q01, double q11, double f);
void sfc_splat_box8_f32(float *img, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                        double q00, double q01, double q11, double f);
void sfc_gather_box8(const double *g, int64_t offset, int64_t stride, int64_t rows, double rx0, double ry0,
                     double q00, double q01, double q11, double *sums);
void sfc_splat_spans_f64(double *img, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                         double ry0, double q00, double q01, double q11, double f);
void sfc_splat_spans_f32(float *img, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                         double ry0, double q00, double q01, double q11, double f);
void sfc_gather_spans(const double *g, int64_t offset, int64_t stride, int64_t rows, int64_t width, double rx0,
                      double ry0, double q00, double q01, double q11, double *sums);

#include "photon_optics.h"

enum { PACKET = SEARCH_LANES, BLOCK = 4096, LANES = 8, SPAN_TAIL = 3 };

/* ---------------------------------------------------------------- emission */

typedef struct { int64_t c; vec3 w, dwu, dwv; double flux; } emitted;

static inline SFC_INLINE emitted emit(const sfc_scene *sc, const double *shifts, int64_t index) {
    emitted e;
    e.c = index / sc->per_channel;
    const double j = (double)(index - e.c * sc->per_channel);
    double u = shifts[2 * e.c] + j * sc->r2_u, v = shifts[2 * e.c + 1] + j * sc->r2_v;
    u -= floor(u);
    v -= floor(v);
    const double dx = (2.0 * sc->aim_half) * u - sc->aim_half - sc->light_x;
    const double dy = (2.0 * sc->aim_half) * v - sc->aim_half - sc->light_y;
    const double dz = sc->base - sc->light_z;
    const double inv_r = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
    e.w = v3(dx * inv_r, dy * inv_r, dz * inv_r);
    const double s = sc->radius * inv_r;
    e.dwu = v3(s - e.w.x * e.w.x * s, -e.w.y * e.w.x * s, -e.w.z * e.w.x * s);
    e.dwv = v3(-e.w.x * e.w.y * s, s - e.w.y * e.w.y * s, -e.w.z * e.w.y * s);
    e.flux = sc->flux_scale * inv_r * inv_r * inv_r;
    return e;
}

/* Every intermediate of a photon's optics from its hit to the receiver (optics_state). */
typedef struct {
    vec3 n1, p1, dpu1, dpv1, dnu, dnv, w1, dwu1, dwv1;
    double ci1, ct1;
    double lost;  /* 1 where the photon is lost (an absorbing wall, total internal reflection), else 0 */
    vec3 n2;      /* normal of the face it leaves through, facing it: the bottom or a side wall */
    double fx, fy, code; /* the walls' mirror of the landing (x -> fx x + ox, y likewise); path code */
    double dist2;
    vec3 p2, dpu2, dpv2, w2, dwu2, dwv2;
    double ci2, ct2, dist3;
    vec3 p3, dpu3, dpv3;  /* on the receiver, mirrored */
    double fu[2], fv[2];
} optics;

/* The face through which a photon at p1 in the glass along w1 leaves the block and the mirror
 * of its landing, or that it is lost (leaving_plane in operators/heightfield/side_walls.py): sets o->n2, o->fx,
 * o->fy, o->code (optics_state sets 0 for a lost photon) and returns the plane's offset c2
 * (n2 . p = c2); *ox, *oy the mirror's shifts, *walled 1 where a wall loses it. Flags are doubles 0 / 1 combined by arithmetic and the
 * comparisons are selects, so that GCC vectorises the loops over a packet. */
static inline SFC_INLINE double leaving_plane(const sfc_scene *sc, vec3 p1, vec3 w1, double eta, optics *o, double *ox,
                                              double *oy, double *walled) {
    const double half = sc->half;
    const double tb = -p1.z / away_from_zero(sc, w1.z);
    const double bx = p1.x + tb * w1.x, by = p1.y + tb * w1.y;
    const double cross_x = fabs(bx) > half ? 1.0 : 0.0, cross_y = fabs(by) > half ? 1.0 : 0.0;
    const double sx = bx > 0.0 ? 1.0 : -1.0, sy = by > 0.0 ? 1.0 : -1.0;
    const double e2 = eta * eta;
    const double exit_x = e2 * (1.0 - w1.x * w1.x) < 1.0 ? cross_x : 0.0;
    const double exit_y = e2 * (1.0 - w1.y * w1.y) < 1.0 ? cross_y : 0.0;
    const double tx = (sx * half - p1.x) * w1.x / dmax(w1.x * w1.x, 1e-300);
    const double ty = (sy * half - p1.y) * w1.y / dmax(w1.y * w1.y, 1e-300);
    const double x_first = tx < ty ? 1.0 : 0.0, y_first = ty < tx ? 1.0 : 0.0;
    const double via_x = exit_x * (1.0 - exit_y * (tx > ty ? 1.0 : 0.0));
    const double via_y = exit_y * (1.0 - via_x);
    const double fold_x = cross_x * (1.0 - via_x) * (1.0 - via_y * (1.0 - x_first));
    const double fold_y = cross_y * (1.0 - via_y) * (1.0 - via_x * (1.0 - y_first));
    const double far = (fabs(bx) > sc->fold_limit * half ? 1.0 : 0.0) + (fabs(by) > sc->fold_limit * half ? 1.0 : 0.0);
    const double absorbed = sc->clear_walls ? 0.0 : cross_x + cross_y;
    /* a top hit outside the square: the ray, aimed beyond it, passed beside the block */
    const double beside = (fabs(p1.x) > sc->beside * half ? 1.0 : 0.0) + (fabs(p1.y) > sc->beside * half ? 1.0 : 0.0);
    const double lost = far + absorbed + beside > 0.0 ? 1.0 : 0.0;
    o->n2 = v3(-sx * via_x, -sy * via_y, 1.0 - via_x - via_y);
    o->fx = 1.0 - 2.0 * fold_x;
    o->fy = 1.0 - 2.0 * fold_y;
    *ox = 2.0 * sx * half * fold_x;
    *oy = 2.0 * sy * half * fold_y;
    *walled = lost;
    o->code = 1.0 + fold_x * (sx > 0.0 ? 1.0 : 2.0) + 3.0 * fold_y * (sy > 0.0 ? 1.0 : 2.0)
              + 9.0 * (via_x + 2.0 * via_y);
    return -half * (via_x + via_y);
}

static inline SFC_INLINE void optics_state(const sfc_scene *sc, vec3 w, vec3 dwu, vec3 dwv, double t, const double jet[5],
                                double eta, optics *o) {
    const double sxx = jet[2], sxy = jet[3], syy = jet[4];
    o->n1 = height_field_normal(jet[0], jet[1]);
    transfer(sc, v3(sc->light_x, sc->light_y, sc->light_z), ZERO, ZERO, w, dwu, dwv, t, o->n1, &o->p1, &o->dpu1,
             &o->dpv1);
    o->dnu = normal_differential(sxx, sxy, syy, o->n1, o->dpu1);
    o->dnv = normal_differential(sxx, sxy, syy, o->n1, o->dpv1);
    refract(w, dwu, dwv, o->n1, o->dnu, o->dnv, 1.0 / eta, &o->w1, &o->dwu1, &o->dwv1, &o->ci1, &o->ct1);
    double ox, oy, walled;
    const double c2 = leaving_plane(sc, o->p1, o->w1, eta, o, &ox, &oy, &walled);
    o->dist2 = (c2 - dot(o->p1, o->n2)) / away_from_zero(sc, dot(o->w1, o->n2));
    transfer(sc, o->p1, o->dpu1, o->dpv1, o->w1, o->dwu1, o->dwv1, o->dist2, o->n2, &o->p2, &o->dpu2, &o->dpv2);
    const double k2 = refract(o->w1, o->dwu1, o->dwv1, o->n2, ZERO, ZERO, eta, &o->w2, &o->dwu2, &o->dwv2, &o->ci2,
                              &o->ct2);
    o->lost = dmax(walled, k2 <= 0.0 ? 1.0 : 0.0);
    o->code = o->lost != 0.0 ? 0.0 : o->code;
    o->dist3 = (sc->receiver_z - o->p2.z) / away_from_zero(sc, o->w2.z);
    transfer(sc, o->p2, o->dpu2, o->dpv2, o->w2, o->dwu2, o->dwv2, o->dist3, UP, &o->p3, &o->dpu3, &o->dpv3);
    o->p3 = v3(o->fx * o->p3.x + ox, o->fy * o->p3.y + oy, o->p3.z);
    o->dpu3 = v3(o->fx * o->dpu3.x, o->fy * o->dpu3.y, o->dpu3.z);
    o->dpv3 = v3(o->fx * o->dpv3.x, o->fy * o->dpv3.y, o->dpv3.z);
    o->fu[0] = o->dpu3.x * sc->to_px;
    o->fu[1] = o->dpu3.y * sc->to_px;
    o->fv[0] = o->dpv3.x * sc->to_px;
    o->fv[1] = o->dpv3.y * sc->to_px;
}

/* (px, py, q00, q01, q11, flux) of the photon on the receiver (splat_arguments). */
static inline SFC_INLINE void splat_arguments(const sfc_scene *sc, double flux, double eta, const optics *o,
                                              double spot[6]) {
    const double transmitted = fresnel(o->ci1, o->ct1, 1.0 / eta) * fresnel(o->ci2, o->ct2, eta);
    flux = sc->fresnel ? flux * transmitted : flux;
    double q[3];
    footprint_metric(sc, o->fu[0], o->fu[1], o->fv[0], o->fv[1], q);
    /* A lost photon carries no flux, so that the splat and its gather skip it (its position and
     * metric may be NaN: not read). Arithmetic and one select, not branches: GCC vectorises the
     * loop over the packet only in this form. */
    const double kept = o->lost != 0.0 ? 0.0 : 1.0;
    spot[0] = kept * ((o->p3.x + sc->receiver_half) * sc->to_px - 0.5);
    spot[1] = kept * ((o->p3.y + sc->receiver_half) * sc->to_px - 0.5);
    spot[2] = kept * q[0] + (1.0 - kept);
    spot[3] = kept * q[1];
    spot[4] = kept * q[2] + (1.0 - kept);
    spot[5] = o->lost != 0.0 ? 0.0 : flux;
}

/* Reverse mode through the optics (optics_adjoint): from the gradients w.r.t. the splat
 * arguments g = (flux, px, py, q00, q01, q11) back to (t, S_x, S_y, S_xx, S_xy, S_yy) in out. */
static inline SFC_INLINE void optics_adjoint(const sfc_scene *sc, vec3 w, vec3 dwu, vec3 dwv, double flux0, double t,
                           const double jet[5], double eta, const optics *o, const double g[6], double out[6]) {
    const double sx = jet[0], sy = jet[1], sxx = jet[2], sxy = jet[3], syy = jet[4];
    const double t1 = sc->fresnel ? fresnel(o->ci1, o->ct1, 1.0 / eta) : 1.0;
    const double t2 = sc->fresnel ? fresnel(o->ci2, o->ct2, eta) : 1.0;
    const double k = sc->to_px;
    double gf[4];
    footprint_metric_adjoint(sc, o->fu[0], o->fu[1], o->fv[0], o->fv[1], g[3], g[4], g[5], gf);
    /* Receiver plane. */
    const vec3 g_p3 = v3(g[1] * k * o->fx, g[2] * k * o->fy, 0.0);
    const transfer_grads a3 = transfer_adjoint(sc, o->dpu2, o->dpv2, o->w2, o->dwu2, o->dwv2, o->dist3, UP, g_p3,
                                               v3(gf[0] * k * o->fx, gf[1] * k * o->fy, 0.0),
                                               v3(gf[2] * k * o->fx, gf[3] * k * o->fy, 0.0));
    const double den3 = away_from_zero(sc, o->w2.z);
    const vec3 g_p2 = v3(g_p3.x, g_p3.y, g_p3.z - a3.g_dist / den3);
    const vec3 g_w2 = v3(a3.g_w.x, a3.g_w.y, a3.g_w.z - a3.g_dist * o->dist3 / den3 * passes(sc, o->w2.z));
    /* Refraction and transfer at the face the photon leaves through (the bottom or a wall, n2). */
    double f_ci2, f_ct2, f_ci1, f_ct1;
    fresnel_adjoint(o->ci2, o->ct2, eta, g[0] * flux0 * t1, &f_ci2, &f_ct2);
    fresnel_adjoint(o->ci1, o->ct1, 1.0 / eta, g[0] * flux0 * t2, &f_ci1, &f_ct1);
    const double g_ci2 = sc->fresnel ? f_ci2 : 0.0, g_ct2 = sc->fresnel ? f_ct2 : 0.0;
    const double g_ci1 = sc->fresnel ? f_ci1 : 0.0, g_ct1 = sc->fresnel ? f_ct1 : 0.0;
    const refract_grads r2 = refract_adjoint(o->w1, o->dwu1, o->dwv1, o->n2, ZERO, ZERO, eta, g_w2, a3.g_dwu, a3.g_dwv,
                                             g_ci2, g_ct2);
    const transfer_grads a2 = transfer_adjoint(sc, o->dpu1, o->dpv1, o->w1, o->dwu1, o->dwv1, o->dist2, o->n2, g_p2,
                                               a3.g_dpu, a3.g_dpv);
    const double wn2 = dot(o->w1, o->n2), den2 = away_from_zero(sc, wn2);
    const vec3 g_p1 = axpy(-a2.g_dist / den2, o->n2, g_p2);
    const vec3 g_w1 = axpy(-a2.g_dist * o->dist2 / den2 * passes(sc, wn2), o->n2, add3(r2.g_w, a2.g_w));
    /* Top refraction, normal differential, top transfer, normal. */
    const refract_grads r1 = refract_adjoint(w, dwu, dwv, o->n1, o->dnu, o->dnv, 1.0 / eta, g_w1,
                                             add3(r2.g_dwu, a2.g_dwu), add3(r2.g_dwv, a2.g_dwv), g_ci1, g_ct1);
    double g_sxx = 0.0, g_sxy = 0.0, g_syy = 0.0, g_sxx2 = 0.0, g_sxy2 = 0.0, g_syy2 = 0.0;
    vec3 g_nu, g_dpu, g_nv, g_dpv;
    normal_differential_adjoint(sxx, sxy, syy, o->n1, o->dpu1, r1.g_dnu, &g_sxx, &g_sxy, &g_syy, &g_nu, &g_dpu);
    normal_differential_adjoint(sxx, sxy, syy, o->n1, o->dpv1, r1.g_dnv, &g_sxx2, &g_sxy2, &g_syy2, &g_nv, &g_dpv);
    const transfer_grads a1 = transfer_adjoint(sc, ZERO, ZERO, w, dwu, dwv, t, o->n1, g_p1, add3(a2.g_dpu, g_dpu),
                                               add3(a2.g_dpv, g_dpv));
    double g_sx, g_sy;
    height_field_normal_adjoint(sx, sy, add3(add3(r1.g_n, g_nu), add3(g_nv, a1.g_n)), &g_sx, &g_sy);
    out[0] = a1.g_dist;
    out[1] = g_sx;
    out[2] = g_sy;
    out[3] = g_sxx + g_sxx2;
    out[4] = g_sxy + g_sxy2;
    out[5] = g_syy + g_syy2;
}

/* ---------------------------------------------------------------- splat and gather */

static inline SFC_INLINE int footprint_usable(const sfc_scene *sc, double f, double px, double py, double q00, double q01,
                                   double q11) {
    return f != 0.0 && isfinite(f) && fabs(px) < sc->far_px && fabs(py) < sc->far_px && q00 > 0.0 && q11 > 0.0
           && q00 * q11 - q01 * q01 > 0.0;
}

static inline SFC_INLINE void footprint_box(double px, double py, double q00, double q01, double q11, int64_t *x0, int64_t *x1,
                                 int64_t *y0, int64_t *y1) {
    const double det = q00 * q11 - q01 * q01;
    const double hx = sqrt(q11 / det), hy = sqrt(q00 / det);
    *x0 = (int64_t)ceil(px - hx);
    *x1 = (int64_t)floor(px + hx);
    *y0 = (int64_t)ceil(py - hy);
    *y1 = (int64_t)floor(py + hy);
}

static inline SFC_INLINE int fits_fixed_box(int64_t x0, int64_t x1, int64_t y0, int64_t y1, int64_t lo, int64_t hi) {
    return x1 - x0 < LANES && y1 - y0 < LANES && x0 >= lo && y0 >= lo && x0 + LANES - 1 <= hi && y0 + LANES - 1 <= hi;
}

/* Whether the bounding box and SPAN_TAIL columns past it lie in columns and rows lo .. hi (_fits_spans). */
static inline SFC_INLINE int fits_spans(int64_t x0, int64_t x1, int64_t y0, int64_t y1, int64_t lo, int64_t hi) {
    return x0 >= lo && y0 >= lo && y1 <= hi && x1 + SPAN_TAIL <= hi;
}

/* Silverman weights of the rows x width pixels from (x0, y0) into buf; returns their sum. */
static inline SFC_INLINE double box_weights(double *buf, int64_t x0, int64_t y0, int64_t width, int64_t rows, double px,
                                 double py, double q00, double q01, double q11) {
    double s = 0.0;
    const double rx0 = (double)x0 - px;
    for (int64_t r = 0; r < rows; r++) {
        const double ry = (double)(y0 + r) - py;
        const double b = 2.0 * q01 * ry, e = q11 * ry * ry;
        for (int64_t j = 0; j < width; j++) {
            const double rx = rx0 + (double)j;
            const double u = dmax(1.0 - ((q00 * rx + b) * rx + e), 0.0);
            buf[r * width + j] = u * u;
            s += u * u;
        }
    }
    return s;
}

/* One photon's flux into channel c of the image (channels, n, n), float64 or float32 (splat_photon). */
static void splat_photon(const sfc_scene *sc, void *img, int f32, int64_t n, int64_t c, const double spot[6],
                         double *buf, int64_t capacity) {
    const double px = spot[0], py = spot[1], q00 = spot[2], q01 = spot[3], q11 = spot[4], f = spot[5];
    if (!footprint_usable(sc, f, px, py, q00, q01, q11)) return;
    int64_t x0, x1, y0, y1;
    footprint_box(px, py, q00, q01, q11, &x0, &x1, &y0, &y1);
    const int64_t plane = c * n * n;
    int64_t width, rows, lo, hi, ylo, yhi;
    if (fits_fixed_box(x0, x1, y0, y1, 0, n - 1) && capacity >= LANES * LANES) {
        if (sc->simd) {
            if (f32)
                sfc_splat_box8_f32((float *)img, plane + y0 * n + x0, n, y1 - y0 + 1, (double)x0 - px,
                                   (double)y0 - py, q00, q01, q11, f);
            else
                sfc_splat_box8_f64((double *)img, plane + y0 * n + x0, n, y1 - y0 + 1, (double)x0 - px,
                                   (double)y0 - py, q00, q01, q11, f);
            return;
        }
        width = rows = LANES;
        lo = x0; hi = x0 + LANES - 1; ylo = y0; yhi = y0 + LANES - 1;
    } else {
        width = x1 - x0 + 1;
        rows = y1 - y0 + 1;
        if (width <= 0 || rows <= 0) return;
        if (sc->simd && fits_spans(x0, x1, y0, y1, 0, n - 1)) {
            if (f32)
                sfc_splat_spans_f32((float *)img, plane + y0 * n + x0, n, rows, width, (double)x0 - px,
                                    (double)y0 - py, q00, q01, q11, f);
            else
                sfc_splat_spans_f64((double *)img, plane + y0 * n + x0, n, rows, width, (double)x0 - px,
                                    (double)y0 - py, q00, q01, q11, f);
            return;
        }
        if (width * rows > capacity) return;
        lo = imax(x0, 0); hi = imin(x1, n - 1); ylo = imax(y0, 0); yhi = imin(y1, n - 1);
    }
    const double s = box_weights(buf, x0, y0, width, rows, px, py, q00, q01, q11);
    if (!(s > 0.0)) return;
    const double scale = f / s;
    for (int64_t iy = ylo; iy <= yhi; iy++) {
        const double *w = buf + (iy - y0) * width - x0;
        if (f32) {
            float *row = (float *)img + plane + iy * n;
            for (int64_t ix = lo; ix <= hi; ix++) row[ix] = (float)((double)row[ix] + scale * w[ix]);
        } else {
            double *row = (double *)img + plane + iy * n;
            for (int64_t ix = lo; ix <= hi; ix++) row[ix] += scale * w[ix];
        }
    }
}

/* The sums of the splat's adjoint over rows x width pixels from (x0, y0) of the padded G
 * (_gather_box): (s, sum G w, v0 .. v4, u0 .. u4). */
static void gather_box(const double *plane, int64_t stride, int64_t pad, int64_t x0, int64_t y0, int64_t width,
                       int64_t rows, double px, double py, double q00, double q01, double q11, double sums[12]) {
    double s = 0.0, gw = 0.0, v[5] = {0.0, 0.0, 0.0, 0.0, 0.0}, u[5] = {0.0, 0.0, 0.0, 0.0, 0.0};
    for (int64_t r = 0; r < rows; r++) {
        const double ry = (double)(y0 + r) - py;
        const double b = 2.0 * q01 * ry, e = q11 * ry * ry;
        const double *row = plane + (y0 + r + pad) * stride + x0 + pad;
        double sw = 0.0, a0 = 0.0, a1 = 0.0, a2 = 0.0, gsw = 0.0, g0 = 0.0, g1 = 0.0, g2 = 0.0;
        for (int64_t j = 0; j < width; j++) {
            const double rx = (double)(x0 + j) - px;
            const double uu = dmax(1.0 - ((q00 * rx + b) * rx + e), 0.0);
            const double gu = row[j] * uu;
            sw += uu * uu;
            a0 += uu;
            a1 += uu * rx;
            a2 += uu * rx * rx;
            gsw += gu * uu;
            g0 += gu;
            g1 += gu * rx;
            g2 += gu * rx * rx;
        }
        s += sw;
        gw += gsw;
        v[0] -= 2.0 * (q00 * a1 + q01 * ry * a0);
        v[1] -= 2.0 * (q01 * a1 + q11 * ry * a0);
        v[2] += a2;
        v[3] += 2.0 * ry * a1;
        v[4] += ry * ry * a0;
        u[0] -= 2.0 * (q00 * g1 + q01 * ry * g0);
        u[1] -= 2.0 * (q01 * g1 + q11 * ry * g0);
        u[2] += g2;
        u[3] += 2.0 * ry * g1;
        u[4] += ry * ry * g0;
    }
    sums[0] = s;
    sums[1] = gw;
    for (int i = 0; i < 5; i++) {
        sums[2 + i] = v[i];
        sums[7 + i] = u[i];
    }
}

/* One photon's splat adjoint (gather_photon_simd): gradients of <G, splat> w.r.t.
 * (flux, px, py, q00, q01, q11) into g; G given padded (channels, n + 2 pad, n + 2 pad). */
static void gather_photon(const sfc_scene *sc, const double *padded, int64_t n, int64_t pad, int64_t c,
                          const double spot[6], double g[6]) {
    const double px = spot[0], py = spot[1], q00 = spot[2], q01 = spot[3], q11 = spot[4], f = spot[5];
    for (int i = 0; i < 6; i++) g[i] = 0.0;
    if (!footprint_usable(sc, f, px, py, q00, q01, q11)) return;
    int64_t x0, x1, y0, y1;
    footprint_box(px, py, q00, q01, q11, &x0, &x1, &y0, &y1);
    if (x1 < 0 || y1 < 0 || x0 > n - 1 || y0 > n - 1 || x1 < x0 || y1 < y0) return;
    const int64_t stride = n + 2 * pad;
    const double *plane = padded + c * stride * stride;
    double sums[12];
    if (fits_fixed_box(x0, x1, y0, y1, -pad, n - 1 + pad)) {
        if (sc->simd)
            sfc_gather_box8(plane, (y0 + pad) * stride + x0 + pad, stride, y1 - y0 + 1, (double)x0 - px,
                            (double)y0 - py, q00, q01, q11, sums);
        else
            gather_box(plane, stride, pad, x0, y0, LANES, LANES, px, py, q00, q01, q11, sums);
    } else {
        x0 = imax(x0, -pad); x1 = imin(x1, n - 1 + pad);
        y0 = imax(y0, -pad); y1 = imin(y1, n - 1 + pad);
        if (sc->simd && fits_spans(x0, x1, y0, y1, -pad, n - 1 + pad))
            sfc_gather_spans(plane, (y0 + pad) * stride + x0 + pad, stride, y1 - y0 + 1, x1 - x0 + 1,
                             (double)x0 - px, (double)y0 - py, q00, q01, q11, sums);
        else
            gather_box(plane, stride, pad, x0, y0, x1 - x0 + 1, y1 - y0 + 1, px, py, q00, q01, q11, sums);
    }
    if (!(sums[0] > 0.0)) return;
    const double mean = sums[1] / sums[0], scale = -2.0 * f / sums[0];
    g[0] = mean;
    for (int i = 0; i < 5; i++) g[1 + i] = scale * (sums[7 + i] - mean * sums[2 + i]);
}

/* ---------------------------------------------------------------- packets */

/* A packet's photons, one row per quantity (structure of arrays, so that the loops over the
 * packet vectorise across photons): emission, hit, jet, splat arguments. */
typedef struct {
    int64_t channel[PACKET];
    double w[3][PACKET], dwu[3][PACKET], dwv[3][PACKET];
    double flux[PACKET], eta[PACKET], t[PACKET];
    double jets[5][PACKET];   /* S_x, S_y, S_xx, S_xy, S_yy */
    double spots[6][PACKET];  /* splat arguments (px, py, q00, q01, q11, flux), then their gradients */
    double g_hit[6][PACKET];  /* gradients w.r.t. (t, jet) */
    double light[3][PACKET];  /* the light's position in every lane: the hit search's origins */
    search_state search;
} packet;

/* A packet for the scene's photons (free it), NULL where memory ran out. */
static packet *new_packet(const sfc_scene *sc) {
    packet *p = (packet *)malloc(sizeof(packet));
    if (!p) return NULL;
    for (int64_t k = 0; k < PACKET; k++) {
        p->light[0][k] = sc->light_x;
        p->light[1][k] = sc->light_y;
        p->light[2][k] = sc->light_z;
    }
    return p;
}

typedef struct {
    const double *d;
    int64_t m;
    const sfc_scene *sc;
    const double *shifts, *indices;
    double *hit_t;
    int64_t hit_len, t_first, replay;
} photons_in;

static inline SFC_INLINE vec3 row3(const double r[3][PACKET], int64_t k) { return v3(r[0][k], r[1][k], r[2][k]); }

static inline SFC_INLINE void jet_of(const packet *p, int64_t k, double jet[5]) {
    for (int j = 0; j < 5; j++) jet[j] = p->jets[j][k];
}

/* Photons first .. first+count-1 up to their hits and jets (trace_packet): emission, the hit
 * search in lockstep (or the recorded hits), the jets. */
static void trace_hits(const photons_in *in, int64_t first, int64_t count, packet *p) {
    const sfc_scene *sc = in->sc;
    for (int64_t k = 0; k < count; k++) {
        const emitted e = emit(sc, in->shifts, first + k);
        p->channel[k] = e.c;
        p->w[0][k] = e.w.x; p->w[1][k] = e.w.y; p->w[2][k] = e.w.z;
        p->dwu[0][k] = e.dwu.x; p->dwu[1][k] = e.dwu.y; p->dwu[2][k] = e.dwu.z;
        p->dwv[0][k] = e.dwv.x; p->dwv[1][k] = e.dwv.y; p->dwv[2][k] = e.dwv.z;
        p->flux[k] = e.flux;
        p->eta[k] = in->indices[e.c];
    }
    const int64_t offset = first - in->t_first;
    if (in->replay) {
        for (int64_t k = 0; k < count; k++) p->t[k] = in->hit_t[offset + k];
    } else {
        solve_hits(in->d, in->m, sc, p->light, p->w, count, p->t, &p->search);
        if (in->hit_len > 0)
            for (int64_t k = 0; k < count; k++) in->hit_t[offset + k] = p->t[k];
    }
    if (sc->simd) {
        sfc_surface_jets(in->d, in->m, -sc->half, 1.0 / sc->spacing, sc->light_x, sc->light_y, &p->w[0][0], PACKET,
                         p->t, count, &p->jets[0][0]);
    } else {
        for (int64_t k = 0; k < count; k++) {
            double jet[5];
            surface_jet_at(in->d, in->m, sc->light_x + p->t[k] * p->w[0][k], sc->light_y + p->t[k] * p->w[1][k],
                           -sc->half, sc->spacing, jet);
            for (int j = 0; j < 5; j++) p->jets[j][k] = jet[j];
        }
    }
}

/* The splat arguments of the packet's photons from their hits: one loop over the packet. */
static void packet_spots(const sfc_scene *sc, int64_t count, packet *p) {
    for (int64_t k = 0; k < count; k++) {
        optics o;
        double jet[5], spot[6];
        jet_of(p, k, jet);
        optics_state(sc, row3(p->w, k), row3(p->dwu, k), row3(p->dwv, k), p->t[k], jet, p->eta[k], &o);
        splat_arguments(sc, p->flux[k], p->eta[k], &o, spot);
        for (int j = 0; j < 6; j++) p->spots[j][k] = spot[j];
    }
}

/* The gradients w.r.t. (t, jet) of the packet's photons from those w.r.t. their splat arguments
 * (p->spots, after the gathers): the optics again and their adjoint, one loop over the packet. */
static void packet_adjoints(const sfc_scene *sc, int64_t count, packet *p) {
    for (int64_t k = 0; k < count; k++) {
        optics o;
        double jet[5], g[6], g_hit[6];
        jet_of(p, k, jet);
        const vec3 w = row3(p->w, k), dwu = row3(p->dwu, k), dwv = row3(p->dwv, k);
        optics_state(sc, w, dwu, dwv, p->t[k], jet, p->eta[k], &o);
        for (int j = 0; j < 6; j++) g[j] = p->spots[j][k];
        optics_adjoint(sc, w, dwu, dwv, p->flux[k], p->t[k], jet, p->eta[k], &o, g, g_hit);
        for (int j = 0; j < 6; j++) p->g_hit[j][k] = g_hit[j];
    }
}

/* ---------------------------------------------------------------- threads */

typedef struct {
    photons_in in;
    int64_t start, stop, blocks, threads;  /* thread t traces blocks t, t + threads, ...: a fixed share, so
                                              that each per-thread image sums the same photons in every run */
    /* render */
    void *out;
    int f32, splat;
    int64_t channels, n, capacity;
    double *reached;  /* per block */
    /* vjp */
    const double *padded;
    int64_t pad;
    double *grad;     /* (threads, m, m) */
} job;

static int render_worker(void *context, int64_t thread) {
    job *j = (job *)context;
    packet *p = new_packet(j->in.sc);
    double *buf = (double *)malloc(sizeof(double) * (size_t)imax(j->capacity, 1));
    if (!p || !buf) {
        free(p);
        free(buf);
        return 1;
    }
    const size_t elem = j->f32 ? sizeof(float) : sizeof(double);
    void *img = (char *)j->out + (size_t)thread * (size_t)(j->channels * j->n * j->n) * elem;
    for (int64_t b = thread; b < j->blocks; b += j->threads) {
        const int64_t lo = j->start + b * BLOCK, hi = imin(j->stop, lo + BLOCK);
        double reached = 0.0;
        for (int64_t first = lo; first < hi; first += PACKET) {
            const int64_t count = imin(PACKET, hi - first);
            trace_hits(&j->in, first, count, p);
            packet_spots(j->in.sc, count, p);
            for (int64_t k = 0; k < count; k++) {
                reached += p->spots[5][k];
                if (j->splat) {
                    const double spot[6] = {p->spots[0][k], p->spots[1][k], p->spots[2][k], p->spots[3][k],
                                            p->spots[4][k], p->spots[5][k]};
                    splat_photon(j->in.sc, img, j->f32, j->n, p->channel[k], spot, buf, j->capacity);
                }
            }
        }
        j->reached[b] = reached;
    }
    free(p);
    free(buf);
    return 0;
}

static int vjp_worker(void *context, int64_t thread) {
    job *j = (job *)context;
    const sfc_scene *sc = j->in.sc;
    const int64_t m = j->in.m;
    packet *p = new_packet(sc);
    char *contributes = (char *)malloc(PACKET);
    if (!p || !contributes) {
        free(p);
        free(contributes);
        return 1;
    }
    double *grad = j->grad + (size_t)thread * (size_t)(m * m);
    for (int64_t b = thread; b < j->blocks; b += j->threads) {
        const int64_t lo = j->start + b * BLOCK, hi = imin(j->stop, lo + BLOCK);
        for (int64_t first = lo; first < hi; first += PACKET) {
            const int64_t count = imin(PACKET, hi - first);
            trace_hits(&j->in, first, count, p);
            packet_spots(sc, count, p);
            for (int64_t k = 0; k < count; k++) {
                const double spot[6] = {p->spots[0][k], p->spots[1][k], p->spots[2][k], p->spots[3][k],
                                        p->spots[4][k], p->spots[5][k]};
                double g[6];
                gather_photon(sc, j->padded, j->n, j->pad, p->channel[k], spot, g);
                contributes[k] = !(g[0] == 0.0 && g[1] == 0.0 && g[2] == 0.0 && g[3] == 0.0 && g[4] == 0.0
                                   && g[5] == 0.0);
                for (int i = 0; i < 6; i++) p->spots[i][k] = g[i];
            }
            packet_adjoints(sc, count, p);
            for (int64_t k = 0; k < count; k++) {
                if (!contributes[k]) continue;
                const vec3 w = row3(p->w, k);
                const double g_hit[6] = {p->g_hit[0][k], p->g_hit[1][k], p->g_hit[2][k], p->g_hit[3][k],
                                         p->g_hit[4][k], p->g_hit[5][k]};
                const double x = sc->light_x + p->t[k] * w.x, y = sc->light_y + p->t[k] * w.y;
                hit_adjoint(sc, j->in.d, grad, m, x, y, w, g_hit);
            }
        }
    }
    free(p);
    free(contributes);
    return 0;
}

/* Render photons start .. stop-1 of heights d (m, m) into out (threads, channels, n, n) (float32
 * if f32, else float64; each thread its own image, the host sums them); with splat 0 only the
 * traces run. hit_t (hit_len = stop - start, or 0: none) receives the hits' ray parameters, or
 * with replay holds them. *reached: the flux that reached the receiver. Returns 0, -1 on
 * failure to allocate or start threads. */
int SFC_EXPORT(sfc_hf_render)(const double *d, int64_t m, const sfc_scene *sc, const double *shifts, const double *indices,
                  int64_t start, int64_t stop, void *out, int64_t f32, int64_t threads, int64_t channels, int64_t n,
                  int64_t capacity, int64_t splat, double *hit_t, int64_t hit_len, int64_t replay, double *reached) {
    job j;
    j.in.d = d; j.in.m = m; j.in.sc = sc; j.in.shifts = shifts; j.in.indices = indices;
    j.in.hit_t = hit_t; j.in.hit_len = hit_len; j.in.t_first = start; j.in.replay = replay;
    j.start = start; j.stop = stop; j.blocks = (stop - start + BLOCK - 1) / BLOCK;
    j.threads = threads < 1 ? 1 : threads;
    j.out = out; j.f32 = (int)f32; j.splat = (int)splat; j.channels = channels; j.n = n; j.capacity = capacity;
    j.padded = NULL; j.pad = 0; j.grad = NULL;
    j.reached = (double *)calloc((size_t)imax(j.blocks, 1), sizeof(double));
    if (!j.reached) return -1;
    const int status = sfc_parallel(threads, render_worker, &j);
    double total = 0.0;
    for (int64_t b = 0; b < j.blocks; b++) total += j.reached[b];
    *reached = total;
    free(j.reached);
    return status;
}

/* Add to grad (threads, m, m) the gradient w.r.t. d of <splat of photons start .. stop-1, G>, G
 * (channels, n, n) given as `padded` with `pad` zero pixels on every side; hit_t as in
 * sfc_hf_render (replayed when hit_len > 0). Returns 0, -1 on failure. */
int SFC_EXPORT(sfc_hf_vjp)(const double *d, int64_t m, const sfc_scene *sc, const double *shifts, const double *indices,
               int64_t start, int64_t stop, const double *padded, int64_t n, int64_t pad, double *grad,
               int64_t threads, double *hit_t, int64_t hit_len) {
    job j;
    j.in.d = d; j.in.m = m; j.in.sc = sc; j.in.shifts = shifts; j.in.indices = indices;
    j.in.hit_t = hit_t; j.in.hit_len = hit_len; j.in.t_first = start; j.in.replay = hit_len > 0;
    j.start = start; j.stop = stop; j.blocks = (stop - start + BLOCK - 1) / BLOCK;
    j.threads = threads < 1 ? 1 : threads;
    j.out = NULL; j.f32 = 0; j.splat = 0; j.channels = 0; j.n = n; j.capacity = 0; j.reached = NULL;
    j.padded = padded; j.pad = pad; j.grad = grad;
    return sfc_parallel(threads, vjp_worker, &j);
}

/* ---------------------------------------------------------------- rays aimed at points */

typedef struct {
    const double *d;
    int64_t m;
    const sfc_scene *sc;
    double eta;
    const double *aim;
    double *pos, *ratio, *path;
    int64_t count, blocks;
    _Atomic int64_t next_block;
} aimed_job;

/* One ray aimed at (ax, ay) on z = base, zero differentials (_trace_ray in
 * operators/wavefront/renderer.py): receiver position in pixel corner units and transmittance
 * (1, or the Fresnel product; 0 if lost) and the path's code (leaving_plane; 0 if lost). */
static void trace_aimed(const aimed_job *j, double ax, double ay, double *x, double *y, double *ratio, double *path) {
    const sfc_scene *sc = j->sc;
    const double dx = ax - sc->light_x, dy = ay - sc->light_y, dz = sc->base - sc->light_z;
    const double inv_r = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
    const vec3 w = v3(dx * inv_r, dy * inv_r, dz * inv_r);
    const double t = solve_hit(j->d, j->m, sc, v3(sc->light_x, sc->light_y, sc->light_z), w);
    double jet[5];
    surface_jet_at(j->d, j->m, sc->light_x + t * w.x, sc->light_y + t * w.y, -sc->half, sc->spacing, jet);
    optics o;
    optics_state(sc, w, ZERO, ZERO, t, jet, j->eta, &o);
    *x = (o.p3.x + sc->receiver_half) * sc->to_px;
    *y = (o.p3.y + sc->receiver_half) * sc->to_px;
    double transmittance = 1.0;
    if (sc->fresnel) transmittance = fresnel(o.ci1, o.ct1, 1.0 / j->eta) * fresnel(o.ci2, o.ct2, j->eta);
    const int good = o.lost == 0.0 && isfinite(*x) && isfinite(*y) && transmittance > 0.0;
    *ratio = good ? transmittance : 0.0;
    *path = good ? o.code : 0.0;
}

static int aimed_worker(void *context, int64_t thread) {
    (void)thread;
    aimed_job *j = (aimed_job *)context;
    for (;;) {
        const int64_t b = atomic_fetch_add(&j->next_block, 1);
        if (b >= j->blocks) break;
        for (int64_t k = b * BLOCK; k < imin(j->count, (b + 1) * BLOCK); k++)
            trace_aimed(j, j->aim[2 * k], j->aim[2 * k + 1], &j->pos[2 * k], &j->pos[2 * k + 1], &j->ratio[k],
                        &j->path[k]);
    }
    return 0;
}

/* Rays aimed at aim (count, 2) (x, y on z = base) through heights d (m, m), glass index eta:
 * receiver positions (count, 2) in pixel corner units into pos, transmittances (count,) into
 * ratio, path codes (count,) into path. Returns 0, -1 on failure to start threads. */
int SFC_EXPORT(sfc_hf_trace_aimed)(const double *d, int64_t m, const sfc_scene *sc, double eta, const double *aim, int64_t count,
                       double *pos, double *ratio, double *path, int64_t threads) {
    aimed_job j;
    j.d = d; j.m = m; j.sc = sc; j.eta = eta; j.aim = aim; j.pos = pos; j.ratio = ratio; j.path = path;
    j.count = count;
    j.blocks = (count + BLOCK - 1) / BLOCK;
    atomic_init(&j.next_block, 0);
    return sfc_parallel(threads, aimed_worker, &j);
}

/* ---------------------------------------------------------------- photons given by their splat arguments */

/* The splat and its adjoint gather for photons that another tracer computed (the mesh scenes, the
 * torch reference path): photon p at pixel (pos[p], pos[count + p]) with metric (metric[p],
 * metric[count + p], metric[2 count + p]), flux[p] and channel[p]; splat_forward and
 * splat_backward in operators/splat/native.py, whose thread shares these keep. */
enum { GATHER_BLOCK = 4096 };

typedef struct {
    sfc_scene sc; /* only simd and far_px are read */
    const double *pos, *metric, *flux;
    const int64_t *channel;
    int64_t count, threads, n;
    void *out; /* splat: (threads, channels, n, n) */
    int f32;
    int64_t channels, capacity;
    const double *padded; /* gather: G padded by pad on every side */
    int64_t pad;
    double *g_pos, *g_metric, *g_flux;
} spots_job;

static inline SFC_INLINE void spot_of(const spots_job *j, int64_t p, double spot[6]) {
    spot[0] = j->pos[p];
    spot[1] = j->pos[j->count + p];
    spot[2] = j->metric[p];
    spot[3] = j->metric[j->count + p];
    spot[4] = j->metric[2 * j->count + p];
    spot[5] = j->flux[p];
}

/* Thread t splats photons t * per .. (t + 1) * per - 1 into its own image (splat_forward). */
static int spots_splat_worker(void *context, int64_t thread) {
    const spots_job *j = (const spots_job *)context;
    double *buf = (double *)malloc(sizeof(double) * (size_t)imax(j->capacity, 1));
    if (!buf) return 1;
    const size_t elem = j->f32 ? sizeof(float) : sizeof(double);
    void *img = (char *)j->out + (size_t)thread * (size_t)(j->channels * j->n * j->n) * elem;
    const int64_t per = (j->count + j->threads - 1) / j->threads;
    for (int64_t p = thread * per; p < imin(j->count, (thread + 1) * per); p++) {
        double spot[6];
        spot_of(j, p, spot);
        splat_photon(&j->sc, img, j->f32, j->n, j->channel[p], spot, buf, j->capacity);
    }
    free(buf);
    return 0;
}

/* Thread t gathers the blocks t, t + threads, ... of GATHER_BLOCK photons (splat_backward):
 * photons with large footprints come in runs, which contiguous shares would leave to one thread. */
static int spots_gather_worker(void *context, int64_t thread) {
    const spots_job *j = (const spots_job *)context;
    const int64_t blocks = (j->count + GATHER_BLOCK - 1) / GATHER_BLOCK;
    for (int64_t b = thread; b < blocks; b += j->threads)
        for (int64_t p = b * GATHER_BLOCK; p < imin(j->count, (b + 1) * GATHER_BLOCK); p++) {
            double spot[6], g[6];
            spot_of(j, p, spot);
            gather_photon(&j->sc, j->padded, j->n, j->pad, j->channel[p], spot, g);
            j->g_flux[p] = g[0];
            j->g_pos[p] = g[1];
            j->g_pos[j->count + p] = g[2];
            j->g_metric[p] = g[3];
            j->g_metric[j->count + p] = g[4];
            j->g_metric[2 * j->count + p] = g[5];
        }
    return 0;
}

/* A job over `count` photons, its scene holding only what the splat and gather read. */
static spots_job spots(const double *pos, const double *metric, const double *flux, const int64_t *channel,
                       int64_t count, int64_t threads, int64_t n, int64_t simd, double far_px) {
    spots_job j;
    memset(&j, 0, sizeof(j));
    j.sc.simd = simd;
    j.sc.far_px = far_px;
    j.pos = pos; j.metric = metric; j.flux = flux; j.channel = channel;
    j.count = count; j.threads = threads < 1 ? 1 : threads; j.n = n;
    return j;
}

/* Splat `count` photons (float64 arguments, see spots_job) into out (threads, channels, n, n),
 * float32 if f32, each thread into its own image (the host sums them); footprints of more than
 * `capacity` pixels are left out; `simd` only where sfc_simd_supported(); photons beyond far_px
 * pixels are left out. Returns 0, -1 on failure to allocate or start threads. */
int SFC_EXPORT(sfc_splat_spots)(const double *pos, const double *metric, const double *flux, const int64_t *channel,
                                int64_t count, void *out, int64_t f32, int64_t threads, int64_t channels, int64_t n,
                                int64_t capacity, int64_t simd, double far_px) {
    spots_job j = spots(pos, metric, flux, channel, count, threads, n, simd, far_px);
    j.out = out; j.f32 = (int)f32; j.channels = channels; j.capacity = capacity;
    return sfc_parallel(j.threads, spots_splat_worker, &j);
}

/* The gradients of <G, splat> w.r.t. pos (2, count), metric (3, count) and flux (count,) of the
 * photons, float64, into g_pos, g_metric, g_flux; G (channels, n, n) given as `padded` with `pad`
 * zero pixels on every side (more than any footprint's half extent, plus SPAN_TAIL). Returns 0,
 * -1 on failure to start threads. */
int SFC_EXPORT(sfc_gather_spots)(const double *pos, const double *metric, const double *flux, const int64_t *channel,
                                 int64_t count, const double *padded, int64_t n, int64_t pad, int64_t threads,
                                 int64_t simd, double far_px, double *g_pos, double *g_metric, double *g_flux) {
    spots_job j = spots(pos, metric, flux, channel, count, threads, n, simd, far_px);
    j.padded = padded; j.pad = pad; j.g_pos = g_pos; j.g_metric = g_metric; j.g_flux = g_flux;
    return sfc_parallel(j.threads, spots_gather_worker, &j);
}
