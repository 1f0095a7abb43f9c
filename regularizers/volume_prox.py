"""Beyond the paper: an exact, convex volume constraint V2 with its proximal map.

The heuristic V1 (eq. (8)) is not a proximal map, so the thresholded Landweber scheme loses
its convergence theory when it is used. V2 replaces it by the indicator of the slab
{q1 <= sum_{j in N^} d_j <= q2} added to the pixel regulariser of eq. (7), whose prox has a
closed form up to one scalar found by bisection.
"""

from __future__ import annotations

import math

import torch

from operators.values import checked_height_field, checked_number

from ._checks import checked_bounds, checked_relative_tolerance
from .base import Regularizer, RegularizerContext
from .shrinkage import clamp_on_mask, soft_shrink
from .volume_heuristic import VolumeBand


class VolumeSlabL1Bounds(VolumeBand, Regularizer):
    """R(d) = alpha ||d||_1 + iota_C(d) + iota_{q1 <= sum_{N^} d <= q2}(d).

    C = {p1 <= d_j <= p2 on N^, d_j = 0 on N°}; q1 = V (1 - V_eps)/a, q2 = V (1 + V_eps)/a
    (V deposited volume, a pixel area, both from the context).

    Proximal map (t = step, k = t alpha, n = |N^|):
        prox_{t R}(w)_j = clamp_[p1,p2](S(w_j - lambda, k)) on N^, 0 on N°,
    with a scalar lambda: 0 if the sum s(0) of the unshifted result already lies in [q1, q2];
    otherwise the root of s(lambda) = q2 (if s(0) > q2, lambda > 0) or s(lambda) = q1
    (if s(0) < q1, lambda < 0), where s(lambda) = sum_{N^} clamp_[p1,p2](S(w_j - lambda, k)).

    Derivation (KKT): the problem min_x t R(x) + 1/2 ||x - w||^2 is strongly convex with the
    affine slab constraint written as sum x <= q2 (multiplier mu2 >= 0) and -sum x <= -q1
    (mu1 >= 0); Slater's condition holds whenever the slab meets the box interior, and the
    constraints are affine anyway, so strong duality holds. With lambda = mu2 - mu1 the
    Lagrangian is separable: each x_j minimises t alpha |x_j| + iota_[p1,p2](x_j) +
    1/2 (x_j - w_j)^2 + lambda x_j = ... + 1/2 (x_j - (w_j - lambda))^2 + const, whose minimiser is
    the eq. (7) map of w_j - lambda (clamp after shrink, see ``pixel_step``). Complementary
    slackness: lambda > 0 only if sum x = q2, lambda < 0 only if sum x = q1, lambda = 0 if the sum
    is in the band. s(lambda) is continuous and non-increasing (each term is a composition of
    non-decreasing maps of w_j - lambda), from n p2 (lambda -> -inf) to n p1 (lambda -> +inf), so
    the root exists iff [q1, q2] meets [n p1, n p2], and bisection finds it; s is piecewise
    linear, so a final secant step on the bracket makes it exact up to rounding.

    Args:
        alpha: L1 weight alpha_p >= 0 (paper's pixel default 2e-3).
        p1: Lower height bound in scene units (official 0.0).
        p2: Upper height bound in scene units (official 0.3).
        v_eps: Relative volume uncertainty V_eps in [0, 1) (official 0.25).
        tol: Relative bracket width at which the bisection on lambda stops.
        max_iter: Maximum number of bisection steps.
    """

    length_keys = ("p1", "p2")  # may be given with a unit, e.g. '0.4 mm' (framework/core/plugin_config.py)

    needs_volume = (
        True  # the run's checks refuse measured data without data.volume (framework/reconstruction/run_checks.py)
    )

    has_prox = True
    smooth = False

    def __init__(
        self,
        alpha: float = 2e-3,
        p1: float = 0.0,
        p2: float = 0.3,
        v_eps: float = 0.25,
        tol: float = 1e-12,
        max_iter: int = 200,
    ) -> None:
        self.alpha = checked_number(alpha, "alpha", least=0.0, unit="the L1 weight alpha_p", example="2e-3 (the paper)")
        self.p1, self.p2 = checked_bounds(p1, p2)
        self.v_eps = checked_relative_tolerance(v_eps)
        self.tol = checked_number(tol, "tol", above=0.0, unit="a relative tolerance", example="1e-12")
        if int(max_iter) < 1:
            raise ValueError(f"max_iter={max_iter!r} must be >= 1; 200 bisection steps reach float64 precision")
        self.max_iter = int(max_iter)

    def setup(self, ctx: RegularizerContext) -> None:
        """Store the context, compute [q1, q2] and check that the constraints can be met."""
        super().setup(ctx)
        self.set_band(ctx, self.v_eps, "volume_v2", (self.p1, self.p2))

    def value(self, d: torch.Tensor, rtol: float = 1e-9) -> float:
        """alpha ||d||_1 if d meets bounds, mask and band (relative tolerance ``rtol``), else ``inf``."""
        checked_height_field(d)
        q1, q2 = self.band
        mask = self._mask_for(d)
        gap = float((d - clamp_on_mask(d, mask, self.p1, self.p2)).abs().max())
        total = float(d.sum())
        scale = rtol * max(1.0, abs(q2))
        if gap > rtol * max(1.0, abs(self.p2), abs(self.p1)) or total < q1 - scale or total > q2 + scale:
            return math.inf
        return self.alpha * float(d.abs().sum())

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """clamp_[p1,p2](S(d - lambda, step alpha)) on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        k = self._check_step(step) * self.alpha
        mask = self._mask_for(d)
        return clamp_on_mask(soft_shrink(d - self.shift(d, step), k), mask, self.p1, self.p2)

    def project(self, d: torch.Tensor) -> torch.Tensor:
        """The nearest point of the set where :meth:`value` is finite (bounds, mask and band): the
        prox without the l1 term, shape (m, m)."""
        checked_height_field(d)
        return clamp_on_mask(d - self._multiplier(d, 0.0), self._mask_for(d), self.p1, self.p2)

    def shift(self, d: torch.Tensor, step: float) -> float:
        """The multiplier lambda of the slab constraint for prox_{step R}(d) (0 inside the band)."""
        checked_height_field(d)
        return self._multiplier(d, self._check_step(step) * self.alpha)

    def _multiplier(self, d: torch.Tensor, k: float) -> float:
        """lambda with clamp(S(d - lambda, k)) summing into the band over the mask (0 inside it)."""
        w = d.detach().to(torch.float64)[self._mask_for(d)]  # only the printed samples enter the sum
        return slab_multiplier(w, k, self.p1, self.p2, self.band, self.tol, self.max_iter)


def slab_multiplier(w: torch.Tensor, k: float, p1: float, p2: float, band: tuple[float, float],
                    tol: float = 1e-12, max_iter: int = 200) -> float:
    """The scalar lambda with s(lambda) = sum clamp_[p1,p2](S(w - lambda, k)) in ``band`` = (q1, q2):
    0 if s(0) lies in it, else the root of s = q2 (lambda > 0) or s = q1 (lambda < 0), by bisection
    to the relative bracket width ``tol`` and a final secant step (s is piecewise linear and
    non-increasing). ``w``: the printed samples (1-D, float64); ``k``: the L1 threshold (0: none)."""
    q1, q2 = band

    def total(lam: float) -> float:
        return float(torch.clamp(soft_shrink(w - lam, k), p1, p2).sum())

    s0 = total(0.0)
    if q1 <= s0 <= q2:
        return 0.0
    if s0 > q2:  # s(lo) > target >= s(hi)
        target, lo, hi = q2, 0.0, float(w.max()) + k - p1
    else:  # s(lo) >= target > s(hi)
        target, lo, hi = q1, float(w.min()) - k - p2, 0.0
    s_lo, s_hi = total(lo), total(hi)
    for _ in range(max_iter):
        if hi - lo <= tol * (1.0 + abs(lo) + abs(hi)):
            break
        mid = 0.5 * (lo + hi)
        s_mid = total(mid)
        if s_mid > target:
            lo, s_lo = mid, s_mid
        else:
            hi, s_hi = mid, s_mid
    # s is piecewise linear: a secant step on the final bracket is exact when it holds one piece.
    if s_lo > s_hi:
        lam = lo + (s_lo - target) / (s_lo - s_hi) * (hi - lo)
        if q1 - 1e-12 * abs(q1) <= total(lam) <= q2 + 1e-12 * abs(q2):
            return lam
    return hi if target == q2 else lo
