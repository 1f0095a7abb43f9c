/* The mesh-scene operator's photon kernels in C: every photon of a chunk through all its events at
 * once (trace), the reverse of each photon's events (reverse), and the splat arguments of the
 * landed photons with their adjoint. Part of the compiled extension operators.kernels._simd
 * (setup.py): compiled at install, so the first render through lenses traces at once instead of
 * waiting minutes for numba. Built twice, for any x86-64 CPU and for AVX2 + FMA (mesh_events_avx2.c;
 * the host calls that build where the CPU has both).
 *
 * The same arithmetic, event for event, as the numba kernels, which trace one event of all
 * photons per call from a Python loop (operators/mesh/trace_native.py) and stay the fallback (no
 * C compiler at install) and the reference the tests compare these with:
 *   events ............. advance, _next_event, event_surface, interface, splat_arguments in
 *                        operators/mesh/kernels_native.py
 *   reverse ............ retreat, _retreat_one, splat_arguments_adjoint in
 *                        operators/mesh/adjoint_native.py
 *   surface, optics .... photon_optics.h (the height-field kernels' own)
 * Here a photon goes through its events on one thread without a return to Python between them;
 * the gradient logs each photon's events (kind, face or plane, distance) as it traces, and the
 * reverse replays them from the photon's start, keeping the states before each event on its
 * thread, instead of a tape of every photon's states per event.
 *
 * A photon's state is a row of STATE doubles (position, its two differentials, direction, its two
 * differentials, flux), as in kernels_native.py. Embree finds the faces: the host passes the
 * scene handle and the address of the library's rtcIntersect1 (operators/mesh/embree_native.py),
 * which every thread calls with its own ray.
 *
 * Threads: thread t takes the blocks t, t + threads, ... of BLOCK photons. The trace writes per
 * photon; the reverse sums each thread's gradient w.r.t. the heights in its own array (the host
 * sums those): the same sums in every run.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "photon_optics.h"
#include "sfc_threads.h"

/* The exported functions' names: mesh_events_avx2.c compiles this file again for AVX2 and FMA, with
 * the suffix _avx2 (the host picks that build where the CPU has both, as for the height field). */
#ifndef SFC_EXPORT
#define SFC_EXPORT(name) name
#endif

enum { STATE = 19, P = 0, DPU = 3, DPV = 6, W = 9, DWU = 12, DWV = 15, FLUX = 18, BLOCK = 4096, REFINEMENTS = 2 };
/* Event kinds, photon status and the medium of a photon in air (kernels_native.py). */
enum { MESH = 0, TOP = 1, BOX = 2, RECEIVER = 3, ESCAPED = 4, INSIDE_TOP = 5, AT_TOP = 6 };
enum { UNDER_WAY = 0, LANDED = 1, LOST = 2, WAITING = 3 };
enum { AIR = -1 };

/* Scene constants, field for field MeshSceneStruct in operators/mesh/events_compiled.py: the
 * height-field constants (half, base = the substrate's thickness, the hit search's planes and
 * slope bounds, receiver, footprint radii, Fresnel), then the mesh's own. */
typedef struct {
    sfc_scene hf;
    double top_max;           /* a plane above the print */
    double lowest;            /* the lowest z of any element */
    double start_offset;      /* intersect_reference.START_OFFSET */
    double min_face_distance; /* intersect_reference.MIN_FACE_DISTANCE */
    double clear_cos;         /* culling.CLEAR_COS */
} mesh_scene;

/* The elements' faces (NativeMeshTracer's arrays) and the Embree scene that holds them. */
typedef void (*intersect1_fn)(void *scene, void *ray_hit, void *arguments);
typedef struct {
    const int64_t *face_element; /* (F,) element of each face */
    const uint8_t *face_clear;   /* (F,) bool: no element in front (culling.py) */
    const double *v0, *plane;    /* (F, 3) first corner, unit plane normal */
    const double *dual;          /* (F, 2, 3) dual basis: barycentric b_k = dual[k] . (p - v0) */
    const double *shading;       /* (F, 3, 3) corner shading normals */
    const int64_t *neighbour;    /* (F, 3) face across the edge opposite corner k, -1 for none */
    const double *indices;       /* (K + 1, channels) refractive index of each element and the substrate */
    int64_t channels, substrate;
    void *embree;                /* RTCScene, NULL for no elements */
    intersect1_fn intersect1;
} mesh_faces;

/* A chunk of photons: state (N, STATE), medium, channel, status, counted events (N,), clear (N,)
 * bool; the flux each one lost (N, LOSS_KINDS); with a log, each photon's events (N, max_depth):
 * kind (-1 past its last), face or plane, distance, which the trace records or, with replay,
 * takes instead of searching (logged at the same heights). The reverse's start (the chunk's state,
 * medium and clear before the trace), its gradients g_state (N, STATE) and g_heights (threads, m, m). */
enum { LOST_ESCAPED = 0, LOST_INSIDE_TOP = 1, LOST_FRESNEL = 2, LOST_MAX_DEPTH = 3, LOSS_KINDS = 4 };
typedef struct {
    const double *d;
    int64_t m;
    double *state;
    int64_t *medium;
    const int64_t *channel;
    int64_t *status, *events;
    uint8_t *clear;
    double *lost;
    int8_t *log_kind;
    int32_t *log_which;
    double *log_t;
    double *g_state, *g_heights;
    int64_t n, max_depth, wait_at_top, replay, threads;
} chunk_job;

/* ---------------------------------------------------------------- small helpers */

static inline SFC_INLINE vec3 sub3(vec3 a, vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline SFC_INLINE vec3 load3(const double *a) { return v3(a[0], a[1], a[2]); }
static inline SFC_INLINE void store3(double *a, vec3 v) { a[0] = v.x; a[1] = v.y; a[2] = v.z; }
static inline SFC_INLINE double component(vec3 a, int k) { return k == 0 ? a.x : (k == 1 ? a.y : a.z); }

/* ---------------------------------------------------------------- faces */

/* Embree's first face along the ray (float32) from o along w, -1 for none (first_face). RTCRayHit
 * as 32 four-byte slots: origin 0-2, tnear 3, direction 4-6, time 7, tfar 8, mask 9, id 10, flags
 * 11; hit: normal 12-14, u 15, v 16, primID 17, geomID 18. */
typedef union { float f[32]; uint32_t u[32]; } __attribute__((aligned(16))) ray_hit;

static int64_t first_face(const mesh_faces *fa, ray_hit *r, vec3 o, vec3 w) {
    r->f[0] = (float)o.x; r->f[1] = (float)o.y; r->f[2] = (float)o.z; r->f[3] = 0.0f;
    r->f[4] = (float)w.x; r->f[5] = (float)w.y; r->f[6] = (float)w.z; r->f[7] = 0.0f;
    r->f[8] = INFINITY;
    r->u[9] = 0xFFFFFFFFu; r->u[10] = 0; r->u[11] = 0;
    r->u[18] = 0xFFFFFFFFu;
    r->u[17] = 0xFFFFFFFFu;
    fa->intersect1(fa->embree, r, NULL);
    return r->u[18] == 0xFFFFFFFFu ? -1 : (int64_t)r->u[17];
}

static inline SFC_INLINE vec3 dual_row(const mesh_faces *fa, int64_t f, int k) { return load3(fa->dual + 6 * f + 3 * k); }

/* The exact hit of the ray p + t w on face f's plane, moved across an edge (at most REFINEMENTS
 * times) where it lies outside the face (_face_hit): returns the face, t in *t (inf on a plane
 * parallel to w). */
static int64_t face_hit(const mesh_faces *fa, vec3 p, vec3 w, int64_t f, double *t_out) {
    double t = INFINITY;
    for (int i = 0; i <= REFINEMENTS; i++) {
        const vec3 n = load3(fa->plane + 3 * f);
        const double cosine = dot(w, n);
        if (fabs(cosine) <= 1e-12) {
            *t_out = INFINITY;
            return f;
        }
        const vec3 corner = load3(fa->v0 + 3 * f);
        t = dot(sub3(corner, p), n) / cosine;
        const vec3 rel = sub3(axpy(t, w, p), corner);
        const double b1 = dot(rel, dual_row(fa, f, 0)), b2 = dot(rel, dual_row(fa, f, 1));
        double lowest = 1.0 - b1 - b2;
        int k = 0;
        if (b1 < lowest) { lowest = b1; k = 1; }
        if (b2 < lowest) { lowest = b2; k = 2; }
        const int64_t across = fa->neighbour[3 * f + k];
        if (i == REFINEMENTS || !(lowest < 0.0 && across >= 0)) break;
        f = across;
    }
    *t_out = t;
    return f;
}

/* The interpolated shading normal of face f at the point q on its plane (face_shading, _shading):
 * N = raw / |raw|, raw = n0 + b1 e1 + b2 e2, e_k = n_k - n0, g_k the face's dual basis. */
typedef struct { vec3 normal; double length; vec3 e1, e2, g1, g2; } shading_frame;

static inline SFC_INLINE shading_frame face_shading(const mesh_faces *fa, vec3 q, int64_t f) {
    shading_frame s;
    const vec3 rel = sub3(q, load3(fa->v0 + 3 * f));
    s.g1 = dual_row(fa, f, 0);
    s.g2 = dual_row(fa, f, 1);
    const double b1 = dot(rel, s.g1), b2 = dot(rel, s.g2);
    const double *corners = fa->shading + 9 * f;
    const vec3 n0 = load3(corners);
    s.e1 = sub3(load3(corners + 3), n0);
    s.e2 = sub3(load3(corners + 6), n0);
    const vec3 raw = axpy(b1, s.e1, axpy(b2, s.e2, n0));
    s.length = sqrt(dot(raw, raw));
    s.normal = scale3(1.0 / s.length, raw);
    return s;
}

/* D N = (I - N N^T) (e1 g1^T + e2 g2^T) D p / |raw| (shading_differential). */
static inline SFC_INLINE vec3 shading_differential(const shading_frame *s, vec3 dp) {
    const vec3 m = axpy(dot(s->g1, dp), s->e1, scale3(dot(s->g2, dp), s->e2));
    return scale3(1.0 / s->length, axpy(-dot(s->normal, m), s->normal, m));
}

/* Adjoint of shading_differential: returns g_normal; *g_length, *g_dp. */
static inline SFC_INLINE vec3 shading_differential_adjoint(const shading_frame *s, vec3 dp, vec3 dn, vec3 g_dn,
                                                           double *g_length, vec3 *g_dp) {
    const vec3 m = axpy(dot(s->g1, dp), s->e1, scale3(dot(s->g2, dp), s->e2));
    const double sm = dot(s->normal, m), ng = dot(s->normal, g_dn);
    const vec3 g_m = scale3(1.0 / s->length, axpy(-ng, s->normal, g_dn));
    *g_length = -dot(dn, g_dn) / s->length;
    *g_dp = axpy(dot(s->e1, g_m), s->g1, scale3(dot(s->e2, g_m), s->g2));
    return scale3(-1.0 / s->length, axpy(sm, g_dn, scale3(ng, m)));
}

/* Mirror reflection r = w - 2 (w . n) n with its differentials (reflect). */
static inline SFC_INLINE void reflect(vec3 w, vec3 dwu, vec3 dwv, vec3 n, vec3 dnu, vec3 dnv, vec3 *r, vec3 *ru, vec3 *rv) {
    const double c = dot(w, n), cu = dot(dwu, n) + dot(w, dnu), cv = dot(dwv, n) + dot(w, dnv);
    *r = axpy(-2.0 * c, n, w);
    *ru = axpy(-2.0 * cu, n, axpy(-2.0 * c, dnu, dwu));
    *rv = axpy(-2.0 * cv, n, axpy(-2.0 * c, dnv, dwv));
}

typedef struct { vec3 g_w, g_dwu, g_dwv, g_n, g_dnu, g_dnv; } reflect_grads;

static inline SFC_INLINE reflect_grads reflect_adjoint(vec3 w, vec3 dwu, vec3 dwv, vec3 n, vec3 dnu, vec3 dnv, vec3 g_r,
                                                       vec3 g_ru, vec3 g_rv) {
    reflect_grads a;
    const double c = dot(w, n), cu = dot(dwu, n) + dot(w, dnu), cv = dot(dwv, n) + dot(w, dnv);
    const double g_cu = -2.0 * dot(g_ru, n), g_cv = -2.0 * dot(g_rv, n);
    const double g_c = -2.0 * (dot(g_r, n) + dot(g_ru, dnu) + dot(g_rv, dnv));
    a.g_w = axpy(g_c, n, axpy(g_cu, dnu, axpy(g_cv, dnv, g_r)));
    a.g_n = axpy(-2.0 * c, g_r, axpy(-2.0 * cu, g_ru, axpy(-2.0 * cv, g_rv, axpy(g_c, w, axpy(g_cu, dwu, scale3(g_cv, dwv))))));
    a.g_dwu = axpy(g_cu, n, g_ru);
    a.g_dwv = axpy(g_cv, n, g_rv);
    a.g_dnu = axpy(g_cu, w, scale3(-2.0 * c, g_ru));
    a.g_dnv = axpy(g_cv, w, scale3(-2.0 * c, g_rv));
    return a;
}

/* ---------------------------------------------------------------- the substrate */

/* The substrate's walls and bottom: plane k at coordinate sign * half of its axis (walls) or z = 0
 * (bottom), with its outward sign (BOX_PLANES). */
static const int BOX_AXIS[5] = {0, 0, 1, 1, 2};
static const double BOX_SIGN[5] = {1.0, -1.0, 1.0, -1.0, 0.0};
static const double BOX_OUTWARD[5] = {1.0, -1.0, 1.0, -1.0, -1.0};

/* The nearest wall or bottom the ray meets, leaving from inside or entering from air (_box):
 * returns t (inf for none), plane in *which (-1 for none). */
static double box_hit(const mesh_scene *ms, vec3 p, vec3 w, int64_t medium, int64_t substrate, int64_t *which) {
    double best = INFINITY;
    *which = -1;
    for (int k = 0; k < 5; k++) {
        const int axis = BOX_AXIS[k];
        const double wa = component(w, axis), outward = BOX_OUTWARD[k];
        if (fabs(wa) <= 1e-12) continue;
        if (!((medium == substrate && wa * outward > 0.0) || (medium == AIR && wa * outward < 0.0))) continue;
        const double t = (BOX_SIGN[k] * ms->hf.half - component(p, axis)) / wa;
        if (!(t > 1e-9 && t < best)) continue;
        int inside = 1;
        for (int j = 0; j < 3; j++) {
            if (j == axis) continue;
            const double c = component(p, j) + t * component(w, j);
            inside &= j == 2 ? (0.0 <= c && c <= ms->hf.base) : fabs(c) <= ms->hf.half;
        }
        if (inside) {
            best = t;
            *which = k;
        }
    }
    return best;
}

static inline SFC_INLINE vec3 box_normal(int64_t k) {
    const int axis = BOX_AXIS[k];
    const double o = BOX_OUTWARD[k];
    return v3(axis == 0 ? o : 0.0, axis == 1 ? o : 0.0, axis == 2 ? o : 0.0);
}

/* Whether a ray in air comes down onto the printed square from above the print (_over_print). */
static inline SFC_INLINE int over_print(const mesh_scene *ms, vec3 p, vec3 w) {
    if (!(w.z < 0.0 && p.z > ms->top_max)) return 0;
    const double s = (ms->hf.base - p.z) / w.z;
    return fabs(p.x + s * w.x) <= ms->hf.half && fabs(p.y + s * w.y) <= ms->hf.half;
}

/* ---------------------------------------------------------------- events */

/* One photon on its way: its state row (STATE), medium, whether it left a clear face, status,
 * wavelength channel. */
typedef struct {
    double *row;
    int64_t medium, status, channel;
    int clear;
} photon;


/* The photon's next event (_next_event): kind, face or box plane in *which, distance in *t. */
static int64_t next_event(const mesh_scene *ms, const mesh_faces *fa, const double *d, int64_t m, const photon *ph,
                          int released, int wait_at_top, ray_hit *ray, int64_t *which, double *t_out) {
    const double *row = ph->row;
    const vec3 p = load3(row + P), w = load3(row + W);
    const int64_t medium = ph->medium;
    const int in_air = medium == AIR, in_sub = medium == fa->substrate;
    const double thickness = ms->hf.base;
    double best = INFINITY;
    int64_t kind = ESCAPED;
    *which = -1;
    const int over = in_air && over_print(ms, p, w);
    double t_top = INFINITY;
    if (over && !wait_at_top) t_top = solve_hit(d, m, &ms->hf, p, w);
    const int skip = ph->clear || (in_air && w.z < 0.0 && p.z < ms->lowest)
                     || (released && t_top < (thickness - p.z) / w.z);
    int64_t face = -1;
    if (fa->embree != NULL && !in_sub && !skip)
        face = first_face(fa, ray, axpy(ms->start_offset, w, p), w);
    if (face >= 0) {
        double t;
        const int64_t f = face_hit(fa, p, w, face, &t);
        if (t > ms->min_face_distance && t < best) {
            best = t;
            kind = MESH;
            *which = f;
        }
    }
    if (over) {
        /* Nothing lies between the print and a ray above it, so while waiting the top comes next
         * unless a face comes before z = thickness. */
        if (wait_at_top && !(best < (thickness - p.z) / w.z)) {
            *which = -1;
            *t_out = 0.0;
            return AT_TOP;
        }
        if (t_top < best) {
            best = t_top;
            kind = TOP;
            *which = -1;
        }
    }
    int64_t plane;
    double t = box_hit(ms, p, w, medium, fa->substrate, &plane);
    if (t < best) {
        best = t;
        kind = BOX;
        *which = plane;
    }
    if (in_air && w.z < 0.0) {
        t = (ms->hf.receiver_z - p.z) / w.z;
        if (t < best) {
            best = t;
            kind = RECEIVER;
            *which = -1;
        }
    }
    if (in_sub && w.z > 0.0) {
        t = (thickness - p.z) / dmax(w.z, 1e-12);
        if (t < best) {
            best = t;
            kind = INSIDE_TOP;
            *which = -1;
        }
    }
    *t_out = best;
    return kind;
}

/* The surface of an event at distance t and the photon moved onto it (event_surface). */
typedef struct {
    vec3 n_plane, outward, dnu, dnv;
    double jet[5];
    vec3 q, dqu, dqv;
} event_surface;

static void surface_of(const mesh_scene *ms, const mesh_faces *fa, const double *d, int64_t m, const double *row,
                       int64_t kind, int64_t which, double t, event_surface *s) {
    const vec3 p = load3(row + P), dpu = load3(row + DPU), dpv = load3(row + DPV);
    const vec3 w = load3(row + W), dwu = load3(row + DWU), dwv = load3(row + DWV);
    for (int j = 0; j < 5; j++) s->jet[j] = 0.0;
    if (kind == MESH) {
        s->n_plane = load3(fa->plane + 3 * which);
    } else if (kind == TOP) {
        surface_jet_at(d, m, p.x + t * w.x, p.y + t * w.y, -ms->hf.half, ms->hf.spacing, s->jet);
        s->n_plane = height_field_normal(s->jet[0], s->jet[1]);
    } else if (kind == BOX) {
        s->n_plane = box_normal(which);
    } else {
        s->n_plane = UP;
    }
    transfer(&ms->hf, p, dpu, dpv, w, dwu, dwv, t, s->n_plane, &s->q, &s->dqu, &s->dqv);
    s->outward = s->n_plane;
    s->dnu = ZERO;
    s->dnv = ZERO;
    if (kind == MESH) {
        const shading_frame frame = face_shading(fa, s->q, which);
        s->outward = frame.normal;
        s->dnu = shading_differential(&frame, s->dqu);
        s->dnv = shading_differential(&frame, s->dqv);
    } else if (kind == TOP) {
        s->dnu = normal_differential(s->jet[2], s->jet[3], s->jet[4], s->n_plane, s->dqu);
        s->dnv = normal_differential(s->jet[2], s->jet[3], s->jet[4], s->n_plane, s->dqv);
    }
}

/* Which side the photon comes from and how it leaves (interface): refracted, or reflected under
 * total internal reflection (through = 0). */
typedef struct {
    int entering, through;
    double sign, eta, ci, ct;
    vec3 r, ru, rv;
} crossing;

static inline SFC_INLINE crossing interface(vec3 w, vec3 dwu, vec3 dwv, const event_surface *s, double n_solid) {
    crossing x;
    x.entering = dot(w, s->n_plane) < 0.0;
    x.sign = x.entering ? 1.0 : -1.0;
    x.eta = x.entering ? 1.0 / n_solid : n_solid;
    const vec3 facing = scale3(x.sign, s->outward), dfu = scale3(x.sign, s->dnu), dfv = scale3(x.sign, s->dnv);
    const double k = refract(w, dwu, dwv, facing, dfu, dfv, x.eta, &x.r, &x.ru, &x.rv, &x.ci, &x.ct);
    if (k <= 0.0) reflect(w, dwu, dwv, facing, dfu, dfv, &x.r, &x.ru, &x.rv);
    x.through = k > 0.0;
    return x;
}

/* What an event computed: the surface met and how the photon crossed it (the reverse's inputs). */
typedef struct {
    event_surface s;
    crossing x;
} event_record;

/* Apply an event (kind, face or plane, distance) to the photon (_advance_one after the search):
 * moves it onto the surface, refracts or reflects it, ends it; Fresnel losses into *lost_fresnel;
 * the surface and the crossing into *record where it is not NULL. */
static void apply_event(const mesh_scene *ms, const mesh_faces *fa, const double *d, int64_t m, photon *ph,
                        int64_t kind, int64_t which, double t, double *lost_fresnel, event_record *record) {
    double *row = ph->row;
    ph->clear = 0;
    if (kind == AT_TOP) {
        ph->status = WAITING;
        return;
    }
    if (kind == ESCAPED || kind == INSIDE_TOP) {
        ph->status = LOST;
        return;
    }
    event_record local;
    event_record *r = record != NULL ? record : &local;
    const event_surface *sp = &r->s;
    surface_of(ms, fa, d, m, row, kind, which, t, &r->s);
    store3(row + P, sp->q);
    store3(row + DPU, sp->dqu);
    store3(row + DPV, sp->dqv);
    if (kind == RECEIVER) {
        ph->status = LANDED;
        return;
    }
    const int64_t solid = kind == MESH ? fa->face_element[which] : fa->substrate;
    r->x = interface(load3(row + W), load3(row + DWU), load3(row + DWV), sp,
                     fa->indices[solid * fa->channels + ph->channel]);
    const crossing x = r->x;
    store3(row + W, x.r);
    store3(row + DWU, x.ru);
    store3(row + DWV, x.rv);
    if (x.through) {
        if (ms->hf.fresnel) {
            const double kept = fresnel(x.ci, x.ct, x.eta);
            *lost_fresnel += row[FLUX] * (1.0 - kept);
            row[FLUX] *= kept;
        }
        ph->medium = x.entering ? solid : AIR;
        ph->clear = kind == MESH && !x.entering && fa->face_clear[which] && dot(x.r, sp->n_plane) >= ms->clear_cos;
    }
}

typedef struct {
    const mesh_scene *ms;
    const mesh_faces *fa;
    const chunk_job *c;
    int64_t blocks;
} worker_job;

/* Photon i of the chunk through its events (advance, _run in operators/mesh/trace_native.py): at
 * most max_depth of them, until it lands, is lost, waits at the top (wait_at_top) or has had
 * max_depth counted events in all; its losses into its row of c->lost, its events into the log
 * (or, with replay, from it). */
static void trace_photon(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c, int64_t i, ray_hit *ray) {
    photon ph = {c->state + STATE * i, c->medium[i], c->status[i], c->channel[i], c->clear[i]};
    double *lost = c->lost + LOSS_KINDS * i;
    int64_t e = 0;
    for (; e < c->max_depth && ph.status == UNDER_WAY; e++) {
        int64_t kind, which;
        double t;
        if (c->replay) {
            kind = c->log_kind[c->max_depth * i + e];
            which = c->log_which[c->max_depth * i + e];
            t = c->log_t[c->max_depth * i + e];
        } else {
            kind = next_event(ms, fa, c->d, c->m, &ph, e == 0 && !c->wait_at_top, (int)c->wait_at_top, ray, &which, &t);
        }
        const double flux = ph.row[FLUX];
        apply_event(ms, fa, c->d, c->m, &ph, kind, which, t, &lost[LOST_FRESNEL], NULL);
        if (c->log_kind != NULL && !c->replay) {
            c->log_kind[c->max_depth * i + e] = (int8_t)kind;
            c->log_which[c->max_depth * i + e] = (int32_t)which;
            c->log_t[c->max_depth * i + e] = t;
        }
        if (kind != AT_TOP) c->events[i]++;
        if (kind == ESCAPED) lost[LOST_ESCAPED] += flux;
        if (kind == INSIDE_TOP) lost[LOST_INSIDE_TOP] += flux;
        if (ph.status == UNDER_WAY && c->events[i] >= c->max_depth) {
            lost[LOST_MAX_DEPTH] += ph.row[FLUX];
            ph.status = LOST;
        }
    }
    if (c->log_kind != NULL && !c->replay)
        for (; e < c->max_depth; e++) c->log_kind[c->max_depth * i + e] = -1;
    c->medium[i] = ph.medium;
    c->status[i] = ph.status;
    c->clear[i] = (uint8_t)ph.clear;
}

static int trace_worker(void *context, int64_t thread) {
    const worker_job *j = (const worker_job *)context;
    const chunk_job *c = j->c;
    ray_hit ray;
    for (int64_t b = thread; b < j->blocks; b += c->threads)
        for (int64_t i = b * BLOCK; i < imin(c->n, (b + 1) * BLOCK); i++) trace_photon(j->ms, j->fa, c, i, &ray);
    return 0;
}

/* ---------------------------------------------------------------- reverse */

/* The gradient w.r.t. the heights (m, m) of g_t t + <g_jet, jet> at a hit on the top of the ray
 * from p along w (_top_adjoint). */
static inline SFC_INLINE void top_adjoint(const mesh_scene *ms, const double *d, int64_t m, double *grad, vec3 p, vec3 w,
                                          double t, const double g[6]) {
    hit_adjoint_scalar(d, grad, m, p.x + t * w.x, p.y + t * w.y, -ms->hf.half, ms->hf.spacing, w, g);
}

/* Reverse of one event (kind k, face or plane, distance t) of a photon whose state before it was
 * `row` and which met the surface and crossed it as `record` says (apply_event's, _retreat_one):
 * g (STATE) from the gradient w.r.t. the state after the event to that before it; at the top into
 * grad (m, m) instead (g zeroed). */
static void retreat_one(const mesh_scene *ms, const mesh_faces *fa, const double *d, int64_t m, const double *row,
                        int64_t k, int64_t which, double t, const event_record *record, double *g, double *grad) {
    const vec3 p = load3(row + P), dpu = load3(row + DPU), dpv = load3(row + DPV);
    const vec3 w = load3(row + W), dwu = load3(row + DWU), dwv = load3(row + DWV);
    const event_surface s = record->s;
    vec3 g_q = load3(g + P), g_dqu = load3(g + DPU), g_dqv = load3(g + DPV);
    vec3 g_w = ZERO, g_dwu = ZERO, g_dwv = ZERO;
    double g_flux = g[FLUX];
    if (k != RECEIVER) {
        const crossing x = record->x;
        const vec3 facing = scale3(x.sign, s.outward), dfu = scale3(x.sign, s.dnu), dfv = scale3(x.sign, s.dnv);
        const vec3 g_r = load3(g + W), g_ru = load3(g + DWU), g_rv = load3(g + DWV);
        vec3 g_f, g_fu, g_fv;
        if (x.through) {
            double g_ci = 0.0, g_ct = 0.0;
            if (ms->hf.fresnel) {
                const double kept = fresnel(x.ci, x.ct, x.eta);
                fresnel_adjoint(x.ci, x.ct, x.eta, g[FLUX] * row[FLUX], &g_ci, &g_ct);
                g_flux = g[FLUX] * kept;
            }
            const refract_grads a = refract_adjoint(w, dwu, dwv, facing, dfu, dfv, x.eta, g_r, g_ru, g_rv, g_ci, g_ct);
            g_w = a.g_w; g_dwu = a.g_dwu; g_dwv = a.g_dwv; g_f = a.g_n; g_fu = a.g_dnu; g_fv = a.g_dnv;
        } else {
            const reflect_grads a = reflect_adjoint(w, dwu, dwv, facing, dfu, dfv, g_r, g_ru, g_rv);
            g_w = a.g_w; g_dwu = a.g_dwu; g_dwv = a.g_dwv; g_f = a.g_n; g_fu = a.g_dnu; g_fv = a.g_dnv;
        }
        const vec3 g_out = scale3(x.sign, g_f), g_dnu = scale3(x.sign, g_fu), g_dnv = scale3(x.sign, g_fv);
        if (k == MESH) {
            const shading_frame frame = face_shading(fa, s.q, which);
            double gl_u, gl_v;
            vec3 gp_u, gp_v;
            const vec3 gn_u = shading_differential_adjoint(&frame, s.dqu, s.dnu, g_dnu, &gl_u, &gp_u);
            const vec3 gn_v = shading_differential_adjoint(&frame, s.dqv, s.dnv, g_dnv, &gl_v, &gp_v);
            g_dqu = add3(g_dqu, gp_u);
            g_dqv = add3(g_dqv, gp_v);
            const vec3 g_normal = add3(g_out, add3(gn_u, gn_v));
            /* N = raw / |raw|, raw = n0 + b1 e1 + b2 e2, b_k = g_k . (q - v0). */
            const vec3 g_raw = axpy(gl_u + gl_v - dot(frame.normal, g_normal) / frame.length, frame.normal,
                                    scale3(1.0 / frame.length, g_normal));
            g_q = axpy(dot(frame.e1, g_raw), frame.g1, axpy(dot(frame.e2, g_raw), frame.g2, g_q));
        } else if (k == TOP) {
            double g_sxx = 0.0, g_sxy = 0.0, g_syy = 0.0;
            vec3 g_nu, g_dpu_n, g_nv, g_dpv_n;
            normal_differential_adjoint(s.jet[2], s.jet[3], s.jet[4], s.n_plane, s.dqu, g_dnu, &g_sxx, &g_sxy,
                                        &g_syy, &g_nu, &g_dpu_n);
            normal_differential_adjoint(s.jet[2], s.jet[3], s.jet[4], s.n_plane, s.dqv, g_dnv, &g_sxx, &g_sxy,
                                        &g_syy, &g_nv, &g_dpv_n);
            g_dqu = add3(g_dqu, g_dpu_n);
            g_dqv = add3(g_dqv, g_dpv_n);
            const vec3 g_n_plane = add3(g_out, add3(g_nu, g_nv));
            const transfer_grads a = transfer_adjoint(&ms->hf, dpu, dpv, w, dwu, dwv, t, s.n_plane, g_q, g_dqu, g_dqv);
            double hit[6];
            hit[0] = a.g_dist;
            height_field_normal_adjoint(s.jet[0], s.jet[1], add3(g_n_plane, a.g_n), &hit[1], &hit[2]);
            hit[3] = g_sxx;
            hit[4] = g_sxy;
            hit[5] = g_syy;
            top_adjoint(ms, d, m, grad, p, w, t, hit);
            for (int j = 0; j < STATE; j++) g[j] = 0.0;
            return;
        }
    }
    const transfer_grads a = transfer_adjoint(&ms->hf, dpu, dpv, w, dwu, dwv, t, s.n_plane, g_q, g_dqu, g_dqv);
    /* The distance to a fixed plane: t = (c - p . n) / (w . n). */
    const double wn = dot(w, s.n_plane);
    store3(g + P, axpy(-a.g_dist / wn, s.n_plane, g_q));
    store3(g + DPU, a.g_dpu);
    store3(g + DPV, a.g_dpv);
    store3(g + W, add3(add3(g_w, a.g_w), scale3(-a.g_dist * t / wn, s.n_plane)));
    store3(g + DWU, add3(g_dwu, a.g_dwu));
    store3(g + DWV, add3(g_dwv, a.g_dwv));
    g[FLUX] = g_flux;
}

/* The reverse of photon i's logged events (retreat over the events of _run, in
 * operators/mesh/trace_native.py): its events replayed from its start (the state before the trace
 * in c->state, its medium and clear), the state before each kept in `before` (max_depth, STATE)
 * and the surface and crossing each computed in `records` (max_depth), then the gradient
 * g_state[i] taken back through them, into grad (m, m) at the top. */
static void reverse_photon(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c, int64_t i, double *before,
                           event_record *records, double *grad) {
    double row[STATE];
    memcpy(row, c->state + STATE * i, sizeof(row));
    photon ph = {row, c->medium[i], UNDER_WAY, c->channel[i], c->clear[i]};
    const int8_t *kind = c->log_kind + c->max_depth * i;
    const int32_t *which = c->log_which + c->max_depth * i;
    const double *t = c->log_t + c->max_depth * i;
    double unused = 0.0;
    int64_t count = 0;
    for (; count < c->max_depth && kind[count] >= 0; count++) {
        memcpy(before + STATE * count, row, sizeof(row));
        apply_event(ms, fa, c->d, c->m, &ph, kind[count], which[count], t[count], &unused, records + count);
    }
    double *g = c->g_state + STATE * i;
    for (int64_t e = count - 1; e >= 0; e--) {
        if (kind[e] == ESCAPED || kind[e] == INSIDE_TOP || kind[e] == AT_TOP) continue;
        retreat_one(ms, fa, c->d, c->m, before + STATE * e, kind[e], which[e], t[e], records + e, g, grad);
    }
}

static int reverse_worker(void *context, int64_t thread) {
    const worker_job *j = (const worker_job *)context;
    const chunk_job *c = j->c;
    double *before = (double *)malloc(sizeof(double) * STATE * (size_t)imax(c->max_depth, 1));
    event_record *records = (event_record *)malloc(sizeof(event_record) * (size_t)imax(c->max_depth, 1));
    if (!before || !records) {
        free(before);
        free(records);
        return 1;
    }
    double *grad = c->g_heights + thread * c->m * c->m;
    for (int64_t b = thread; b < j->blocks; b += c->threads)
        for (int64_t i = b * BLOCK; i < imin(c->n, (b + 1) * BLOCK); i++)
            if (c->status[i] == LANDED) reverse_photon(j->ms, j->fa, c, i, before, records, grad);
    free(before);
    free(records);
    return 0;
}

/* ---------------------------------------------------------------- exported */

/* Trace every photon of the chunk under way through its events, on c->threads threads, in place
 * (see trace_photon). Returns 0, -1 when a thread could not start. */
int SFC_EXPORT(sfc_mesh_trace)(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c) {
    worker_job j = {ms, fa, c, (c->n + BLOCK - 1) / BLOCK};
    return sfc_parallel(c->threads, trace_worker, &j);
}

/* The gradient w.r.t. the heights, into c->g_heights (threads, m, m), of the photons' final
 * states' gradient c->g_state (N, STATE; overwritten): c->state, medium and clear hold the chunk
 * as it was before sfc_mesh_trace logged its events, c->status the status after it (only landed
 * photons carry a gradient). Returns 0, -1 on failure to allocate or start threads. */
int SFC_EXPORT(sfc_mesh_reverse)(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c) {
    worker_job j = {ms, fa, c, (c->n + BLOCK - 1) / BLOCK};
    return sfc_parallel(c->threads, reverse_worker, &j);
}

typedef struct {
    const mesh_scene *ms;
    const double *state;
    const int64_t *status, *where;
    int64_t n, threads;
    double *pos, *metric, *flux, *missed;
} splat_job;

/* Thread t's share of sfc_mesh_splat_arguments: photons t * per .. (t + 1) * per - 1. */
static int splat_arguments_worker(void *context, int64_t thread) {
    const splat_job *j = (const splat_job *)context;
    const sfc_scene *sc = &j->ms->hf;
    const double k = sc->to_px;
    const int64_t n = j->n, per = (n + j->threads - 1) / j->threads;
    double missed = 0.0;
    for (int64_t i = thread * per; i < imin(n, (thread + 1) * per); i++) {
        const int64_t c = j->where[i];
        double *pos = j->pos, *metric = j->metric;
        if (j->status[i] != LANDED) {
            pos[c] = pos[n + c] = 0.0;
            metric[c] = 1.0;
            metric[n + c] = 0.0;
            metric[2 * n + c] = 1.0;
            j->flux[c] = 0.0;
            continue;
        }
        const double *row = j->state + STATE * i;
        if (fabs(row[P]) > sc->receiver_half || fabs(row[P + 1]) > sc->receiver_half) missed += row[FLUX];
        pos[c] = (row[P] + sc->receiver_half) * k - 0.5;
        pos[n + c] = (row[P + 1] + sc->receiver_half) * k - 0.5;
        double q[3];
        footprint_metric(sc, row[DPU] * k, row[DPU + 1] * k, row[DPV] * k, row[DPV + 1] * k, q);
        metric[c] = q[0];
        metric[n + c] = q[1];
        metric[2 * n + c] = q[2];
        j->flux[c] = row[FLUX];
    }
    j->missed[thread] = missed;
    return 0;
}

/* Pixel positions (2, N), footprint metrics (3, N) and flux (N,) of the landed photons, photon i's
 * at column where[i]; flux 0 and a unit metric for the others (splat_arguments), on `threads`
 * threads (thread t: a contiguous share). The flux (W) of the landed photons beside the receiver
 * into *missed (summed per thread, then in thread order). Returns 0, -1 on failure to allocate or
 * start threads. */
int SFC_EXPORT(sfc_mesh_splat_arguments)(const mesh_scene *ms, const double *state, const int64_t *status,
                                         const int64_t *where, int64_t n, int64_t threads, double *pos,
                                         double *metric, double *flux, double *missed) {
    if (threads < 1) threads = 1;
    double *shares = (double *)calloc((size_t)threads, sizeof(double));
    if (!shares) return -1;
    splat_job j = {ms, state, status, where, n, threads, pos, metric, flux, shares};
    const int result = sfc_parallel(threads, splat_arguments_worker, &j);
    *missed = 0.0;
    for (int64_t t = 0; t < threads; t++) *missed += shares[t];
    free(shares);
    return result;
}

typedef struct {
    const mesh_scene *ms;
    const double *state;
    const int64_t *status;
    int64_t n, threads;
    const double *g_pos, *g_metric, *g_flux;
    double *g_state;
} splat_adjoint_job;

/* Thread t's share of sfc_mesh_splat_arguments_adjoint: photons t * per .. (t + 1) * per - 1. */
static int splat_adjoint_worker(void *context, int64_t thread) {
    const splat_adjoint_job *j = (const splat_adjoint_job *)context;
    const sfc_scene *sc = &j->ms->hf;
    const double k = sc->to_px;
    const int64_t n = j->n, per = (n + j->threads - 1) / j->threads;
    for (int64_t i = thread * per; i < imin(n, (thread + 1) * per); i++) {
        double *g = j->g_state + STATE * i;
        for (int c = 0; c < STATE; c++) g[c] = 0.0;
        if (j->status[i] != LANDED) continue;
        const double *row = j->state + STATE * i;
        double gf[4];
        footprint_metric_adjoint(sc, row[DPU] * k, row[DPU + 1] * k, row[DPV] * k, row[DPV + 1] * k, j->g_metric[i],
                                 j->g_metric[n + i], j->g_metric[2 * n + i], gf);
        g[P] = j->g_pos[i] * k;
        g[P + 1] = j->g_pos[n + i] * k;
        g[DPU] = gf[0] * k;
        g[DPU + 1] = gf[1] * k;
        g[DPV] = gf[2] * k;
        g[DPV + 1] = gf[3] * k;
        g[FLUX] = j->g_flux[i];
    }
    return 0;
}

/* The gradient w.r.t. the photons' states (N, STATE) from those w.r.t. their splat arguments,
 * photon i's at column i (splat_arguments_adjoint), on `threads` threads (thread t: a contiguous
 * share; every photon's row is its own, so the result does not depend on the threads). Returns 0,
 * -1 on failure to start threads. */
int SFC_EXPORT(sfc_mesh_splat_arguments_adjoint)(const mesh_scene *ms, const double *state, const int64_t *status,
                                                 int64_t n, int64_t threads, const double *g_pos,
                                                 const double *g_metric, const double *g_flux, double *g_state) {
    splat_adjoint_job j = {ms, state, status, n, threads < 1 ? 1 : threads, g_pos, g_metric, g_flux, g_state};
    return sfc_parallel(j.threads, splat_adjoint_worker, &j);
}
