"""Forward mode through the per-photon optics of :mod:`operators.optics.native`.

Every ``*_tangent`` function takes its forward function's inputs and their tangents (the changes
along one direction; a constant input has none) and returns the tangents of its outputs, with the
same clamps as the forward function and as its adjoint (``away_from_zero``, the floor under
cos_t, the footprint's bounds): where the adjoint cuts a gradient, the tangent is cut too, so the
Jacobian-vector product and the gradient are transposes of one another
(tests/operators/test_jvp.py). The small functions with few outputs (Fresnel's weight, the
footprint metric) take their rows from their adjoints.
"""

from __future__ import annotations

import math

from operators.kernels.numba_settings import jit_inline
from operators.optics.native import (Vec, add, away_from_zero, axpy, dot, footprint_metric_adjoint, fresnel_adjoint,
                                     passes, scale)

__all__ = ["footprint_metric_tangent", "fresnel_tangent", "height_field_normal_tangent",
           "normal_differential_tangent", "plane_distance_tangent", "refract_tangent", "transfer_tangent"]


@jit_inline
def height_field_normal_tangent(sx: float, sy: float, sx_d: float, sy_d: float) -> Vec:
    """Tangent of :func:`operators.optics.native.height_field_normal`."""
    inv = 1.0 / math.sqrt(1.0 + sx * sx + sy * sy)
    inv_d = -inv * inv * inv * (sx * sx_d + sy * sy_d)
    return (-sx_d * inv - sx * inv_d, -sy_d * inv - sy * inv_d, inv_d)


@jit_inline
def _moved_differential_tangent(dp: Vec, dw: Vec, dp_d: Vec, dw_d: Vec, w: Vec, n: Vec, dist: float, dist_d: float,
                                w_d: Vec, n_d: Vec, den: float, den_d: float) -> Vec:
    """Tangent of one transferred differential m - (m . n / den) w, m = D p + dist D w."""
    m = axpy(dist, dw, dp)
    m_d = add(dp_d, axpy(dist_d, dw, scale(dist, dw_d)))
    c = -dot(m, n) / den
    c_d = (-(dot(m_d, n) + dot(m, n_d)) - c * den_d) / den
    return add(m_d, axpy(c_d, w, scale(c, w_d)))


@jit_inline
def transfer_tangent(dpu: Vec, dpv: Vec, w: Vec, dwu: Vec, dwv: Vec, dist: float, n: Vec,
                     p_d: Vec, dpu_d: Vec, dpv_d: Vec, w_d: Vec, dwu_d: Vec, dwv_d: Vec, dist_d: float, n_d: Vec
                     ) -> tuple[Vec, Vec, Vec]:
    """Tangents (p', D_u p', D_v p') of :func:`operators.optics.native.transfer`."""
    wn = dot(w, n)
    den = away_from_zero(wn)
    den_d = passes(wn) * (dot(w_d, n) + dot(w, n_d))
    return (add(p_d, axpy(dist_d, w, scale(dist, w_d))),
            _moved_differential_tangent(dpu, dwu, dpu_d, dwu_d, w, n, dist, dist_d, w_d, n_d, den, den_d),
            _moved_differential_tangent(dpv, dwv, dpv_d, dwv_d, w, n, dist, dist_d, w_d, n_d, den, den_d))


@jit_inline
def plane_distance_tangent(w: Vec, n: Vec, dist: float, p_d: Vec, w_d: Vec) -> float:
    """Tangent of the distance dist = (c - p . n) / away_from_zero(w . n) along w from p to a
    fixed plane n . x = c."""
    wn = dot(w, n)
    return -(dot(p_d, n) + dist * passes(wn) * dot(w_d, n)) / away_from_zero(wn)


@jit_inline
def _refracted_differential_tangent(w: Vec, dw: Vec, n: Vec, dn: Vec, eta: float, ci: float, ct: float,
                                    ci_d: float, ct_d: float, a: float, a_d: float,
                                    w_d: Vec, dw_d: Vec, n_d: Vec, dn_d: Vec) -> Vec:
    """Tangent of one refracted differential a D n + b n + eta D w, b = eta D cos_i - D cos_t
    (:func:`operators.optics.native.refract`)."""
    e2 = eta * eta
    dci = -dot(dw, n) - dot(w, dn)
    dci_d = -dot(dw_d, n) - dot(dw, n_d) - dot(w_d, dn) - dot(w, dn_d)
    b = eta * dci - e2 * ci * dci / ct
    b_d = eta * dci_d - e2 * (ci_d * dci + ci * dci_d) / ct + e2 * ci * dci * ct_d / (ct * ct)
    return add(axpy(a_d, dn, scale(a, dn_d)), add(axpy(b_d, n, scale(b, n_d)), scale(eta, dw_d)))


@jit_inline
def refract_tangent(w: Vec, dwu: Vec, dwv: Vec, n: Vec, dnu: Vec, dnv: Vec, eta: float,
                    w_d: Vec, dwu_d: Vec, dwv_d: Vec, n_d: Vec, dnu_d: Vec, dnv_d: Vec):
    """Tangents (w', D_u w', D_v w', cos_i, cos_t) of :func:`operators.optics.native.refract`."""
    ci = -dot(w, n)
    ci_d = -dot(w_d, n) - dot(w, n_d)
    k = 1.0 - eta * eta * (1.0 - ci * ci)
    ct = math.sqrt(max(k, 1e-12))
    ct_d = eta * eta * ci * ci_d / ct if k >= 1e-12 else 0.0
    a = eta * ci - ct
    a_d = eta * ci_d - ct_d
    w1_d = add(axpy(a_d, n, scale(a, n_d)), scale(eta, w_d))
    dwu1_d = _refracted_differential_tangent(w, dwu, n, dnu, eta, ci, ct, ci_d, ct_d, a, a_d, w_d, dwu_d, n_d, dnu_d)
    dwv1_d = _refracted_differential_tangent(w, dwv, n, dnv, eta, ci, ct, ci_d, ct_d, a, a_d, w_d, dwv_d, n_d, dnv_d)
    return w1_d, dwu1_d, dwv1_d, ci_d, ct_d


@jit_inline
def normal_differential_tangent(sxx: float, sxy: float, syy: float, n: Vec, dp: Vec, sxx_d: float, sxy_d: float,
                                syy_d: float, n_d: Vec, dp_d: Vec) -> Vec:
    """Tangent of :func:`operators.optics.native.normal_differential`."""
    r = (-(sxx * dp[0] + sxy * dp[1]), -(sxy * dp[0] + syy * dp[1]), 0.0)
    r_d = (-(sxx_d * dp[0] + sxx * dp_d[0] + sxy_d * dp[1] + sxy * dp_d[1]),
           -(sxy_d * dp[0] + sxy * dp_d[0] + syy_d * dp[1] + syy * dp_d[1]), 0.0)
    s = dot(r, n)
    s_d = dot(r_d, n) + dot(r, n_d)
    q = axpy(-s, n, r)
    q_d = add(r_d, axpy(-s_d, n, scale(-s, n_d)))
    return axpy(n_d[2], q, scale(n[2], q_d))


@jit_inline
def fresnel_tangent(ci: float, ct: float, eta: float, ci_d: float, ct_d: float) -> float:
    """Tangent of :func:`operators.optics.native.fresnel` (its adjoint's row)."""
    g_ci, g_ct = fresnel_adjoint(ci, ct, eta, 1.0)
    return g_ci * ci_d + g_ct * ct_d


@jit_inline
def footprint_metric_tangent(ux: float, uy: float, vx: float, vy: float, r0: float, rmax: float,
                             ux_d: float, uy_d: float, vx_d: float, vy_d: float) -> tuple[float, float, float]:
    """Tangents (q00, q01, q11) of :func:`operators.optics.native.footprint_metric` (its adjoint's
    three rows)."""
    a = footprint_metric_adjoint(ux, uy, vx, vy, r0, rmax, 1.0, 0.0, 0.0)
    b = footprint_metric_adjoint(ux, uy, vx, vy, r0, rmax, 0.0, 1.0, 0.0)
    c = footprint_metric_adjoint(ux, uy, vx, vy, r0, rmax, 0.0, 0.0, 1.0)
    return (a[0] * ux_d + a[1] * uy_d + a[2] * vx_d + a[3] * vy_d,
            b[0] * ux_d + b[1] * uy_d + b[2] * vx_d + b[3] * vy_d,
            c[0] * ux_d + c[1] * uy_d + c[2] * vx_d + c[3] * vy_d)
