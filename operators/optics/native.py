"""Per-photon ray optics with differentials and their adjoints, as scalar numba functions.

The same maths as :mod:`operators.optics.reference` and :func:`operators.splat.splat.footprint_metric`, for one
photon at a time inside the fused kernels (:mod:`operators.heightfield.kernels_native`): vectors are 3-tuples
of floats, a pair of differentials (d/du, d/dv) is two such tuples. Every ``*_adjoint`` function is
the hand-written reverse mode of its forward function: given the forward inputs and the
gradients of a loss w.r.t. the outputs, it returns the gradients w.r.t. the (non-constant)
inputs, matching what torch autograd computes through the torch path, including where
``away_from_zero`` and the clamps cut the gradient.
"""

from __future__ import annotations

import math


from operators.kernels.numba_settings import jit_inline
from operators.optics.reference import GRAZING
from operators.splat.splat import MAX_DIFFERENTIAL_PX

Vec = tuple[float, float, float]
UP = (0.0, 0.0, 1.0)
ZERO = (0.0, 0.0, 0.0)

_jit = jit_inline


@_jit
def dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@_jit
def axpy(s: float, x: Vec, y: Vec) -> Vec:
    """s x + y."""
    return (s * x[0] + y[0], s * x[1] + y[1], s * x[2] + y[2])


@_jit
def scale(s: float, x: Vec) -> Vec:
    return (s * x[0], s * x[1], s * x[2])


@_jit
def add(a: Vec, b: Vec) -> Vec:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@_jit
def away_from_zero(x: float) -> float:
    """x with magnitudes below GRAZING raised to GRAZING, sign kept (see optics.away_from_zero)."""
    if abs(x) < GRAZING:
        return -GRAZING if x < 0.0 else GRAZING
    return x


@_jit
def passes(x: float) -> float:
    """Derivative of away_from_zero at x: 1 where it is the identity, else 0."""
    return 0.0 if abs(x) < GRAZING else 1.0


@_jit
def transfer(p: Vec, dpu: Vec, dpv: Vec, w: Vec, dwu: Vec, dwv: Vec, dist: float, n: Vec
             ) -> tuple[Vec, Vec, Vec]:
    """Move a photon ``dist`` along w onto a surface with normal n (optics.transfer):
    D p' = D p + dist D w + D dist w with D dist = -(D p + dist D w) . n / (w . n)."""
    mu = axpy(dist, dwu, dpu)
    mv = axpy(dist, dwv, dpv)
    den = away_from_zero(dot(w, n))
    return axpy(dist, w, p), axpy(-dot(mu, n) / den, w, mu), axpy(-dot(mv, n) / den, w, mv)


@_jit
def transfer_adjoint(dpu: Vec, dpv: Vec, w: Vec, dwu: Vec, dwv: Vec, dist: float, n: Vec,
                     g_p: Vec, g_dpu: Vec, g_dpv: Vec):
    """Adjoint of :func:`transfer`: (g_dpu, g_dpv, g_w, g_dwu, g_dwv, g_dist, g_n); the
    gradient w.r.t. p is g_p itself."""
    mu = axpy(dist, dwu, dpu)
    mv = axpy(dist, dwv, dpv)
    wn = dot(w, n)
    den = away_from_zero(wn)
    ddu = -dot(mu, n) / den
    ddv = -dot(mv, n) / den
    g_ddu = dot(g_dpu, w)
    g_ddv = dot(g_dpv, w)
    g_w = axpy(dist, g_p, axpy(ddu, g_dpu, scale(ddv, g_dpv)))
    g_mu = axpy(-g_ddu / den, n, g_dpu)
    g_mv = axpy(-g_ddv / den, n, g_dpv)
    g_n = axpy(-g_ddu / den, mu, scale(-g_ddv / den, mv))
    g_wn = -(g_ddu * ddu + g_ddv * ddv) / den * passes(wn)
    g_w = axpy(g_wn, n, g_w)
    g_n = axpy(g_wn, w, g_n)
    g_dist = dot(g_p, w) + dot(g_mu, dwu) + dot(g_mv, dwv)
    return g_mu, g_mv, g_w, scale(dist, g_mu), scale(dist, g_mv), g_dist, g_n


@_jit
def refract(w: Vec, dwu: Vec, dwv: Vec, n: Vec, dnu: Vec, dnv: Vec, eta: float):
    """Snell refraction with differentials (optics.refract), eta = n_incident / n_transmitted.
    Returns (w', D_u w', D_v w', cos_i, cos_t, k), k <= 0 meaning total internal reflection."""
    ci = -dot(w, n)
    k = 1.0 - eta * eta * (1.0 - ci * ci)
    ct = math.sqrt(max(k, 1e-12))
    a = eta * ci - ct
    dciu = -dot(dwu, n) - dot(w, dnu)
    dciv = -dot(dwv, n) - dot(w, dnv)
    bu = eta * dciu - eta * eta * ci * dciu / ct
    bv = eta * dciv - eta * eta * ci * dciv / ct
    return (axpy(a, n, scale(eta, w)), axpy(a, dnu, axpy(bu, n, scale(eta, dwu))),
            axpy(a, dnv, axpy(bv, n, scale(eta, dwv))), ci, ct, k)


@_jit
def _refract_differential_adjoint(w: Vec, dw: Vec, n: Vec, dn: Vec, eta: float, ci: float, ct: float,
                                  g_dw1: Vec, g_dw: Vec, g_dn: Vec, g_n: Vec, g_w: Vec, g_ci: float, g_ct: float):
    """Adjoint of the b-term of one refracted differential, b (n) with b = eta D cos_i - D cos_t,
    D cos_i = -(D w . n + w . D n), D cos_t = eta^2 cos_i D cos_i / cos_t: adds to and returns
    (g_dw, g_dn, g_n, g_w, g_ci, g_ct)."""
    e2 = eta * eta
    dci = -dot(dw, n) - dot(w, dn)
    dct = e2 * ci * dci / ct
    g_b = dot(g_dw1, n)
    g_n = axpy(eta * dci - dct, g_dw1, g_n)
    g_dct = -g_b
    g_dci = eta * g_b + g_dct * e2 * ci / ct
    g_ci += g_dct * e2 * dci / ct
    g_ct -= g_dct * dct / ct
    return (axpy(-g_dci, n, g_dw), axpy(-g_dci, w, g_dn), axpy(-g_dci, dw, g_n), axpy(-g_dci, dn, g_w),
            g_ci, g_ct)


@_jit
def refract_adjoint(w: Vec, dwu: Vec, dwv: Vec, n: Vec, dnu: Vec, dnv: Vec, eta: float,
                    g_w1: Vec, g_dwu1: Vec, g_dwv1: Vec, g_ci: float, g_ct: float):
    """Adjoint of :func:`refract`: (g_w, g_dwu, g_dwv, g_n, g_dnu, g_dnv)."""
    ci = -dot(w, n)
    k = 1.0 - eta * eta * (1.0 - ci * ci)
    ct = math.sqrt(max(k, 1e-12))
    a = eta * ci - ct
    e2 = eta * eta
    g_w = scale(eta, g_w1)
    g_a = dot(g_w1, n)
    g_n = scale(a, g_w1)
    g_dwu = scale(eta, g_dwu1)
    g_dwv = scale(eta, g_dwv1)
    g_dnu = scale(a, g_dwu1)
    g_dnv = scale(a, g_dwv1)
    g_a += dot(g_dwu1, dnu) + dot(g_dwv1, dnv)
    g_dwu, g_dnu, g_n, g_w, g_ci, g_ct = _refract_differential_adjoint(
        w, dwu, n, dnu, eta, ci, ct, g_dwu1, g_dwu, g_dnu, g_n, g_w, g_ci, g_ct)
    g_dwv, g_dnv, g_n, g_w, g_ci, g_ct = _refract_differential_adjoint(
        w, dwv, n, dnv, eta, ci, ct, g_dwv1, g_dwv, g_dnv, g_n, g_w, g_ci, g_ct)
    # a = eta cos_i - cos_t, cos_t = sqrt(max(k, 1e-12)), k = 1 - eta^2 (1 - cos_i^2), cos_i = -w . n
    g_ci += eta * g_a
    g_ct -= g_a
    g_k = 0.5 * g_ct / ct if k >= 1e-12 else 0.0
    g_ci += g_k * 2.0 * e2 * ci
    g_w = axpy(-g_ci, n, g_w)
    g_n = axpy(-g_ci, w, g_n)
    return g_w, g_dwu, g_dwv, g_n, g_dnu, g_dnv


@_jit
def fresnel(ci: float, ct: float, eta: float) -> float:
    """Unpolarised Fresnel power transmittance (optics.fresnel_transmittance)."""
    rs = (eta * ci - ct) / (eta * ci + ct)
    rp = (ci - eta * ct) / (ci + eta * ct)
    return 1.0 - 0.5 * (rs * rs + rp * rp)


@_jit
def fresnel_adjoint(ci: float, ct: float, eta: float, g_t: float) -> tuple[float, float]:
    """Adjoint of :func:`fresnel`: (g_cos_i, g_cos_t)."""
    ss = eta * ci + ct
    sp = ci + eta * ct
    g_rs = -g_t * (eta * ci - ct) / ss
    g_rp = -g_t * (ci - eta * ct) / sp
    g_ci = g_rs * 2.0 * eta * ct / (ss * ss) + g_rp * 2.0 * eta * ct / (sp * sp)
    g_ct = -g_rs * 2.0 * eta * ci / (ss * ss) - g_rp * 2.0 * eta * ci / (sp * sp)
    return g_ci, g_ct


@_jit
def height_field_normal(sx: float, sy: float) -> Vec:
    """Unit upward normal of z = S(x, y): (-S_x, -S_y, 1) / |.|."""
    inv = 1.0 / math.sqrt(1.0 + sx * sx + sy * sy)
    return (-sx * inv, -sy * inv, inv)


@_jit
def height_field_normal_adjoint(sx: float, sy: float, g_n: Vec) -> tuple[float, float]:
    """Adjoint of :func:`height_field_normal`: (g_sx, g_sy)."""
    inv = 1.0 / math.sqrt(1.0 + sx * sx + sy * sy)
    g_inv = -g_n[0] * sx - g_n[1] * sy + g_n[2]
    c = -g_inv * inv * inv * inv
    return -g_n[0] * inv + c * sx, -g_n[1] * inv + c * sy


@_jit
def normal_differential(sxx: float, sxy: float, syy: float, n: Vec, dp: Vec) -> Vec:
    """D n = (D m - n (n . D m)) n_z, D m = -(Hessian of S) D p_xy (optics.height_field_normal_differential)."""
    r = (-(sxx * dp[0] + sxy * dp[1]), -(sxy * dp[0] + syy * dp[1]), 0.0)
    return scale(n[2], axpy(-dot(r, n), n, r))


@_jit
def normal_differential_adjoint(sxx: float, sxy: float, syy: float, n: Vec, dp: Vec, g_dn: Vec):
    """Adjoint of :func:`normal_differential`: (g_sxx, g_sxy, g_syy, g_n, g_dp)."""
    r = (-(sxx * dp[0] + sxy * dp[1]), -(sxy * dp[0] + syy * dp[1]), 0.0)
    s = dot(r, n)
    q = axpy(-s, n, r)
    g_q = scale(n[2], g_dn)
    g_s = -dot(g_q, n)
    g_r = axpy(g_s, n, g_q)
    g_n = axpy(g_s, r, scale(-s, g_q))
    g_n = (g_n[0], g_n[1], g_n[2] + dot(g_dn, q))
    g_dp = (-g_r[0] * sxx - g_r[1] * sxy, -g_r[0] * sxy - g_r[1] * syy, 0.0)
    return -g_r[0] * dp[0], -g_r[0] * dp[1] - g_r[1] * dp[0], -g_r[1] * dp[1], g_n, g_dp


@_jit
def _bound(x: float) -> float:
    return min(max(x, -MAX_DIFFERENTIAL_PX), MAX_DIFFERENTIAL_PX)


@_jit
def _inside_bound(x: float) -> float:
    return 1.0 if -MAX_DIFFERENTIAL_PX <= x <= MAX_DIFFERENTIAL_PX else 0.0


@_jit
def footprint_metric(ux: float, uy: float, vx: float, vy: float, r0: float, rmax: float
                     ) -> tuple[float, float, float]:
    """Metric (q00, q01, q11) of the footprint spanned by Du = (ux, uy), Dv = (vx, vy) (pixels),
    as :func:`operators.splat.splat.footprint_metric`: cut-off at ``rmax``, ``r0`` added in quadrature."""
    ux, uy, vx, vy = _bound(ux), _bound(uy), _bound(vx), _bound(vy)
    b00 = ux * ux + vx * vx
    b01 = ux * uy + vx * vy
    b11 = uy * uy + vy * vy
    major = 0.5 * (b00 + b11) + math.sqrt(0.25 * (b00 - b11) ** 2 + b01 * b01 + 1e-300)
    r2 = r0 * r0
    s = min((rmax * rmax - r2) / max(major, 1e-300), 1.0)
    a00, a01, a11 = b00 * s, b01 * s, b11 * s
    det = max(a00 * a11 - a01 * a01, 0.0) + r2 * (a00 + a11) + r2 * r2
    return (a11 + r2) / det, -a01 / det, (a00 + r2) / det


@_jit
def footprint_metric_adjoint(ux: float, uy: float, vx: float, vy: float, r0: float, rmax: float,
                             g00: float, g01: float, g11: float) -> tuple[float, float, float, float]:
    """Adjoint of :func:`footprint_metric`: (g_ux, g_uy, g_vx, g_vy)."""
    mux, muy, mvx, mvy = _inside_bound(ux), _inside_bound(uy), _inside_bound(vx), _inside_bound(vy)
    ux, uy, vx, vy = _bound(ux), _bound(uy), _bound(vx), _bound(vy)
    b00 = ux * ux + vx * vx
    b01 = ux * uy + vx * vy
    b11 = uy * uy + vy * vy
    root = math.sqrt(0.25 * (b00 - b11) ** 2 + b01 * b01 + 1e-300)
    major = 0.5 * (b00 + b11) + root
    r2 = r0 * r0
    ratio = (rmax * rmax - r2) / max(major, 1e-300)
    s = min(ratio, 1.0)
    a00, a01, a11 = b00 * s, b01 * s, b11 * s
    e = a00 * a11 - a01 * a01
    det = max(e, 0.0) + r2 * (a00 + a11) + r2 * r2
    q00, q01, q11 = (a11 + r2) / det, -a01 / det, (a00 + r2) / det
    g_det = -(g00 * q00 + g01 * q01 + g11 * q11) / det
    pos = 1.0 if e >= 0.0 else 0.0
    g_a00 = g11 / det + g_det * (r2 + pos * a11)
    g_a11 = g00 / det + g_det * (r2 + pos * a00)
    g_a01 = -g01 / det - g_det * pos * 2.0 * a01
    g_b00, g_b01, g_b11 = s * g_a00, s * g_a01, s * g_a11
    if ratio <= 1.0 and major >= 1e-300:
        g_major = -(g_a00 * b00 + g_a01 * b01 + g_a11 * b11) * s / major
        half_diff = 0.25 * (b00 - b11) / root
        g_b00 += g_major * (0.5 + half_diff)
        g_b11 += g_major * (0.5 - half_diff)
        g_b01 += g_major * b01 / root
    return ((2.0 * ux * g_b00 + uy * g_b01) * mux, (2.0 * uy * g_b11 + ux * g_b01) * muy,
            (2.0 * vx * g_b00 + vy * g_b01) * mvx, (2.0 * vy * g_b11 + vx * g_b01) * mvy)
