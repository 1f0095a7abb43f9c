"""A stack of shots from flat glass: the nearest screen first (docs/method.md, "Several photos").

A near screen sees a gentle caustic that a run from flat glass fits; a far one sees the fine
detail, and from flat glass its strong caustic stalls the fit in the wrong basin. So a stack's run
from a start without the print's shape (flat glass) first fits the nearest shot alone, with the
run's own solver, stopping rules and photon budget, and the stack then goes on from those heights
at the solver's finest stage. With joint calibration of the gains, the first fit calibrates that
shot's gain (the geometry waits for the whole stack, which alone can tell it).
"""

from __future__ import annotations

import torch

from framework.core.contracts.stage import Solve
from framework.core.problem import Problem
from framework.core.solver_loop import Callback

__all__ = ["fit_first_shot"]


def fit_first_shot(problem: Problem, d0: torch.Tensor, solve: Solve, extra: list[Callback]
                   ) -> tuple[torch.Tensor, dict[str, float]]:
    """The heights (m, m) that fit the stack's ``data.first_fit_shot`` alone from ``d0`` by the
    run's own solver, stopping rules and photon budget (``solve``), and what that cost
    (``first_fit_*``: the shot, iterations, its discrepancy, renders, gradient passes,
    photon-traces); ``extra``: further callbacks of that run (its gain's calibration)."""
    index = problem.data.first_fit_shot
    if index is None:
        raise ValueError("a first fit needs data with a nearest shot (data.first_fit_shot)")
    shot = problem.shot(index)
    d, result = solve(shot, d0, f"shot {index} first", extra)
    fidelity = shot.fidelity
    return d, {
        "first_fit_shot": float(index),
        "first_fit_iterations": float(result.iterations),
        "first_fit_rel_discrepancy": fidelity.relative_discrepancy(shot.operator.render(d)),
        "first_fit_renders": float(fidelity.renders),
        "first_fit_gradient_passes": float(fidelity.gradient_passes),
        "first_fit_photon_traces": float(fidelity.photon_traces),
    }
