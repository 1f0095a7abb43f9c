"""Limited-memory quasi-Newton directions for the proximal-gradient iteration (docs/method.md,
"Quasi-Newton steps").

The preconditioned gradient P grad f converges at the rate of the worst-conditioned direction
that P leaves: on sharp caustics (folds, narrow strokes) the line search keeps the step small for
the sake of a few stiff directions while the others crawl. L-BFGS (Nocedal 1980) learns the
curvature of the data term along the last k steps from the pairs

    s_i = x_{i+1} - x_i,    y_i = grad f(x_{i+1}) - grad f(x_i)

and applies an approximate inverse Hessian H with H_0 = gamma P (P the Sobolev preconditioner,
gamma = s^T y / y^T P y of the newest pair) by the two-loop recursion. The direction is returned
divided by gamma,

    direction = H grad f / gamma,

so that where the pairs know nothing it is P grad f, as without this module, and the step size
tau, the L1 prox's threshold tau alpha and the line search keep their meaning. The gradients of a
pair come from renders with the same photons (common random numbers); the memory is cleared
whenever the objective changes (photon budget, calibration, preconditioner stage). A pair with
s^T y <= 0 (no positive curvature along s, e.g. across a post-step heuristic) is not stored.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from operators.values import checked_whole

__all__ = ["LbfgsMemory", "check_quasi_newton"]


def check_quasi_newton(settings: Any) -> dict[str, int] | None:
    """``solver.quasi_newton`` ({memory: k >= 1, from_stage: s >= 0} or null) checked, with defaults
    memory 8 and from_stage 1."""
    if settings is None:
        return None
    if not isinstance(settings, Mapping) or set(settings) - {"memory", "from_stage"}:
        raise ValueError(f"solver.quasi_newton={settings!r} must be null or a map with keys memory (pairs kept, "
                         "e.g. 8) and from_stage (the preconditioner stage it starts at, e.g. 1)")
    out = {"memory": settings.get("memory", 8), "from_stage": settings.get("from_stage", 1)}
    for key, low in (("memory", 1), ("from_stage", 0)):
        out[key] = checked_whole(out[key], f"solver.quasi_newton.{key}", low)
    return out


class LbfgsMemory:
    """The last ``memory`` curvature pairs (s_i, y_i), each (m, m), and the two-loop recursion.

    Args:
        memory: Pairs kept (the oldest is dropped first).
    """

    def __init__(self, memory: int = 8) -> None:
        self.memory = checked_whole(memory, "quasi-Newton memory", 1)
        self.pairs: list[tuple[Tensor, Tensor, float]] = []  # (s, y, 1 / s^T y)
        self.gamma = 1.0

    def reset(self) -> None:
        """Forget every pair (the objective or the metric changed)."""
        self.pairs.clear()
        self.gamma = 1.0

    def update(self, s: Tensor, y: Tensor, precondition: Callable[[Tensor], Tensor], tolerance: float = 0.0) -> bool:
        """Store the pair (s, y) if s^T y > ``tolerance`` ||s|| ||y|| and set gamma = s^T y / y^T P y;
        returns whether it was stored."""
        sy = float(torch.sum(s * y))
        least = 0.0 if tolerance == 0.0 else tolerance * float(torch.sum(s * s)) ** 0.5 * float(torch.sum(y * y)) ** 0.5
        if not sy > least:
            return False
        ypy = float(torch.sum(y * precondition(y)))
        if not ypy > 0.0:
            return False
        self.pairs.append((s.detach().clone(), y.detach().clone(), 1.0 / sy))
        del self.pairs[:-self.memory]
        self.gamma = sy / ypy
        return True

    def direction(self, grad: Tensor, precondition: Callable[[Tensor], Tensor], free: Tensor | None = None) -> Tensor:
        """H grad / gamma (m, m) by the two-loop recursion with H_0 = gamma P; ``free`` (m, m, bool)
        restricts the recursion to those samples (the others get 0). Without pairs: P grad."""
        keep = (lambda x: x) if free is None else (lambda x: torch.where(free, x, torch.zeros_like(x)))
        q = keep(grad)
        alphas = []
        for s, y, rho in reversed(self.pairs):
            alpha = rho * float(torch.sum(keep(s) * q))
            q = q - alpha * keep(y)
            alphas.append(alpha)
        r = keep(precondition(q)) * self.gamma
        for (s, y, rho), alpha in zip(self.pairs, reversed(alphas)):
            beta = rho * float(torch.sum(keep(y) * r))
            r = r + (alpha - beta) * keep(s)
        return r / self.gamma

    def state_dict(self) -> dict[str, Any]:
        """The pairs and gamma (for checkpoints)."""
        return {"pairs": [(s, y, rho) for s, y, rho in self.pairs], "gamma": self.gamma}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`."""
        self.pairs = [(s, y, float(rho)) for s, y, rho in state.get("pairs", [])]
        self.gamma = float(state.get("gamma", 1.0))
