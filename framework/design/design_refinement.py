"""Caustic-design solvers on the differentiable operator (docs/design.md): the plugins
``design/design_lbfgs`` (the refinement of ``sfc-design``) and ``design/design_adam`` (the baseline
of the Mitsuba 3 caustics tutorial: Adam on the heights from flat glass).

Both minimise the design objective

    J(d) = f(d) + weight * P(d),

f the problem's data term (1/2 ||F(d) - b||^2 / (||b||^2 a), framework/core/objective.py) against
the energy-normalised target, P the printing limits' squared relative violations
(:meth:`framework.design.print_constraints.PrintConstraints.penalty`; none on a problem without limits). The
limits hold exactly only
after the design pipeline's final projection (framework/design/design_run.py); the penalty keeps
that projection small.

``design_lbfgs`` is limited-memory BFGS (Nocedal and Wright, Algorithm 7.4) with a backtracking
Armijo line search: one operator render and gradient per trial, the accepted trial's evaluation
reused by the next iteration. The first step moves the heights by at most ``first_step`` (scene
units). With ``adam_steps`` > 0 its first iterations are that many Adam steps of ``adam_lr``
(as ``design_adam``'s): fixed steps move light across a stiff objective where the line search
from flat glass creeps. ``design_adam`` is Adam (Kingma and Ba 2015) with learning rate ``lr`` (scene units per
step), the heights clipped to [0, max_height] after every step as in the tutorial.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from framework.core.image_metrics import ssim_tensor
from framework.core.solver_loop import IterationFailed, IterationRecord, IterativeSolver
from framework.optimization.preconditioner import SobolevPreconditioner
from framework.optimization.quasi_newton import LbfgsMemory
from framework.optimization.step_size import LineSearchFailed, backtrack
from framework.design.print_constraints import printing_limits
from operators.values import checked_number, checked_whole

if TYPE_CHECKING:
    from framework.core.problem import Problem

__all__ = ["DesignAdam", "DesignLBFGS"]

ARMIJO_C1 = 1e-4
MAX_BACKTRACKS = 10
PAIR_TOLERANCE = 1e-12  # a curvature pair is kept where s^T y > this x ||s|| ||y|| (positive curvature)
LOSSES = ("l2", "hellinger", "l2_ssim")
SSIM_WEIGHT = 0.05  # w of the l2_ssim data term
HELLINGER_FLOOR = 1e-3  # added to both images under the square roots, as a fraction of the target's peak


def _hellinger(problem: Problem, d: Tensor) -> tuple[float, Tensor, float]:
    """(h, grad h, relative discrepancy) at d: h = 1/2 sum (sqrt(F + e) - sqrt(b + e))^2 / (sum b a),
    e = HELLINGER_FLOOR max b, a the cell area (the Hellinger distance of the two light
    distributions: light astray costs its power however thinly it is spread)."""
    operator, target = problem.operator, problem.fidelity.target
    image = operator.render(d).detach()
    b = target.to(image)
    floor = HELLINGER_FLOOR * float(b.max())
    root_f, root_b = torch.sqrt(image.clamp(min=0.0) + floor), torch.sqrt(b.clamp(min=0.0) + floor)
    scale = 1.0 / (float(b.clamp(min=0.0).sum()) * problem.fidelity.cell_area)
    value = 0.5 * float(((root_f - root_b) ** 2).sum()) * scale
    grad = operator.vjp(d, (0.5 * scale * (root_f - root_b) / root_f).to(image.dtype))
    relative = float(torch.linalg.vector_norm(image - b) / torch.linalg.vector_norm(b))
    return value, grad.double(), relative


def _l2_ssim(problem: Problem, d: Tensor, ssim_weight: float) -> tuple[float, Tensor, float]:
    """(f, grad f, relative discrepancy) at d: f = [1/2 ||F - b||^2 / ||b||^2 + w (1 - SSIM(F, b))] / a,
    w = ``ssim_weight``, SSIM the measure a design is scored by (framework/core/image_metrics.py), a
    the cell area: the L2 term with the structure's similarity beside it, which counts faint light
    on black as the score does."""
    operator, target = problem.operator, problem.fidelity.target
    image = operator.render(d).detach()
    b = target.to(torch.float64)
    x = image.to(torch.float64, copy=True).requires_grad_(True)
    scale = 1.0 / problem.fidelity.cell_area
    value = scale * (0.5 * ((x - b) ** 2).sum() / (b * b).sum() + ssim_weight * (1.0 - ssim_tensor(x, b)))
    (grad_image,) = torch.autograd.grad(value, x)
    grad = operator.vjp(d, grad_image.to(image.dtype))
    relative = float(torch.linalg.vector_norm(image.double() - b) / torch.linalg.vector_norm(b))
    return float(value.detach()), grad.double(), relative


def _adam_step(objective: _DesignObjective, adam: torch.optim.Adam, heights: torch.nn.Parameter, d: Tensor
               ) -> tuple[tuple[float, Tensor, float, float], Tensor]:
    """One Adam step on ``heights`` (the optimiser's parameter, holding d): the evaluation
    (J, grad J, f, relative discrepancy) at d and the new heights, clipped to [0, max_height]."""
    evaluation = objective(d)
    heights.grad = evaluation[1]
    adam.step()
    with torch.no_grad():
        limits = printing_limits(objective.problem)
        heights.clamp_(min=0.0, max=None if limits is None else limits.max_height)
    return evaluation, heights.detach().to(d.dtype).clone()



class _DesignObjective:
    """J(d) = f(d) + weight P(d) with its gradient, the rendered image and the data term apart; f
    the problem's data term (``loss="l2"``), the Hellinger term :func:`_hellinger` or the L2 and
    SSIM term :func:`_l2_ssim` (``ssim_weight``)."""

    def __init__(self, problem: Problem, weight: float, loss: str = "l2", ssim_weight: float = 0.0) -> None:
        self.problem, self.weight, self.loss, self.ssim_weight = problem, weight, loss, ssim_weight

    def __call__(self, d: Tensor) -> tuple[float, Tensor, float, float]:
        """(J, grad J, f, relative discrepancy) at d."""
        if self.loss == "hellinger":
            data_value, data_grad, relative = _hellinger(self.problem, d)
        elif self.loss == "l2_ssim":
            data_value, data_grad, relative = _l2_ssim(self.problem, d, self.ssim_weight)
        else:
            evaluation = self.problem.fidelity.evaluate(d, with_grad=True)
            data_value, data_grad, relative = evaluation.value, evaluation.grad.double(), evaluation.rel_discrepancy
        limits = printing_limits(self.problem)
        if limits is None:  # a problem without printing limits (a reconstruction): the data term alone
            return data_value, data_grad, data_value, relative
        x = d.detach().double().requires_grad_(True)
        penalty = limits.penalty(x)
        (grad_penalty,) = torch.autograd.grad(penalty, x)
        value = data_value + self.weight * float(penalty.detach())
        grad = data_grad + self.weight * grad_penalty
        return value, grad, data_value, relative


class DesignLBFGS(IterativeSolver):
    """L-BFGS on the design objective (module docstring).

    Args:
        problem: The design problem (its constraints set).
        d0: Start heights (m, m), e.g. the transport design.
        memory: Curvature pairs kept.
        penalty_weight: ``weight`` of the printing limits' penalty.
        first_step: Largest height change of the first step, scene units.
        smoothing_length: With a length (scene units), the initial inverse Hessian is the Sobolev
            smoothing (I - l^2 Laplace)^-2 (framework/optimization/preconditioner.py) instead of
            the identity: broad corrections first, as for a start far from the design.
        loss: The data term: ``l2`` (the problem's, 1/2 ||F(d) - b||^2 / (||b||^2 a)),
            ``hellinger`` (:func:`_hellinger`) or ``l2_ssim`` (:func:`_l2_ssim`).
        ssim_weight: The SSIM term's weight w of ``l2_ssim``.
        adam_steps: Adam steps before the first L-BFGS iteration (0: none).
        adam_lr: Their learning rate, scene units per step.
    """

    name = "design_lbfgs"

    def __init__(self, problem: Problem, d0: Tensor, memory: int = 12, penalty_weight: float = 10.0,
                 first_step: float = 2e-3, smoothing_length: float | None = None, loss: str = "l2",
                 adam_steps: int = 0, adam_lr: float = 2e-4, ssim_weight: float = SSIM_WEIGHT) -> None:
        super().__init__(d0)
        self.objective = _DesignObjective(problem, penalty_weight, loss, ssim_weight)
        self.adam_steps, self.adam_lr = adam_steps, adam_lr
        self._heights = torch.nn.Parameter(self.state.d.detach().double().clone())
        self._adam = torch.optim.Adam([self._heights], lr=adam_lr)
        self._smooth = None
        if smoothing_length is not None:
            self._smooth = SobolevPreconditioner(smoothing_length)
            self._smooth.setup(problem.context)
        self.first_step = first_step
        self._lbfgs = LbfgsMemory(memory)
        self._current: tuple[float, Tensor, float, float] | None = None

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py): from flat glass, far
        from the known problem's bump, broad corrections first."""
        return {"first_step": 5e-3, "smoothing_length": 0.25}

    @classmethod
    def from_config(cls, memory: int = 12, penalty_weight: float = 10.0, first_step: float = 2e-3,
                    smoothing_length: float | None = None, loss: str = "l2", adam_steps: int = 0,
                    adam_lr: float = 2e-4, ssim_weight: float = SSIM_WEIGHT) -> Any:
        """The plugin ``design/design_lbfgs``: checks the settings, returns the builder."""
        memory = checked_whole(memory, "solver.memory", least=1)
        weight = checked_number(penalty_weight, "solver.penalty_weight", above=0.0, must="must be a number > 0")
        step = checked_number(first_step, "solver.first_step", above=0.0, must="must be a number > 0")
        length = None if smoothing_length is None else checked_number(
            smoothing_length, "solver.smoothing_length", above=0.0, must="must be a number > 0")
        if loss not in LOSSES:
            raise ValueError(f"solver.loss={loss!r} must be one of {', '.join(LOSSES)}")
        adam_steps = checked_whole(adam_steps, "solver.adam_steps", 0,
                                   must="must be a whole number >= 0 (0: L-BFGS from the start)")
        lr = checked_number(adam_lr, "solver.adam_lr", above=0.0, must="must be a number > 0")
        similarity = checked_number(ssim_weight, "solver.ssim_weight", above=0.0, must="must be a number > 0")
        return lambda problem, d0: cls(problem, d0, memory, weight, step, length, loss, adam_steps, lr, similarity)

    def _initial_metric(self, x: Tensor) -> Tensor:
        """H_0 / gamma applied to x: the Sobolev smoothing, or the identity without one."""
        return x if self._smooth is None else self._smooth(x)

    def _direction(self, grad: Tensor) -> Tensor:
        """-H grad (m, m): the L-BFGS recursion over the kept pairs with H_0 = gamma P
        (framework/optimization/quasi_newton.py)."""
        return -self._lbfgs.gamma * self._lbfgs.direction(grad, self._initial_metric)

    def step(self) -> IterationRecord:
        """One L-BFGS iteration: direction, backtracking until Armijo holds, pair update (an Adam
        step while fewer than ``adam_steps`` iterations are done)."""
        t0 = time.perf_counter()
        if self.state.iteration < self.adam_steps:
            evaluation, self.state.d = _adam_step(self.objective, self._adam, self._heights, self.state.d)
            return self._record(evaluation, self.adam_lr, 1, t0)
        d = self.state.d.double()
        if self._current is None:
            self._current = self.objective(self.state.d)
        value, grad, _, _ = self._current
        direction = self._direction(grad)
        slope = float((grad * direction).sum())
        if not slope < 0.0:  # not a descent direction: forget the curvature and start afresh
            self._lbfgs.reset()
            direction = self._direction(grad)
            slope = float((grad * direction).sum())
        tau = 1.0 if self._lbfgs.pairs else self.first_step / max(float(direction.abs().max()), 1e-300)

        def evaluate(step: float) -> tuple[float, tuple[Tensor, Any]]:
            candidate = (d + step * direction).to(self.state.d.dtype)
            evaluation = self.objective(candidate)
            return evaluation[0], (candidate, evaluation)

        try:
            tau, (candidate, trial), trials = backtrack(evaluate, lambda step, _: value + ARMIJO_C1 * step * slope,
                                                        tau, 0.5, MAX_BACKTRACKS)
        except LineSearchFailed as failed:
            raise IterationFailed(f"no decrease along the L-BFGS direction: {failed}") from None
        self._lbfgs.update(candidate.double() - d, trial[1] - grad, self._initial_metric, PAIR_TOLERANCE)
        self.state.d, self._current = candidate, trial
        return self._record(trial, tau, trials, t0)

    def _record(self, evaluation: tuple[float, Tensor, float, float], tau: float, trials: int, t0: float
                ) -> IterationRecord:
        value, _, data_term, rel = evaluation
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        record = IterationRecord(self.state.iteration, value, data_term, rel, tau, self.state.elapsed_s,
                                 {"evaluations": float(trials), "penalty": (value - data_term) / self.objective.weight})
        self.history.append(record)
        return record

    def setup_changed(self) -> None:  # noqa: D102
        self._lbfgs.reset()
        self._current = None

    def set_heights(self, d: Tensor) -> None:  # noqa: D102
        super().set_heights(d)
        with torch.no_grad():
            self._heights.copy_(self.state.d.double())

    def state_dict(self) -> dict[str, Any]:
        """Adds the curvature pairs and the Adam steps' moments."""
        return {**super().state_dict(), "quasi_newton": self._lbfgs.state_dict(), "adam": self._adam.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        super().load_state_dict(state)
        self._lbfgs.reset()
        if "quasi_newton" in state:
            self._lbfgs.load_state_dict(state["quasi_newton"])
        for s, y in state.get("pairs", []):  # a checkpoint that kept the pairs alone
            self._lbfgs.update(s.double(), y.double(), self._initial_metric, PAIR_TOLERANCE)
        self._current = None
        with torch.no_grad():
            self._heights.copy_(self.state.d.double())
        if "adam" in state:
            self._adam.load_state_dict(state["adam"])


class DesignAdam(IterativeSolver):
    """Adam on the heights, clipped to [0, max_height] after every step (module docstring). An
    iteration's record holds the figures of the heights its step started from (one evaluation a step).

    Args:
        problem: The design problem (its constraints set).
        d0: Start heights (m, m) (the baseline starts from flat glass, zeros).
        lr: Adam's learning rate, scene units per step.
        penalty_weight: ``weight`` of the printing limits' penalty.
    """

    name = "design_adam"
    contract_iterations = 400  # steps of lr each: the known problem of the contract checks needs ~300

    def __init__(self, problem: Problem, d0: Tensor, lr: float = 2e-4, penalty_weight: float = 10.0) -> None:
        super().__init__(d0)
        self.objective = _DesignObjective(problem, penalty_weight)
        self.lr = lr
        self._heights = torch.nn.Parameter(self.state.d.detach().double().clone())
        self._adam = torch.optim.Adam([self._heights], lr=lr)

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py): steps of 5e-4 toward
        the known problem's 0.05-high bump (halved discrepancy after 300 steps, 0.063 -> 0.031)."""
        return {"lr": 5e-4}

    @classmethod
    def from_config(cls, lr: float = 2e-4, penalty_weight: float = 10.0) -> Any:
        """The plugin ``design/design_adam``: checks the settings, returns the builder."""
        lr = checked_number(lr, "solver.lr", above=0.0, must="must be a number > 0")
        weight = checked_number(penalty_weight, "solver.penalty_weight", above=0.0, must="must be a number > 0")
        return lambda problem, d0: cls(problem, d0, lr, weight)

    def step(self) -> IterationRecord:
        """One Adam step from the gradient at the current heights."""
        t0 = time.perf_counter()
        (value, _, data_term, rel), self.state.d = _adam_step(self.objective, self._adam, self._heights, self.state.d)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        record = IterationRecord(self.state.iteration, value, data_term, rel, self.lr, self.state.elapsed_s,
                                 {"penalty": (value - data_term) / self.objective.weight})
        self.history.append(record)
        return record

    def set_heights(self, d: Tensor) -> None:  # noqa: D102
        super().set_heights(d)
        with torch.no_grad():
            self._heights.copy_(self.state.d.double())

    def state_dict(self) -> dict[str, Any]:
        """Adds Adam's moments."""
        return {**super().state_dict(), "adam": self._adam.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        super().load_state_dict(state)
        with torch.no_grad():
            self._heights.copy_(self.state.d.double())
        if "adam" in state:
            self._adam.load_state_dict(state["adam"])
