"""A stopping-rule plugin in one file: ``stopping/small_change``, stop once an iteration moves no
height sample by more than a tolerance.

    [project.entry-points."shape_from_caustics.stopping"]
    small_change = "examples.plugins.small_change_stopping:SmallChangeStopping"

Config ``examples/plugins/conf/stopping/small_change.yaml``; chosen with ``stopping=small_change``.
"""

from __future__ import annotations

import torch

from framework.core.contracts.stopping import StoppingRule
from framework.core.solver_loop import IterationRecord, IterativeSolver
from operators.values import checked_number


class SmallChangeStopping(StoppingRule):
    """Stop once an iteration moves no height sample by more than ``tolerance`` (scene units)."""

    def __init__(self, tolerance: float = 1e-6) -> None:
        self.tolerance = checked_number(tolerance, "stopping.small_change.tolerance", above=0.0, unit="scene units",
                                        example="1e-6")
        self.previous: torch.Tensor | None = None

    def on_start(self, solver: IterativeSolver) -> None:
        self.previous = solver.state.d.clone()

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> bool:
        change = float((solver.state.d - self.previous).abs().max())
        self.previous = solver.state.d.clone()
        if change <= self.tolerance:
            self.stop_reason = f"no height moved by more than {self.tolerance:g} in iteration {record.iteration}"
            return True
        return False
