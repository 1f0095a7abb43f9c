"""The contract check of a representation plugin (framework/core/contracts/representation.py),
run on every registered one by tests/test_plugin_contracts.py."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from framework.core.contracts.violation import require
from framework.core.contracts.representation import Representation
from framework.core.problem import Problem

__all__ = ["check_representation"]


def check_representation(make: Callable[[Problem, torch.Tensor], Any], problem: Problem, trials: int = 3,
                         who: str = "representation") -> None:
    """A representation built for ``problem`` keeps its contract
    (framework/core/contracts/representation.py): shapes, a start inside its bounds that clipping
    leaves alone, stages over its parameters, and its vjp and prior gradient against central
    differences along random directions (the adjoint identity <J v, g> = <v, J^T g>), in double
    precision."""
    d0 = torch.zeros(problem.grid.shape, dtype=torch.float64)  # double: central differences of 1e-5
    rep = make(problem, d0)
    require(isinstance(rep, Representation), who, f"built {type(rep).__name__}, not a Representation")
    theta = rep.initial()
    require(tuple(theta.shape) == (rep.size,), who, f"initial() has shape {tuple(theta.shape)}, not ({rep.size},)")
    lower, upper = rep.bounds()
    require(bool(((lower <= theta) & (theta <= upper)).all()), who, "its start lies outside its bounds")
    require(torch.equal(rep.clipped(theta), theta), who, "clipping moves a start inside the bounds")
    require(tuple(rep.heights(theta).shape) == problem.grid.shape, who, "heights() do not have the grid's shape")
    scale = rep.scale()
    require(bool((scale > 0).all()), who, "scale() has a parameter of size <= 0")
    for mask in rep.stages():
        require(tuple(mask.shape) == (rep.size,) and mask.dtype == torch.bool, who, "a stage is not (p,) bool")
    generator = torch.Generator().manual_seed(0)
    for trial in range(trials):
        v = torch.randn(rep.size, generator=generator, dtype=theta.dtype) * scale
        g = torch.randn(problem.grid.shape, generator=generator, dtype=theta.dtype)
        eps = 1e-5
        moved = (rep.heights(theta + eps * v) - rep.heights(theta - eps * v)) / (2 * eps)
        lhs, rhs = float(torch.sum(moved * g)), float(torch.sum(v * rep.vjp(theta, g)))
        require(abs(lhs - rhs) <= 1e-5 * (abs(lhs) + abs(rhs)) + 1e-12, who,
                 f"<J v, g> = {lhs:.8g} by central differences but <v, J^T g> = {rhs:.8g} (trial {trial})")
        value_plus, value_minus = rep.prior(theta + eps * v)[0], rep.prior(theta - eps * v)[0]
        slope, along = (value_plus - value_minus) / (2 * eps), float(torch.sum(v * rep.prior(theta)[1]))
        require(abs(slope - along) <= 1e-4 * (abs(slope) + abs(along)) + 1e-10, who,
                 f"the prior's slope {slope:.8g} by central differences differs from its gradient's {along:.8g}")
