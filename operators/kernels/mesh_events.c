/* The mesh-scene operator's photon kernels in C: every photon of a chunk through all its events at
 * once, ending in the splat arguments of the landed photons (trace), and the reverse of both, from
 * the gradient w.r.t. the splat arguments to the heights (reverse). Part of the compiled extension
 * operators.kernels._simd (setup.py): compiled at install, so the first render through lenses
 * traces at once instead of waiting minutes for numba. Built twice, for any x86-64 CPU and for
 * AVX2 + FMA (mesh_events_avx2.c; the host calls that build where the CPU has both).
 *
 * The same arithmetic, event for event, as the numba kernels, which trace one event of all
 * photons per call from a Python loop (operators/mesh/trace_native.py) and stay the fallback (no
 * C compiler at install) and the reference the tests compare these with:
 *   events ............. advance, _next_event, event_surface, interface, splat_arguments in
 *                        operators/mesh/kernels_native.py
 *   reverse ............ retreat, _retreat_one, splat_arguments_adjoint in
 *                        operators/mesh/adjoint_native.py
 *   surface, optics .... photon_optics.h (the height-field kernels' own)
 * Here the photons go through all their events on one thread without a return to Python, in
 * packets of PACKET photons that take their events in step (see "packets" below): the print's hit
 * search for the packet's photons over it in lockstep (solve_hits, as in the height-field
 * kernels), Embree's faces for the packet's rays eight at a time, the rest of the search for each
 * photon's next event one photon at a time, the lookup of the surfaces for the packet, the
 * arithmetic of the event (transfer, shading normal, refraction or reflection, Fresnel) in two
 * branch-free loops over the packet and that of its reverse in one, which GCC vectorises across
 * photons (compiled once per kind of surface: faces, the print, the walls and bottom, the
 * receiver, a mix). The print's jets and hit adjoint come from the AVX2 kernels of simd_kernels.c
 * where the scene's `simd` is set (as in the height-field kernels; the scalar ones of
 * photon_optics.h elsewhere). The gradient logs each photon's events (kind, face or plane,
 * distance) as it traces, and the reverse replays them from the photons' start, keeping the states
 * before each event and what each computed for the packet on its thread, instead of a tape of
 * every photon's states per event.
 *
 * A photon's state is a row of STATE doubles (position, its two differentials, direction, its two
 * differentials, flux), as in kernels_native.py. Embree finds the faces: the host passes the
 * scene handle and the address of the library's rtcIntersect8 (operators/mesh/embree_native.py),
 * which every thread calls with the rays of its packet's photons that search the faces, eight at
 * a time.
 *
 * Threads: thread t takes the blocks t, t + threads, ... of BLOCK photons, and packets of a block's
 * photons in order. The trace writes per photon; the reverse sums each thread's gradient w.r.t.
 * the heights in its own array (the host sums those), a packet's event by event: the same sums in
 * every run.
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
typedef void (*intersect8_fn)(const int *valid, void *scene, void *ray_hits, void *arguments);
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
    intersect8_fn intersect8;    /* rtcIntersect8 */
} mesh_faces;

/* A chunk of photons: state (N, STATE), medium, channel, status, counted events (N,), clear (N,)
 * bool; the flux lost in each block of BLOCK photons per kind (LOSS_KINDS, blocks; LOST_MISSED:
 * landed beside the receiver); with a log, the photons' events (max_depth, N: event e of photon i
 * at e N + i, so that a packet's photons' event is contiguous): kind (-1 past its last), face or
 * plane, distance, which the trace records or, with replay, takes instead of searching (logged at
 * the same heights). The trace's output for the splat: each photon's pixel position (2, N),
 * footprint metric (3, N) and flux (N,) (flux 0 and a unit metric unless it landed). The
 * reverse's start (the chunk's state, medium and clear before the trace), the gradient w.r.t. the
 * splat arguments g_pos (2, N), g_metric (3, N), g_flux (N,) and its output g_heights (threads,
 * m, m). */
enum { LOST_ESCAPED = 0, LOST_INSIDE_TOP = 1, LOST_FRESNEL = 2, LOST_MAX_DEPTH = 3, LOST_MISSED = 4, LOSS_KINDS = 5 };
typedef struct {
    const double *d;
    int64_t m;
    double *state;       /* the trace's photons as they end (N, STATE); NULL with start: not kept */
    const double *start; /* the trace's photons as they start (N, STATE), NULL: state itself */
    int64_t *medium;
    const int64_t *channel;
    int64_t *status, *events;
    uint8_t *clear;
    double *lost;
    int8_t *log_kind;
    int32_t *log_which;
    double *log_t;
    double *pos, *metric, *flux;
    const double *g_pos, *g_metric, *g_flux;
    double *g_heights;
    int64_t n, max_depth, wait_at_top, replay, threads;
} chunk_job;

/* ---------------------------------------------------------------- small helpers */

/* Event e of photon i in the chunk's log (max_depth, N): event by event, so that a packet's
 * photons' event lies together. */
static inline SFC_INLINE int64_t log_slot(const chunk_job *c, int64_t e, int64_t i) { return e * c->n + i; }

/* The flux of kind `kind` lost in block b (c->lost is (LOSS_KINDS, blocks)). */
static inline SFC_INLINE double *lost_in(const chunk_job *c, int kind, int64_t b) {
    return c->lost + kind * ((c->n + BLOCK - 1) / BLOCK) + b;
}

/* Photon i's splat arguments (splat_arguments in kernels_native.py) into column i: pixel
 * position, footprint metric and flux where it landed (position p, position differentials dpu,
 * dpv in mm), else flux 0 and a unit metric. Returns the flux of a landed photon beside the
 * receiver (W), else 0. */
static inline SFC_INLINE double put_splat_arguments(const mesh_scene *ms, const chunk_job *c, int64_t i,
                                                    int landed, double px, double py, double dpux, double dpuy,
                                                    double dpvx, double dpvy, double flux) {
    const sfc_scene *sc = &ms->hf;
    const double k = sc->to_px;
    const int64_t n = c->n;
    double q[3] = {1.0, 0.0, 1.0};
    if (landed) footprint_metric(sc, dpux * k, dpuy * k, dpvx * k, dpvy * k, q);
    c->pos[i] = landed ? (px + sc->receiver_half) * k - 0.5 : 0.0;
    c->pos[n + i] = landed ? (py + sc->receiver_half) * k - 0.5 : 0.0;
    c->metric[i] = q[0];
    c->metric[n + i] = q[1];
    c->metric[2 * n + i] = q[2];
    c->flux[i] = landed ? flux : 0.0;
    return landed && (fabs(px) > sc->receiver_half || fabs(py) > sc->receiver_half) ? flux : 0.0;
}

static inline SFC_INLINE vec3 sub3(vec3 a, vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline SFC_INLINE vec3 load3(const double *a) { return v3(a[0], a[1], a[2]); }
static inline SFC_INLINE double component(vec3 a, int k) { return k == 0 ? a.x : (k == 1 ? a.y : a.z); }

/* ---------------------------------------------------------------- faces */

/* Eight rays for Embree (RTCRayHit8): field j of ray r at slot 8 j + r, four bytes each. Ray:
 * origin 0-2, tnear 3, direction 4-6, time 7, tfar 8, mask 9, id 10, flags 11; hit: normal 12-14,
 * u 15, v 16, primID 17, geomID 18, then the instance ids (room for two fields). */
enum { RAYS = 8, RAY_FIELDS = 22 };
typedef union { float f[RAY_FIELDS * RAYS]; uint32_t u[RAY_FIELDS * RAYS]; } __attribute__((aligned(32))) ray_hit8;

/* Ray r of the eight: from o along w (float32), any distance, no hit yet. */
static inline SFC_INLINE void set_ray(ray_hit8 *rays, int r, vec3 o, vec3 w) {
    rays->f[r] = (float)o.x; rays->f[8 + r] = (float)o.y; rays->f[16 + r] = (float)o.z;
    rays->f[24 + r] = 0.0f;
    rays->f[32 + r] = (float)w.x; rays->f[40 + r] = (float)w.y; rays->f[48 + r] = (float)w.z;
    rays->f[56 + r] = 0.0f;
    rays->f[64 + r] = INFINITY;
    rays->u[72 + r] = 0xFFFFFFFFu; rays->u[80 + r] = 0; rays->u[88 + r] = 0;
    rays->u[136 + r] = 0xFFFFFFFFu; rays->u[144 + r] = 0xFFFFFFFFu;
}

/* Embree's first faces along the first `count` of the eight rays (first_face, a packet at a time):
 * face[lane[r]] the face of ray r, -1 for none. */
static void first_faces(const mesh_faces *fa, ray_hit8 *rays, int count, const int64_t *lane, int64_t *face) {
    int valid[RAYS];
    for (int r = 0; r < RAYS; r++) valid[r] = r < count ? -1 : 0;
    fa->intersect8(valid, fa->embree, rays, NULL);
    for (int r = 0; r < count; r++) face[lane[r]] = rays->u[144 + r] == 0xFFFFFFFFu ? -1 : (int64_t)rays->u[136 + r];
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

/* A face's interpolated shading normal at a point q on its plane (_shading): N = raw / |raw|,
 * raw = n0 + b1 e1 + b2 e2, b_k = g_k . (q - v0), e_k = n_k - n0 the corner normals' differences,
 * g_k the face's dual basis (apply_columns computes it across a packet). */
typedef struct { vec3 normal; double length; vec3 e1, e2, g1, g2; } shading_frame;

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
 * returns t (inf for none), plane in *which (-1 for none). Along each axis the ray can cross only
 * one of the planes, the one its direction leaves through (from inside) or enters by (from air). */
static double box_hit(const mesh_scene *ms, vec3 p, vec3 w, int64_t medium, int64_t substrate, int64_t *which) {
    const int leaving = medium == substrate;
    double best = INFINITY;
    *which = -1;
    if (!leaving && medium != AIR) return best;
    for (int axis = 0; axis < 3; axis++) {
        const double wa = component(w, axis);
        if (fabs(wa) <= 1e-12) continue;
        int k = 4; /* the bottom: left going down, entered going up */
        if (axis < 2)
            k = 2 * axis + ((wa > 0.0) == leaving ? 0 : 1);
        else if ((wa < 0.0) != leaving)
            continue;
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

/* Whether the photon's next event may be on a face (_next_event's search of the faces), from p
 * along w in `medium`, `clear` if it left a clear face, t_top as in next_event. */
static inline SFC_INLINE int searches_faces(const mesh_scene *ms, const mesh_faces *fa, vec3 p, vec3 w,
                                            int64_t medium, int clear, int released, double t_top) {
    const int in_air = medium == AIR;
    const int skip = clear || (in_air && w.z < 0.0 && p.z < ms->lowest)
                     || (released && t_top < (ms->hf.base - p.z) / w.z);
    return fa->embree != NULL && medium != fa->substrate && !skip;
}

/* The photon's next event (_next_event), from p along w in `medium`, t_top its hit on the print
 * where it comes down onto it (over_print; searched beforehand for the packet, print_hits), face
 * the first face along its ray where searches_faces (searched beforehand, packet_faces), else -1:
 * kind, face or box plane in *which, distance in *t. */
static int64_t next_event(const mesh_scene *ms, const mesh_faces *fa, vec3 p, vec3 w, int64_t medium,
                          int wait_at_top, double t_top, int64_t face, int64_t *which, double *t_out) {
    const int in_air = medium == AIR, in_sub = medium == fa->substrate;
    const double thickness = ms->hf.base;
    double best = INFINITY;
    int64_t kind = ESCAPED;
    *which = -1;
    const int over = in_air && over_print(ms, p, w);
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

/* ---------------------------------------------------------------- packets */

/* The photons of a block go through their events PACKET at a time and in step: each photon's
 * next event is found (or read from the log) one photon at a time, the surfaces looked up for the
 * packet (look_up), then one loop over the packet moves every photon onto its surface and refracts
 * or reflects it (apply_columns); the reverse takes the events back the same way
 * (retreat_columns). Those two loops are written branch-free (where the packet meets several kinds
 * of surface, every lane computes each kind's arithmetic and keeps its own), so that GCC vectorises
 * them across photons; each lane keeps exactly the arithmetic of its own kind. A packet holds its
 * photons in columns: state[j][k] is entry j of lane k's row. */
enum { PACKET = 32 };
_Static_assert((int)PACKET <= (int)SEARCH_LANES, "a packet must fit one lockstep hit search");

typedef struct {
    int64_t count;         /* lanes in use */
    int64_t index[PACKET]; /* the chunk's row of each lane */
    double state[STATE][PACKET];
    int64_t medium[PACKET], status[PACKET], clear[PACKET];
    double t_top[PACKET];  /* each lane's hit on the print where it comes down onto it, else inf */
    int64_t face[PACKET];  /* each lane's first face along its ray where searches_faces, else -1 */
    ray_hit8 rays;         /* Embree's rays for them */
    double search_o[3][SEARCH_LANES], search_w[3][SEARCH_LANES]; /* the rays of the lanes over the print */
    search_state search;   /* the print's hit search for them */
} packet;

/* One event of a packet's photons. Looked up: kind (-1: none), face or plane, distance, whether it
 * moves the photon (MESH, TOP, BOX or RECEIVER) and whether it crosses a surface (not RECEIVER),
 * whether it is a face's or the print's, the solid's refractive index, the plane
 * normal, a face's shading corners n0, e_k = n_k - n0 with v0 and the dual basis g_k (where the
 * packet meets faces; flat for other kinds: n0 the plane normal, the rest zero) and the print's
 * jet (where the packet meets the print; zero off it).
 * Computed (apply_columns, the reverse's inputs): the point met with its differentials, the
 * shading normal with its differentials and |raw|, the crossing (sign, eta, cosines, refracted or
 * reflected), the flux lost to Fresnel and the cosine of the way out with the plane normal. */
typedef struct {
    int64_t kind[PACKET], which[PACKET];
    int surfaces; /* the kinds of surface the applied events meet (surfaces_met) */
    double moves[PACKET], crosses[PACKET], on_mesh[PACKET], on_top[PACKET]; /* 1.0 or 0.0: the masks of the
                                                                                 packet loops, in doubles so that
                                                                                 they vectorise with the rest */
    double t[PACKET], n_solid[PACKET];
    double n_plane[3][PACKET], n0[3][PACKET], e1[3][PACKET], e2[3][PACKET], v0[3][PACKET], g1[3][PACKET],
        g2[3][PACKET], jet[5][PACKET];
    double q[3][PACKET], dqu[3][PACKET], dqv[3][PACKET], outward[3][PACKET], dnu[3][PACKET], dnv[3][PACKET];
    double length[PACKET], sign[PACKET], eta[PACKET], ci[PACKET], ct[PACKET], lost[PACKET], leave_cos[PACKET];
    double through[PACKET]; /* 1.0 refracted, 0.0 reflected */
} event_columns;

static inline SFC_INLINE vec3 col3(const double c[][PACKET], int j, int64_t k) {
    return v3(c[j][k], c[j + 1][k], c[j + 2][k]);
}
static inline SFC_INLINE void put3(double c[][PACKET], int j, int64_t k, vec3 v) {
    c[j][k] = v.x; c[j + 1][k] = v.y; c[j + 2][k] = v.z;
}
static inline SFC_INLINE vec3 pick3(int which, vec3 a, vec3 b) {
    return v3(which ? a.x : b.x, which ? a.y : b.y, which ? a.z : b.z);
}

/* A packet's work space, aligned for Embree's rays (free with free). */
static packet *new_packet(void) {
    const size_t align = 64, size = (sizeof(packet) + align - 1) / align * align;
    return (packet *)aligned_alloc(align, size);
}

/* pk->t_top: the print's hits of the lanes under way that come down onto it from above
 * (over_print), searched in lockstep (solve_hits); inf for the others. */
static void print_hits(const mesh_scene *ms, const chunk_job *c, packet *pk) {
    int64_t lane[PACKET], count = 0;
    for (int64_t k = 0; k < pk->count; k++) {
        pk->t_top[k] = INFINITY;
        const vec3 p = col3(pk->state, P, k), w = col3(pk->state, W, k);
        if (pk->status[k] != UNDER_WAY || pk->medium[k] != AIR || !over_print(ms, p, w)) continue;
        for (int j = 0; j < 3; j++) {
            pk->search_o[j][count] = pk->state[P + j][k];
            pk->search_w[j][count] = pk->state[W + j][k];
        }
        lane[count++] = k;
    }
    double t[PACKET];
    if (count > 0) solve_hits(c->d, c->m, &ms->hf, pk->search_o, pk->search_w, count, t, &pk->search);
    for (int64_t j = 0; j < count; j++) pk->t_top[lane[j]] = t[j];
}

/* pk->face: the first face along the ray of each lane under way where searches_faces, by Embree
 * RAYS rays at a time; -1 for the others. `released`: the packet's first event of a render. */
static void packet_faces(const mesh_scene *ms, const mesh_faces *fa, packet *pk, int released) {
    int64_t lane[RAYS];
    int count = 0;
    for (int64_t k = 0; k < pk->count; k++) {
        pk->face[k] = -1;
        const vec3 p = col3(pk->state, P, k), w = col3(pk->state, W, k);
        if (pk->status[k] != UNDER_WAY
            || !searches_faces(ms, fa, p, w, pk->medium[k], (int)pk->clear[k], released, pk->t_top[k]))
            continue;
        set_ray(&pk->rays, count, axpy(ms->start_offset, w, p), w);
        lane[count++] = k;
        if (count == RAYS) {
            first_faces(fa, &pk->rays, count, lane, pk->face);
            count = 0;
        }
    }
    if (count > 0) first_faces(fa, &pk->rays, count, lane, pk->face);
}

/* The surfaces a packet's applied events meet: all faces, all the print, all the substrate's walls
 * and bottom, all the receiver, or a mix. The packet loops below keep one lane's arithmetic of its
 * own kind either way; for one kind they are compiled without the others' (the flags are constants
 * there), and the look-up fills only the columns those read. The photons of a packet nearly always
 * meet the same kind of surface at the same event. */
enum { ON_FACES = 0, ON_PRINT = 1, ON_WALLS = 2, ON_RECEIVER = 3, ON_MIX = 4 };

static int surfaces_met(int64_t count, const int64_t *kind) {
    int faces = 0, print = 0, walls = 0, receiver = 0;
    for (int64_t k = 0; k < count; k++) {
        faces |= kind[k] == MESH;
        print |= kind[k] == TOP;
        walls |= kind[k] == BOX;
        receiver |= kind[k] == RECEIVER;
    }
    if (faces + print + walls + receiver > 1) return ON_MIX;
    return faces ? ON_FACES : (print ? ON_PRINT : (walls ? ON_WALLS : ON_RECEIVER));
}

/* The surfaces of the packet's events (ev->kind, which, t set; kind -1 for a lane without one), as
 * event_surface looks them up, photon i in its wavelength channel: ev->surfaces and the columns
 * the packet loops read for those surfaces. */
static void look_up(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c, const packet *pk,
                    event_columns *ev) {
    const int64_t count = pk->count;
    const int surfaces = surfaces_met(count, ev->kind);
    const int faces = surfaces == ON_FACES || surfaces == ON_MIX, print = surfaces == ON_PRINT || surfaces == ON_MIX;
    ev->surfaces = surfaces;
    for (int64_t k = 0; k < count; k++) {
        const int64_t kind = ev->kind[k], f = ev->which[k];
        vec3 n_plane = UP;
        int64_t solid = fa->substrate;
        if (kind == MESH) {
            n_plane = load3(fa->plane + 3 * f);
            solid = fa->face_element[f];
        } else if (kind == BOX) {
            n_plane = box_normal(f);
        }
        if (faces) {
            vec3 n0 = n_plane, e1 = ZERO, e2 = ZERO, v0 = ZERO, g1 = ZERO, g2 = ZERO;
            if (kind == MESH) {
                const double *corners = fa->shading + 9 * f;
                n0 = load3(corners);
                e1 = sub3(load3(corners + 3), n0);
                e2 = sub3(load3(corners + 6), n0);
                v0 = load3(fa->v0 + 3 * f);
                g1 = dual_row(fa, f, 0);
                g2 = dual_row(fa, f, 1);
            }
            put3(ev->n0, 0, k, n0);
            put3(ev->e1, 0, k, e1);
            put3(ev->e2, 0, k, e2);
            put3(ev->v0, 0, k, v0);
            put3(ev->g1, 0, k, g1);
            put3(ev->g2, 0, k, g2);
        }
        if (print) {
            double jet[5] = {0.0, 0.0, 0.0, 0.0, 0.0};
            if (kind == TOP) {
                const double t = ev->t[k];
                surface_jet(&ms->hf, c->d, c->m, pk->state[P][k] + t * pk->state[W][k],
                            pk->state[P + 1][k] + t * pk->state[W + 1][k], jet);
                n_plane = height_field_normal(jet[0], jet[1]);
            }
            for (int j = 0; j < 5; j++) ev->jet[j][k] = jet[j];
        }
        const int applied = kind == MESH || kind == TOP || kind == BOX || kind == RECEIVER;
        ev->moves[k] = applied ? 1.0 : 0.0;
        ev->crosses[k] = applied && kind != RECEIVER ? 1.0 : 0.0;
        ev->on_mesh[k] = kind == MESH ? 1.0 : 0.0;
        ev->on_top[k] = kind == TOP ? 1.0 : 0.0;
        ev->n_solid[k] = kind == RECEIVER ? 1.0 : fa->indices[solid * fa->channels + c->channel[pk->index[k]]];
        put3(ev->n_plane, 0, k, n_plane);
    }
}

/* Lane k's applied event, first half (event_surface and _advance_one's transfer): the point met
 * with its differentials, the surface normal there with its differentials (a face's interpolated
 * shading normal, the print's or a plane's normal) into ev. `mesh`, `top`: whether the surface is
 * a face, the print (constants in the loops for one kind). */
static inline SFC_INLINE void meet_lane(const mesh_scene *ms, const packet *restrict pk, event_columns *restrict ev,
                                        int64_t k, int mesh, int top) {
    const vec3 p = col3(pk->state, P, k), dpu = col3(pk->state, DPU, k), dpv = col3(pk->state, DPV, k);
    const vec3 w = col3(pk->state, W, k), dwu = col3(pk->state, DWU, k), dwv = col3(pk->state, DWV, k);
    const vec3 n_plane = col3(ev->n_plane, 0, k);
    vec3 q, dqu, dqv;
    transfer(&ms->hf, p, dpu, dpv, w, dwu, dwv, ev->t[k], n_plane, &q, &dqu, &dqv);
    /* A face's interpolated normal (_shading); the plane normal on the other kinds. */
    shading_frame frame;
    frame.e1 = col3(ev->e1, 0, k);
    frame.e2 = col3(ev->e2, 0, k);
    frame.g1 = col3(ev->g1, 0, k);
    frame.g2 = col3(ev->g2, 0, k);
    const vec3 rel = sub3(q, col3(ev->v0, 0, k));
    const vec3 raw = axpy(dot(rel, frame.g1), frame.e1, axpy(dot(rel, frame.g2), frame.e2, col3(ev->n0, 0, k)));
    frame.length = sqrt(dot(raw, raw));
    frame.normal = scale3(1.0 / frame.length, raw);
    const double sxx = ev->jet[2][k], sxy = ev->jet[3][k], syy = ev->jet[4][k];
    put3(ev->q, 0, k, q);
    put3(ev->dqu, 0, k, dqu);
    put3(ev->dqv, 0, k, dqv);
    put3(ev->outward, 0, k, pick3(mesh, frame.normal, n_plane));
    put3(ev->dnu, 0, k, pick3(mesh, shading_differential(&frame, dqu),
                              pick3(top, normal_differential(sxx, sxy, syy, n_plane, dqu), ZERO)));
    put3(ev->dnv, 0, k, pick3(mesh, shading_differential(&frame, dqv),
                              pick3(top, normal_differential(sxx, sxy, syy, n_plane, dqv), ZERO)));
    ev->length[k] = mesh ? frame.length : 1.0;
}

/* Lane k's applied event, second half (interface and the rest of _advance_one): the photon moved
 * onto the point meet_lane found, refracted or reflected (not at the receiver), its flux less the
 * Fresnel loss (fresnel on); the crossing into ev. `crossing` 0 where no lane crosses its surface
 * (a constant in the receiver's loop). */
static inline SFC_INLINE void cross_lane(const mesh_scene *ms, packet *restrict pk, event_columns *restrict ev,
                                         int64_t k, int crossing) {
    const int64_t fres = ms->hf.fresnel;
    const int applied = ev->moves[k] != 0.0, crosses = crossing && ev->crosses[k] != 0.0;
    const vec3 w = col3(pk->state, W, k), dwu = col3(pk->state, DWU, k), dwv = col3(pk->state, DWV, k);
    const double flux = pk->state[FLUX][k];
    const vec3 n_plane = col3(ev->n_plane, 0, k);
    const int entering = dot(w, n_plane) < 0.0;
    const double sign = entering ? 1.0 : -1.0, n_solid = ev->n_solid[k];
    const double eta = entering ? 1.0 / n_solid : n_solid;
    const vec3 facing = scale3(sign, col3(ev->outward, 0, k));
    const vec3 dfu = scale3(sign, col3(ev->dnu, 0, k)), dfv = scale3(sign, col3(ev->dnv, 0, k));
    vec3 r, ru, rv, m, mu, mv;
    double ci, ct;
    const int through = refract(w, dwu, dwv, facing, dfu, dfv, eta, &r, &ru, &rv, &ci, &ct) > 0.0;
    reflect(w, dwu, dwv, facing, dfu, dfv, &m, &mu, &mv);
    const vec3 out = pick3(through, r, m), out_u = pick3(through, ru, mu), out_v = pick3(through, rv, mv);
    const double kept = fres && through ? fresnel(ci, ct, eta) : 1.0;
    put3(pk->state, P, k, pick3(applied, col3(ev->q, 0, k), col3(pk->state, P, k)));
    put3(pk->state, DPU, k, pick3(applied, col3(ev->dqu, 0, k), col3(pk->state, DPU, k)));
    put3(pk->state, DPV, k, pick3(applied, col3(ev->dqv, 0, k), col3(pk->state, DPV, k)));
    put3(pk->state, W, k, pick3(crosses, out, w));
    put3(pk->state, DWU, k, pick3(crosses, out_u, dwu));
    put3(pk->state, DWV, k, pick3(crosses, out_v, dwv));
    pk->state[FLUX][k] = crosses ? flux * kept : flux;
    /* The crossing's columns, read only where the lane crosses its surface (zero in a packet whose
     * lanes do not, so that its loop leaves the crossing out). */
    ev->lost[k] = crossing ? flux * (1.0 - kept) : 0.0;
    ev->leave_cos[k] = crossing ? dot(out, n_plane) : 0.0;
    ev->sign[k] = crossing ? sign : 0.0;
    ev->eta[k] = crossing ? eta : 0.0;
    ev->ci[k] = crossing ? ci : 0.0;
    ev->ct[k] = crossing ? ct : 0.0;
    ev->through[k] = crossing && through ? 1.0 : 0.0;
}

/* Every applied event of the packet at once (meet_lane, then cross_lane), in two loops that GCC
 * vectorises (two, so that each keeps its values in registers). */
static void apply_columns(const mesh_scene *ms, packet *restrict pk, event_columns *restrict ev) {
    const int64_t count = pk->count;
#define MEET(mesh, top) _Pragma("GCC ivdep") for (int64_t k = 0; k < count; k++) meet_lane(ms, pk, ev, k, mesh, top)
    switch (ev->surfaces) {
    case ON_FACES: MEET(1, 0); break;
    case ON_PRINT: MEET(0, 1); break;
    case ON_WALLS: case ON_RECEIVER: MEET(0, 0); break;
    default: MEET(ev->on_mesh[k] != 0.0, ev->on_top[k] != 0.0);
    }
#undef MEET
    if (ev->surfaces == ON_RECEIVER) {
#pragma GCC ivdep
        for (int64_t k = 0; k < count; k++) cross_lane(ms, pk, ev, k, 0);
    } else {
#pragma GCC ivdep
        for (int64_t k = 0; k < count; k++) cross_lane(ms, pk, ev, k, 1);
    }
}

/* The packet's lanes k = 0 .. count - 1 as chunk rows index[k]: their state (from `rows`) into
 * columns. */
static void load_packet(const chunk_job *c, const double *rows, packet *pk) {
    for (int64_t k = 0; k < pk->count; k++) {
        const int64_t i = pk->index[k];
        for (int j = 0; j < STATE; j++) pk->state[j][k] = rows[STATE * i + j];
        pk->medium[k] = c->medium[i];
        pk->status[k] = c->status[i];
        pk->clear[k] = c->clear[i];
    }
}

/* The packet's photons through their events (advance, _run in operators/mesh/trace_native.py):
 * each at most max_depth of them, until it lands, is lost, waits at the top (wait_at_top) or has
 * had max_depth counted events in all, from c->start (or c->state); their losses added to block
 * `block`'s, their events into the log (or, with replay, from it); their state, medium, status and
 * clear back into the chunk, their splat arguments into their columns. */
static void trace_packet(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c, packet *pk,
                         event_columns *ev, int64_t block) {
    const int64_t depth = c->max_depth, logging = c->log_kind != NULL && !c->replay;
    double lost[LOSS_KINDS] = {0.0};
    load_packet(c, c->start != NULL ? c->start : c->state, pk);
    for (int64_t e = 0; e < depth; e++) {
        double flux[PACKET];
        int any = 0;
        const int released = e == 0 && !c->wait_at_top;
        if (!c->replay) {
            if (!c->wait_at_top) print_hits(ms, c, pk);
            packet_faces(ms, fa, pk, released);
        }
        for (int64_t k = 0; k < pk->count; k++) {
            ev->kind[k] = -1;
            ev->which[k] = -1;
            ev->t[k] = 0.0;
            if (pk->status[k] != UNDER_WAY) continue;
            any = 1;
            const int64_t i = pk->index[k];
            const vec3 p = col3(pk->state, P, k), w = col3(pk->state, W, k);
            if (c->replay) {
                const int64_t at = log_slot(c, e, i);
                ev->kind[k] = c->log_kind[at];
                ev->which[k] = c->log_which[at];
                ev->t[k] = c->log_t[at];
            } else {
                ev->kind[k] = next_event(ms, fa, p, w, pk->medium[k], (int)c->wait_at_top,
                                         c->wait_at_top ? INFINITY : pk->t_top[k], pk->face[k], &ev->which[k],
                                         &ev->t[k]);
            }
            flux[k] = pk->state[FLUX][k];
        }
        if (!any) break;
        look_up(ms, fa, c, pk, ev);
        apply_columns(ms, pk, ev);
        for (int64_t k = 0; k < pk->count; k++) {
            const int64_t kind = ev->kind[k], i = pk->index[k];
            if (pk->status[k] != UNDER_WAY) continue;
            pk->clear[k] = 0;
            if (kind == AT_TOP) {
                pk->status[k] = WAITING;
            } else if (kind == ESCAPED || kind == INSIDE_TOP) {
                pk->status[k] = LOST;
            } else if (kind == RECEIVER) {
                pk->status[k] = LANDED;
            } else if (ev->through[k] != 0.0) {
                const int64_t solid = kind == MESH ? fa->face_element[ev->which[k]] : fa->substrate;
                const int entering = ev->sign[k] > 0.0;
                if (ms->hf.fresnel) lost[LOST_FRESNEL] += ev->lost[k];
                pk->medium[k] = entering ? solid : AIR;
                pk->clear[k] = kind == MESH && !entering && fa->face_clear[ev->which[k]]
                               && ev->leave_cos[k] >= ms->clear_cos;
            }
            if (logging) {
                const int64_t at = log_slot(c, e, i);
                c->log_kind[at] = (int8_t)kind;
                c->log_which[at] = (int32_t)ev->which[k];
                c->log_t[at] = ev->t[k];
            }
            if (kind != AT_TOP) c->events[i]++;
            if (kind == ESCAPED) lost[LOST_ESCAPED] += flux[k];
            if (kind == INSIDE_TOP) lost[LOST_INSIDE_TOP] += flux[k];
            if (pk->status[k] == UNDER_WAY && c->events[i] >= depth) {
                lost[LOST_MAX_DEPTH] += pk->state[FLUX][k];
                pk->status[k] = LOST;
            }
        }
    }
    for (int64_t k = 0; k < pk->count; k++) {
        const int64_t i = pk->index[k];
        if (c->state != NULL)
            for (int j = 0; j < STATE; j++) c->state[STATE * i + j] = pk->state[j][k];
        c->medium[i] = pk->medium[k];
        c->status[i] = pk->status[k];
        c->clear[i] = (uint8_t)pk->clear[k];
        lost[LOST_MISSED] += put_splat_arguments(ms, c, i, pk->status[k] == LANDED, pk->state[P][k],
                                                 pk->state[P + 1][k], pk->state[DPU][k], pk->state[DPU + 1][k],
                                                 pk->state[DPV][k], pk->state[DPV + 1][k], pk->state[FLUX][k]);
    }
    for (int kind = 0; kind < LOSS_KINDS; kind++) *lost_in(c, kind, block) += lost[kind];
}

typedef struct {
    const mesh_scene *ms;
    const mesh_faces *fa;
    const chunk_job *c;
    int64_t blocks;
} worker_job;

static int trace_worker(void *context, int64_t thread) {
    const worker_job *j = (const worker_job *)context;
    const chunk_job *c = j->c;
    packet *pk = new_packet();
    event_columns *ev = (event_columns *)malloc(sizeof(event_columns));
    if (!pk || !ev) {
        free(pk);
        free(ev);
        return 1;
    }
    for (int64_t b = thread; b < j->blocks; b += c->threads) {
        const int64_t first = b * BLOCK, end = imin(c->n, (b + 1) * BLOCK);
        if (c->log_kind != NULL && !c->replay) /* no event yet: kind -1 in every slot of the block's photons */
            for (int64_t e = 0; e < c->max_depth; e++)
                memset(c->log_kind + log_slot(c, e, first), -1, (size_t)(end - first));
        for (int kind = 0; kind < LOSS_KINDS; kind++) *lost_in(c, kind, b) = 0.0;
        pk->count = 0;
        for (int64_t i = first; i < end; i++) {
            if (c->status[i] != UNDER_WAY) { /* not traced: as it starts */
                const double *row = (c->start != NULL ? c->start : c->state) + STATE * i;
                if (c->start != NULL && c->state != NULL) memcpy(c->state + STATE * i, row, STATE * sizeof(double));
                *lost_in(c, LOST_MISSED, b) += put_splat_arguments(j->ms, c, i, c->status[i] == LANDED, row[P],
                                                                   row[P + 1], row[DPU], row[DPU + 1], row[DPV],
                                                                   row[DPV + 1], row[FLUX]);
                continue;
            }
            pk->index[pk->count++] = i;
            if (pk->count == PACKET) {
                trace_packet(j->ms, j->fa, c, pk, ev, b);
                pk->count = 0;
            }
        }
        if (pk->count > 0) trace_packet(j->ms, j->fa, c, pk, ev, b);
    }
    free(pk);
    free(ev);
    return 0;
}

/* ---------------------------------------------------------------- reverse */

/* The reverse of lane k's applied event (_retreat_one): column k of g (STATE columns) from the
 * gradient w.r.t. the state after the event to that before it (`before`, the states apply_columns
 * started from; ev, what it computed); at the top the gradient w.r.t. the hit's distance and jet
 * into column k of hit (6 columns, zero elsewhere) and g zeroed (the host of the loop adds hit into
 * the heights' gradient). `mesh`, `top` as in meet_lane, `crossing` as in cross_lane; `reflecting` 0 where no lane
 * was reflected. */
static inline SFC_INLINE void retreat_lane(const mesh_scene *ms, int64_t k, const event_columns *restrict ev,
                                           const double (*restrict before)[PACKET], double (*restrict g)[PACKET],
                                           double (*restrict hit)[PACKET], int mesh, int top, int crossing,
                                           int reflecting) {
    const int64_t fres = ms->hf.fresnel;
    const int applied = ev->moves[k] != 0.0, crosses = crossing && ev->crosses[k] != 0.0;
    const vec3 dpu = col3(before, DPU, k), dpv = col3(before, DPV, k);
    const vec3 w = col3(before, W, k), dwu = col3(before, DWU, k), dwv = col3(before, DWV, k);
    const double flux = before[FLUX][k], t = ev->t[k];
    const vec3 n_plane = col3(ev->n_plane, 0, k), outward = col3(ev->outward, 0, k);
    const vec3 dnu = col3(ev->dnu, 0, k), dnv = col3(ev->dnv, 0, k);
    const vec3 dqu = col3(ev->dqu, 0, k), dqv = col3(ev->dqv, 0, k);
    const vec3 g_q = col3(g, P, k), g_dqu = col3(g, DPU, k), g_dqv = col3(g, DPV, k);
    const vec3 g_r = col3(g, W, k), g_ru = col3(g, DWU, k), g_rv = col3(g, DWV, k);
    const double g_flux = g[FLUX][k], sign = ev->sign[k], eta = ev->eta[k], ci = ev->ci[k], ct = ev->ct[k];
    const int through = !reflecting || ev->through[k] != 0.0;
    /* The crossing, refracted or reflected. */
    const vec3 facing = scale3(sign, outward), dfu = scale3(sign, dnu), dfv = scale3(sign, dnv);
    double g_ci = 0.0, g_ct = 0.0, kept = 1.0;
    if (fres) {
        kept = fresnel(ci, ct, eta);
        fresnel_adjoint(ci, ct, eta, g_flux * flux, &g_ci, &g_ct);
    }
    const refract_grads a_t = refract_adjoint(w, dwu, dwv, facing, dfu, dfv, eta, g_r, g_ru, g_rv, g_ci, g_ct);
    const reflect_grads a_r = reflect_adjoint(w, dwu, dwv, facing, dfu, dfv, g_r, g_ru, g_rv);
    const vec3 g_w = pick3(crosses, pick3(through, a_t.g_w, a_r.g_w), ZERO);
    const vec3 g_dwu = pick3(crosses, pick3(through, a_t.g_dwu, a_r.g_dwu), ZERO);
    const vec3 g_dwv = pick3(crosses, pick3(through, a_t.g_dwv, a_r.g_dwv), ZERO);
    const vec3 g_out = scale3(sign, pick3(through, a_t.g_n, a_r.g_n));
    const vec3 g_dnu = scale3(sign, pick3(through, a_t.g_dnu, a_r.g_dnu));
    const vec3 g_dnv = scale3(sign, pick3(through, a_t.g_dnv, a_r.g_dnv));
    const double g_flux_before = crosses && through && fres ? g_flux * kept : g_flux;
    /* A face's shading: N = raw / |raw|, raw = n0 + b1 e1 + b2 e2, b_k = g_k . (q - v0). */
    shading_frame frame;
    frame.normal = outward;
    frame.length = ev->length[k];
    frame.e1 = col3(ev->e1, 0, k);
    frame.e2 = col3(ev->e2, 0, k);
    frame.g1 = col3(ev->g1, 0, k);
    frame.g2 = col3(ev->g2, 0, k);
    double gl_u, gl_v;
    vec3 gp_u, gp_v;
    const vec3 gn_u = shading_differential_adjoint(&frame, dqu, dnu, g_dnu, &gl_u, &gp_u);
    const vec3 gn_v = shading_differential_adjoint(&frame, dqv, dnv, g_dnv, &gl_v, &gp_v);
    const vec3 g_normal = add3(g_out, add3(gn_u, gn_v));
    const vec3 g_raw = axpy(gl_u + gl_v - dot(frame.normal, g_normal) / frame.length, frame.normal,
                            scale3(1.0 / frame.length, g_normal));
    const vec3 g_q_mesh = axpy(dot(frame.e1, g_raw), frame.g1, axpy(dot(frame.e2, g_raw), frame.g2, g_q));
    /* The print's normal and its differentials. */
    const double sxx = ev->jet[2][k], sxy = ev->jet[3][k], syy = ev->jet[4][k];
    double g_sxx = 0.0, g_sxy = 0.0, g_syy = 0.0;
    vec3 g_nu, g_dpu_n, g_nv, g_dpv_n;
    normal_differential_adjoint(sxx, sxy, syy, n_plane, dqu, g_dnu, &g_sxx, &g_sxy, &g_syy, &g_nu, &g_dpu_n);
    normal_differential_adjoint(sxx, sxy, syy, n_plane, dqv, g_dnv, &g_sxx, &g_sxy, &g_syy, &g_nv, &g_dpv_n);
    const vec3 g_q_at = pick3(mesh, g_q_mesh, g_q);
    const vec3 g_dqu_at = pick3(mesh, add3(g_dqu, gp_u), pick3(top, add3(g_dqu, g_dpu_n), g_dqu));
    const vec3 g_dqv_at = pick3(mesh, add3(g_dqv, gp_v), pick3(top, add3(g_dqv, g_dpv_n), g_dqv));
    const transfer_grads a = transfer_adjoint(&ms->hf, dpu, dpv, w, dwu, dwv, t, n_plane, g_q_at, g_dqu_at, g_dqv_at);
    /* At the top: the hit's distance and jet. */
    double g_sx, g_sy;
    height_field_normal_adjoint(ev->jet[0][k], ev->jet[1][k], add3(add3(g_out, add3(g_nu, g_nv)), a.g_n), &g_sx,
                                &g_sy);
    hit[0][k] = top ? a.g_dist : 0.0;
    hit[1][k] = top ? g_sx : 0.0;
    hit[2][k] = top ? g_sy : 0.0;
    hit[3][k] = top ? g_sxx : 0.0;
    hit[4][k] = top ? g_sxy : 0.0;
    hit[5][k] = top ? g_syy : 0.0;
    /* Elsewhere the distance to a fixed plane: t = (c - p . n) / (w . n). */
    const double wn = dot(w, n_plane);
    const int keep = !applied, zero = top;
    put3(g, P, k, pick3(keep, g_q, pick3(zero, ZERO, axpy(-a.g_dist / wn, n_plane, g_q_at))));
    put3(g, DPU, k, pick3(keep, g_dqu, pick3(zero, ZERO, a.g_dpu)));
    put3(g, DPV, k, pick3(keep, g_dqv, pick3(zero, ZERO, a.g_dpv)));
    put3(g, W, k, pick3(keep, g_r, pick3(zero, ZERO, add3(add3(g_w, a.g_w), scale3(-a.g_dist * t / wn, n_plane)))));
    put3(g, DWU, k, pick3(keep, g_ru, pick3(zero, ZERO, add3(g_dwu, a.g_dwu))));
    put3(g, DWV, k, pick3(keep, g_rv, pick3(zero, ZERO, add3(g_dwv, a.g_dwv))));
    g[FLUX][k] = keep ? g_flux : (zero ? 0.0 : g_flux_before);
}

/* The reverse of every applied event of the packet at once (retreat_lane), in one loop that GCC
 * vectorises. */
static void retreat_columns(const mesh_scene *ms, int64_t count, const event_columns *restrict ev,
                            const double (*restrict before)[PACKET], double (*restrict g)[PACKET],
                            double (*restrict hit)[PACKET]) {
    int reflected = 0;
    for (int64_t k = 0; k < count; k++) reflected |= ev->crosses[k] != 0.0 && ev->through[k] == 0.0;
#define RETREAT(mesh, top, crossing, reflecting)                                                              \
    _Pragma("GCC ivdep") for (int64_t k = 0; k < count; k++)                                                \
        retreat_lane(ms, k, ev, before, g, hit, mesh, top, crossing, reflecting)
    switch (reflected ? ON_MIX : ev->surfaces) {
    case ON_FACES: RETREAT(1, 0, 1, 0); break;
    case ON_PRINT: RETREAT(0, 1, 1, 0); break;
    case ON_WALLS: RETREAT(0, 0, 1, 0); break;
    case ON_RECEIVER: RETREAT(0, 0, 0, 0); break;
    default: RETREAT(ev->on_mesh[k] != 0.0, ev->on_top[k] != 0.0, 1, 1);
    }
#undef RETREAT
}

/* A reverse packet's work space: the states before each event and what each event computed. */
typedef struct {
    double (*before)[STATE][PACKET]; /* (max_depth) */
    event_columns *events;           /* (max_depth) */
    double g[STATE][PACKET], hit[6][PACKET];
} reverse_space;

/* The reverse of the packet's logged events (retreat over the events of _run, in
 * operators/mesh/trace_native.py): the events replayed from the photons' start (the states before
 * the trace in c->state), the states before each and what each computed kept, then the gradient
 * w.r.t. the final states (splat_arguments_adjoint, from the replayed final states and the gradient
 * w.r.t. the splat arguments) taken back through them event by event, into grad (m, m) at the top. */
static void reverse_packet(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c, packet *pk,
                           reverse_space *rs, double *grad) {
    const int64_t depth = c->max_depth;
    load_packet(c, c->state, pk);
    int64_t events = 0;
    for (; events < depth; events++) {
        event_columns *ev = rs->events + events;
        int any = 0;
        for (int64_t k = 0; k < pk->count; k++) {
            const int64_t at = log_slot(c, events, pk->index[k]);
            ev->kind[k] = c->log_kind[at];
            ev->which[k] = c->log_which[at];
            ev->t[k] = ev->kind[k] >= 0 ? c->log_t[at] : 0.0;
            any |= ev->kind[k] >= 0;
        }
        if (!any) break;
        look_up(ms, fa, c, pk, ev);
        memcpy(rs->before[events], pk->state, sizeof(pk->state));
        apply_columns(ms, pk, ev);
    }
    const sfc_scene *sc = &ms->hf;
    const double to_px = sc->to_px;
    for (int64_t k = 0; k < pk->count; k++) {
        const int64_t i = pk->index[k], n = c->n;
        for (int j = 0; j < STATE; j++) rs->g[j][k] = 0.0;
        double gf[4];
        footprint_metric_adjoint(sc, pk->state[DPU][k] * to_px, pk->state[DPU + 1][k] * to_px,
                                 pk->state[DPV][k] * to_px, pk->state[DPV + 1][k] * to_px, c->g_metric[i],
                                 c->g_metric[n + i], c->g_metric[2 * n + i], gf);
        rs->g[P][k] = c->g_pos[i] * to_px;
        rs->g[P + 1][k] = c->g_pos[n + i] * to_px;
        rs->g[DPU][k] = gf[0] * to_px;
        rs->g[DPU + 1][k] = gf[1] * to_px;
        rs->g[DPV][k] = gf[2] * to_px;
        rs->g[DPV + 1][k] = gf[3] * to_px;
        rs->g[FLUX][k] = c->g_flux[i];
    }
    for (int64_t e = events - 1; e >= 0; e--) {
        const event_columns *ev = rs->events + e;
        retreat_columns(ms, pk->count, ev, rs->before[e], rs->g, rs->hit);
        for (int64_t k = 0; k < pk->count; k++) {
            if (ev->kind[k] != TOP) continue;
            const double hit[6] = {rs->hit[0][k], rs->hit[1][k], rs->hit[2][k], rs->hit[3][k], rs->hit[4][k],
                                   rs->hit[5][k]};
            const vec3 p = col3(rs->before[e], P, k), w = col3(rs->before[e], W, k);
            hit_adjoint(&ms->hf, c->d, grad, c->m, p.x + ev->t[k] * w.x, p.y + ev->t[k] * w.y, w, hit);
        }
    }
}

static int reverse_worker(void *context, int64_t thread) {
    const worker_job *j = (const worker_job *)context;
    const chunk_job *c = j->c;
    const size_t depth = (size_t)imax(c->max_depth, 1);
    packet *pk = new_packet();
    reverse_space *rs = (reverse_space *)malloc(sizeof(reverse_space));
    double (*before)[STATE][PACKET] = malloc(sizeof(*before) * depth);
    event_columns *events = (event_columns *)malloc(sizeof(event_columns) * depth);
    if (!pk || !rs || !before || !events) {
        free(pk);
        free(rs);
        free(before);
        free(events);
        return 1;
    }
    rs->before = before;
    rs->events = events;
    double *grad = c->g_heights + thread * c->m * c->m;
    for (int64_t b = thread; b < j->blocks; b += c->threads) {
        pk->count = 0;
        for (int64_t i = b * BLOCK; i < imin(c->n, (b + 1) * BLOCK); i++) {
            if (c->status[i] != LANDED) continue;
            pk->index[pk->count++] = i;
            if (pk->count == PACKET) {
                reverse_packet(j->ms, j->fa, c, pk, rs, grad);
                pk->count = 0;
            }
        }
        if (pk->count > 0) reverse_packet(j->ms, j->fa, c, pk, rs, grad);
    }
    free(pk);
    free(rs);
    free(before);
    free(events);
    return 0;
}

/* ---------------------------------------------------------------- exported */

/* Photons per block of the threads' work (BLOCK): c->lost holds a column per block. */
int64_t SFC_EXPORT(sfc_mesh_block)(void) { return BLOCK; }

/* Trace every photon of the chunk under way through its events, on c->threads threads, into
 * c->state (NULL: not kept) from c->start (NULL: in place; see trace_packet), and every photon's
 * splat arguments into c->pos, metric, flux; the flux lost per kind and block into c->lost.
 * Returns 0, -1 when a thread could not start. */
int SFC_EXPORT(sfc_mesh_trace)(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c) {
    worker_job j = {ms, fa, c, (c->n + BLOCK - 1) / BLOCK};
    return sfc_parallel(c->threads, trace_worker, &j);
}

/* The gradient w.r.t. the heights, into c->g_heights (threads, m, m), of the gradient w.r.t. the
 * landed photons' splat arguments (c->g_pos, g_metric, g_flux): c->state, medium and clear hold the
 * chunk as it was before sfc_mesh_trace logged its events, c->status the status after it (only
 * landed photons carry a gradient). Returns 0, -1 on failure to allocate or start threads. */
int SFC_EXPORT(sfc_mesh_reverse)(const mesh_scene *ms, const mesh_faces *fa, const chunk_job *c) {
    worker_job j = {ms, fa, c, (c->n + BLOCK - 1) / BLOCK};
    return sfc_parallel(c->threads, reverse_worker, &j);
}
