"""The paper's volume-conservation heuristic V1, eq. (8): a post-step update, not a prox."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from operators.values import checked_height_field, checked_number

from ._checks import checked_relative_tolerance
from .base import PostStepUpdate, RegularizerContext


def volume_band(ctx: RegularizerContext, v_eps: float, who: str) -> tuple[float, float]:
    """Sample-sum band [q1, q2] = [V (1 - v_eps) / a, V (1 + v_eps) / a] of the deposited volume.

    Args:
        ctx: Context with ``volume`` V (scene units^3) and ``pixel_area`` a (scene units^2).
        v_eps: Relative volume uncertainty in [0, 1).
        who: Registry name of the caller, for the error message.

    Returns:
        (q1, q2) in scene units (a sum of heights), 0 < q1 <= q2.
    """
    if ctx.volume is None:
        raise ValueError(f"{who} needs the deposited volume: set data.volume=... or use a ground truth")
    volume = float(ctx.volume)
    return volume * (1.0 - v_eps) / ctx.pixel_area, volume * (1.0 + v_eps) / ctx.pixel_area


class VolumeBand:
    """Mixin of the volume terms (V1, V2, the hold): the band [q1, q2] of the height sum, set up once
    from the context (:meth:`set_band`) and read as :attr:`band`. Needs ``ctx`` (a set-up
    :class:`regularizers.base._UsesContext`)."""

    _q: tuple[float, float] | None = None

    def set_band(self, ctx: RegularizerContext, v_eps: float, who: str,
                 bounds: tuple[float, float] | None = None) -> None:
        """The band of :func:`volume_band`; with ``bounds`` (p1, p2), refuse a band that heights within
        them on the mask cannot reach."""
        q1, q2 = volume_band(ctx, v_eps, who)
        if bounds is not None:
            p1, p2 = bounds
            n = int(ctx.mask.sum())
            if n * p1 > q2 or n * p2 < q1:
                raise ValueError(
                    f"{who}: the volume band [{q1:.6g}, {q2:.6g}] (sum of heights) is unreachable with {n} mask "
                    f"pixels and bounds [{p1}, {p2}] (reachable [{n * p1:.6g}, {n * p2:.6g}]); check volume, "
                    "pixel_area, mask and p2, and check data.volume's unit"
                )
        self._q = (q1, q2)

    @property
    def band(self) -> tuple[float, float]:
        """(q1, q2) in scene units (sum of heights)."""
        _ = self.ctx  # raises if not set up
        assert self._q is not None
        return self._q


def window_mean(d: torch.Tensor, radius: int) -> torch.Tensor:
    """dbar_j: mean of d over the (2r+1) x (2r+1) window around j, zero padding at the borders.

    The divisor is always (2r+1)^2, also at the borders. Shape, dtype, device of d (m, m).
    """
    k = 2 * radius + 1
    return F.avg_pool2d(d[None, None], kernel_size=k, stride=1, padding=radius, count_include_pad=True)[0, 0]


class VolumeHeuristic(VolumeBand, PostStepUpdate):
    """Eq. (8): push the total height sum v(d) = sum_j d_j back into [q1, q2].

    With q1 = V (1 - V_eps) / a, q2 = V (1 + V_eps) / a and dbar the local window mean
    (:func:`window_mean`), for j in the printed area N^ only:
        if v(d) <= q1:  d_j <- d_j + gamma dbar_j sin(pi v(d) / q1)
        if v(d) >= q2:  d_j <- d_j - gamma dbar_j sin(pi (v(d) / q2 - 1))
    and d is unchanged when q1 < v(d) < q2 or off the mask. The sine makes the correction slow
    at the start (v ~ 0) and near the band, fast in between. It is a heuristic from the paper,
    not the proximal map of any functional (for a convex alternative see ``volume_v2``);
    note that for v(d) > 2 q2 the sine changes sign, as in the paper.

    Args:
        gamma: Relative strength gamma >= 0 (official 0.1).
        v_eps: Relative volume uncertainty V_eps in [0, 1) (official 0.25).
        r_v: Window radius r_V >= 0 in pixels (official 2).
    """

    needs_volume = (
        True  # the run's checks refuse measured data without data.volume (framework/reconstruction/run_checks.py)
    )

    def __init__(self, gamma: float = 0.1, v_eps: float = 0.25, r_v: int = 2) -> None:
        self.gamma = checked_number(gamma, "gamma", least=0.0, unit="the heuristic strength", example="0.1 (the paper)")
        self.v_eps = checked_relative_tolerance(v_eps)
        if int(r_v) != r_v or int(r_v) < 0:
            raise ValueError(f"window radius r_v={r_v!r} must be a non-negative integer; the paper uses 2")
        self.r_v = int(r_v)

    def setup(self, ctx: RegularizerContext) -> None:
        """Store the context and compute the band [q1, q2]; requires ``ctx.volume``."""
        super().setup(ctx)
        self.set_band(ctx, self.v_eps, "volume_v1")

    def __call__(self, d: torch.Tensor) -> torch.Tensor:
        """Apply eq. (8) once; returns a new tensor of d's shape (m, m), dtype and device."""
        checked_height_field(d)
        mask = self._mask_for(d)
        q1, q2 = self.band
        v = float(d.sum())
        if v <= q1:
            factor = self.gamma * math.sin(math.pi * v / q1)
        elif v >= q2:
            factor = -self.gamma * math.sin(math.pi * (v / q2 - 1.0))
        else:
            return d.clone()
        return torch.where(mask, d + factor * window_mean(d, self.r_v), d)
