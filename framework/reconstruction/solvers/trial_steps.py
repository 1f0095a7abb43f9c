"""The trial steps a proximal-gradient iteration (framework/reconstruction/solvers/proximal_gradient.py)
tries before its line search: the momentum trials at the extrapolated point, and the first step
tested at the finished iterate (docs/method.md, "One proximal-gradient iteration"). Each is held
to the line search's sufficient decrease, F(trial) <= F(d) - c / (2 tau) ||x+ - d||^2 with x+ the
trial's proximal point, and returns (the accepted choice or None, forward evaluations spent).
``solver`` is the ProximalGradientSolver (not imported here: it imports this module)."""

from __future__ import annotations

from typing import Any
from collections.abc import Callable

import torch
from torch import Tensor

from framework.optimization.step_size import StepChoice

__all__ = ["Candidate", "extrapolated_trial", "finished_first_trial"]

Candidate = dict[str, Tensor]  # "d": the heights (m, m); "prox_point": the proximal point a trial moved from


def _decreases(solver: Any, trial: Candidate, tau: float, objective_now: float,
               sq_distance: Callable[[Candidate], float]) -> bool:
    """Whether F at ``trial`` passes the sufficient-decrease test of its step ``tau``."""
    decrease = float(solver.step_size.sufficient_decrease)
    return solver._objective(trial) <= objective_now - decrease / (2.0 * tau) * sq_distance(trial)


def extrapolated_trial(solver: Any, objective_now: float,
                       sq_distance: Callable[[Candidate], float]) -> tuple[StepChoice | None, int]:
    """The momentum trials: at each of the policy's momentum steps, the proximal point and the data
    term at its extrapolation, kept when it decreases F enough; when every trial is rejected the
    momentum restarts."""
    spent = 0
    for tau in solver.step_size.momentum_trials():
        candidate = solver._propose(tau)
        z = solver.momentum.extrapolate(candidate["d"], solver.state.d)
        if z is None:
            return None, spent
        trial = {**candidate, "d": solver._project(z), "prox_point": candidate["d"]}
        spent += 1
        if _decreases(solver, trial, tau, objective_now, sq_distance):
            solver.step_size.accepted_elsewhere(tau)
            return StepChoice(step=tau, candidate=trial, trials=spent, forward_evaluations=spent), spent
    solver.momentum.reset()
    return None, spent


def finished_first_trial(solver: Any, objective_now: float,
                         sq_distance: Callable[[Candidate], float]) -> tuple[StepChoice | None, int]:
    """The search's first step with the post steps applied (the finished iterate, marked
    ``finished``), kept when it decreases F enough: its render is then the next gradient's
    (framework/core/objective.py), where a step tested at its proximal point and then moved by a
    post step (V1, the volume hold) needs a render of its own. None when the test fails (the
    search goes on at the proximal points from the same step) or when the post steps leave the
    proximal point as it is (then nothing was rendered)."""
    tau = solver.step_size.current_step
    candidate = solver._propose(tau)
    finished = solver._finalize(candidate)
    if torch.equal(finished["d"], candidate["d"]):
        return None, 0
    trial = {**finished, "prox_point": candidate["d"], "finished": candidate["d"]}
    if not _decreases(solver, trial, tau, objective_now, sq_distance):
        return None, 1
    solver.step_size.accepted_elsewhere(tau)
    return StepChoice(step=tau, candidate=trial, trials=1, forward_evaluations=1), 1
