"""A solver plugin in one file: ``solver/exact_step``, one steepest-descent step with the exact
step length of a quadratic data term. For ``operator/shadow`` (U^T U = (n/m)^2 I) that one step is
the least-squares solution.

    [project.entry-points."shape_from_caustics.solver"]
    exact_step = "examples.plugins.exact_step_solver:ExactStepSolver"

Config ``examples/plugins/conf/solver/exact_step.yaml``; chosen with ``solver=exact_step``
(docs/plugins.md, "A newcomer's path").
"""

from __future__ import annotations

import time
from typing import Any

import torch

from framework.core.solver_loop import IterationRecord, IterativeSolver


class ExactStepSolver(IterativeSolver):
    """d = d0 - t g, g = grad f(d0), t = <r, J g> / ||J g||^2 (r = F(d0) - b, J g = F(d0 + g) - F(d0))."""

    name = "exact_step"

    def __init__(self, problem: Any, d0: torch.Tensor) -> None:
        super().__init__(d0)
        self.problem = problem

    @classmethod
    def from_config(cls):
        return cls

    def step(self) -> IterationRecord:
        t0 = time.perf_counter()
        fidelity, render, d = self.problem.fidelity, self.problem.operator.render, self.state.d
        g = fidelity.evaluate(d, with_grad=True).grad
        residual = render(d) - fidelity.target
        direction = render(d + g) - render(d)
        step = float((residual * direction).sum() / (direction * direction).sum())
        self.state.d = d - step * g
        after = fidelity.evaluate(self.state.d, with_grad=False)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        record = IterationRecord(self.state.iteration, after.value, after.value, after.rel_discrepancy, step,
                                 self.state.elapsed_s)
        self.history.append(record)
        return record

    def finished(self) -> str | None:
        return "one exact step minimises the quadratic data term" if self.iteration >= 1 else None
