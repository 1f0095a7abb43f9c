"""Nesterov momentum for the proximal-gradient iteration (docs/method.md, "Momentum in the later
stages"; what was measured with and without it: docs/performance.md, "Fewer photon-traces").

FISTA's extrapolation (Beck and Teboulle 2009) with adaptive restart (O'Donoghue and Candes
2015): the solver evaluates the data term at

    z+ = x+ + beta_k (x+ - x),      beta_k = (t_k - 1) / t_{k+1},   t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2,

where x+ is the proximal-gradient point computed from the current evaluation point z and x the
previous one. Momentum restarts (t = 1, no extrapolation on the next step) when the step turns
against the momentum, (z - x+) . (x+ - x) > 0 (the gradient test), and whenever the caller says
so (a rejected trial of the line search, a post-step heuristic that moved the iterate, a change of
preconditioner). For nonlinear ill-posed problems the same two-point scheme reaches the
discrepancy principle in far fewer iterations than Landweber's (Hubmer and Ramlau 2017).
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from framework.optimization.preconditioner import check_stage_index

__all__ = ["NesterovMomentum", "check_momentum_from"]


def check_momentum_from(stage: Any) -> int | None:
    """``solver.momentum_from`` as a preconditioner stage index >= 0, or None."""
    return check_stage_index(stage, "solver.momentum_from", "no momentum")


class NesterovMomentum:
    """The momentum state: FISTA's t and the previous proximal-gradient point x (m, m)."""

    def __init__(self) -> None:
        self.t = 1.0
        self.anchor: Tensor | None = None

    def reset(self) -> None:
        """Forget the previous point: the next step takes no momentum."""
        self.t = 1.0
        self.anchor = None

    def extrapolate(self, prox_point: Tensor, z: Tensor) -> Tensor | None:
        """z+ = x+ + beta (x+ - x) for the proximal-gradient point x+ (m, m) computed from the
        evaluation point z (m, m); None when no momentum applies (no previous point, t = 1, or
        the gradient test restarts it)."""
        anchor = self.anchor
        if anchor is None or self.t <= 1.0:
            return None
        if float(torch.sum((z - prox_point) * (prox_point - anchor))) > 0.0:
            self.t = 1.0
            return None
        beta = (self.t - 1.0) / self._next_t()
        return prox_point + beta * (prox_point - anchor)

    def _next_t(self) -> float:
        return 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * self.t * self.t))

    def accepted(self, point: Tensor, keep: bool) -> None:
        """Record the accepted step's proximal-gradient point x+ (m, m); ``keep`` False restarts
        the momentum at ``point`` (t = 1: the next step takes none, the ones after build it up)."""
        self.t = self._next_t() if keep else 1.0
        self.anchor = point.detach().clone()

    def state_dict(self) -> dict[str, Any]:
        """t and the previous point, for checkpoints."""
        return {"t": self.t, "anchor": self.anchor}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`."""
        self.t = float(state.get("t", 1.0))
        anchor = state.get("anchor")
        self.anchor = None if anchor is None else anchor.clone()
