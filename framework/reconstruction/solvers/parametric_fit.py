"""The solver ``parametric``: the parameters theta of a representation d = R(theta)
(framework/core/contracts/representation.py) fitted to the photo by projected L-BFGS.

Each iteration: the gradient J_R^T grad f(R(theta)) plus the representation's prior, an L-BFGS
direction in the representation's own metric (its scales) over the parameters the current stage
frees and that no bound holds, and Armijo backtracking along the projected path. When the fit
stalls (stopping.stagnation offers :meth:`ParametricFit.refine`), the next stage frees more
parameters (for tracks: the residual grid after the beads). Before the first step and at each stall
before the next stage, up to ``searches`` times in all, the representation's global search tries
other basins for the parts of the print the photo objects to most (framework/tracks/track_search.py)
and the fit goes on from what it kept.
The data term, the stopping rules, checkpoints and callbacks are those of every solver: only the
parameters differ (docs/method.md, "Representations").
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor

from framework.core.contracts.solver import SolverBuilder
from framework.core.objective import DataFidelity
from framework.core.plugin_config import build_plugin, split_name
from framework.core.solver_loop import IterationFailed, IterationRecord, IterativeSolver
from framework.core.pixel_noise import pixel_noise
from framework.optimization.quasi_newton import LbfgsMemory
from framework.optimization.step_size import LineSearchFailed, backtrack
from framework.core.contracts.representation import Representation, SearchContext
from operators.values import checked_number, checked_whole

__all__ = ["ParametricFit"]

ARMIJO = 1e-4
FIRST_MOVE = 0.05  # without curvature pairs, the first trial moves theta by this share of its scales at most

_LOG = logging.getLogger(__name__)


class ParametricFit(IterativeSolver):
    """Projected L-BFGS over a representation's parameters (module docstring).

    Args:
        data: The data term f.
        representation: d = R(theta), its bounds, scales, prior and stages.
        memory: L-BFGS pairs kept.
        halvings: Backtracking halvings at most per iteration.
        volume: The known deposited volume (scene units^3) with ``volume_weight`` > 0: a penalty
            volume_weight / 2 (V(d) / volume - 1)^2 / a, a share of the data term; None: none.
        cell_area: a, scene units^2.
        searches: Global searches at most (the first before the first step, then at stalls).
        receiver: (half width, pixels n) of the receiver, for the search's windows.
        delta: The data's noise level (the search's expected misfit per pixel).
    """

    name = "parametric"

    def __init__(self, data: DataFidelity, representation: Representation, memory: int = 10, halvings: int = 12,
                 volume: float | None = None, volume_weight: float = 0.0,
                 cell_area: float = 1.0, searches: int = 0, receiver: tuple[float, int] = (1.0, 1),
                 delta: float = 0.05) -> None:
        self.representation = representation
        self.theta = representation.clipped(representation.initial())
        super().__init__(representation.heights(self.theta))
        self.data, self.halvings = data, int(halvings)
        self.memory = LbfgsMemory(memory)
        self.lower, self.upper = representation.bounds()
        self.metric = representation.scale() ** 2
        self.masks = representation.stages()
        self.stage_index = 0
        self.volume, self.volume_weight, self.cell_area = volume, float(volume_weight), float(cell_area)
        self._at: tuple[float, Tensor, float] | None = None  # (objective, gradient, discrepancy) at theta
        self.searches, self.searched, self.receiver, self.delta = int(searches), 0, receiver, float(delta)
        self.search_changes: list[str] = []

    # -- the objective ---------------------------------------------------------------------------------
    def _volume_term(self, d: Tensor) -> tuple[float, Tensor | None]:
        if self.volume is None or self.volume_weight <= 0.0:
            return 0.0, None
        ratio = float(d.sum()) * self.cell_area / self.volume - 1.0
        grad_d = torch.full_like(d, self.volume_weight * ratio / self.volume)  # d/dd of w/2 ratio^2 / a
        return 0.5 * self.volume_weight * ratio**2 / self.cell_area, grad_d

    def _evaluate(self, theta: Tensor, with_grad: bool) -> tuple[float, Tensor | None, float]:
        d = self.representation.heights(theta)
        evaluation = self.data.evaluate(d, with_grad=with_grad)
        prior, prior_grad = self.representation.prior(theta)
        volume, volume_grad = self._volume_term(d)
        value = evaluation.value + prior + volume
        if not with_grad:
            return value, None, evaluation.rel_discrepancy
        assert evaluation.grad is not None
        grad_d = evaluation.grad if volume_grad is None else evaluation.grad + volume_grad
        return value, self.representation.vjp(theta, grad_d) + prior_grad, evaluation.rel_discrepancy

    # -- one iteration ---------------------------------------------------------------------------------
    def _free(self, grad: Tensor) -> Tensor:
        """The parameters the stage frees that no bound holds against the gradient's descent."""
        held = ((self.theta <= self.lower) & (grad > 0)) | ((self.theta >= self.upper) & (grad < 0))
        return self.masks[self.stage_index] & ~held

    def _direction(self, grad: Tensor, free: Tensor) -> tuple[Tensor, float]:
        """(descent direction, first trial step)."""
        precondition = self.metric.__mul__
        if self.memory.pairs:
            direction = -self.memory.gamma * self.memory.direction(grad, precondition, free)
            if float(torch.sum(direction * grad)) < 0.0:
                return direction, 1.0
            self.memory.reset()
        direction = -torch.where(free, self.metric * grad, torch.zeros_like(grad))
        largest = float(torch.max(torch.abs(direction) / self.metric.sqrt()))
        return direction, (FIRST_MOVE / largest if largest > 0.0 else 0.0)

    def step(self) -> IterationRecord:
        began = time.perf_counter()
        if self.iteration == 0 and self.searched == 0 and self.searches:  # the nominal print's basins first
            self.searched += 1
            self._search()
        if self._at is None:
            value, grad, _ = self._evaluate(self.theta, with_grad=True)
            assert grad is not None
            self._at = (value, grad, 0.0)
        value, grad, _ = self._at
        free = self._free(grad)
        direction, t = self._direction(grad, free)
        if t == 0.0:
            raise IterationFailed("the gradient vanishes on every free parameter")
        def evaluate(step: float) -> tuple[float, Tensor]:
            candidate = self.representation.clipped(self.theta + step * direction)
            return self._evaluate(candidate, with_grad=False)[0], candidate

        def bound(step: float, candidate: Tensor) -> float:  # Armijo along the projected path
            return value + ARMIJO * float(torch.sum(grad * (candidate - self.theta)))

        try:
            t, candidate, trials = backtrack(evaluate, bound, t, 0.5, self.halvings + 1)
        except LineSearchFailed as failed:
            self.memory.reset()
            raise IterationFailed(str(failed)) from None
        moved = candidate - self.theta
        new_value, new_grad, discrepancy = self._evaluate(candidate, with_grad=True)
        assert new_grad is not None
        self.memory.update(moved, new_grad - grad, self.metric.__mul__, tolerance=1e-10)
        self.theta, self._at = candidate, (new_value, new_grad, discrepancy)
        self.state.d = self.representation.heights(candidate)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - began
        record = IterationRecord(iteration=self.iteration, objective=new_value, data_fidelity=new_value,
                                 rel_discrepancy=discrepancy, step_size=t, elapsed_s=self.state.elapsed_s,
                                 extras={"trials": float(trials), "stage": float(self.stage_index)})
        self.history.append(record)
        return record

    def refine(self, d: Tensor) -> bool:
        """The fit stalled (stopping.stagnation): first the representation's global search, up to
        ``searches`` times, then its next stage; False when neither changes anything. The fit goes
        on from the current parameters (heights ``d`` cannot be mapped back onto them)."""
        while self.searched < self.searches:
            self.searched += 1
            if self._search():
                return True
        if self.stage_index + 1 < len(self.masks):
            self.stage_index += 1
            self.memory.reset()
            return True
        return False

    def _search(self) -> bool:
        """The representation's global search from theta; whether it changed theta."""
        target, weights = self.data.target, self.data.weights
        unit = 0.5 / (self.data.target_norm_sq * self.data.cell_area)  # a squared residual's share of the data term
        noise = unit * pixel_noise(target, self.delta, weights) ** 2 * target.shape[0]  # channels summed

        def pixel_misfit(theta: Tensor) -> np.ndarray:
            image = self.data.evaluate(self.representation.heights(theta), with_grad=False).image
            squared = (image - target.to(image)) ** 2
            if weights is not None:
                squared = squared * weights.to(squared)
            return unit * squared.sum(dim=0).reshape(-1).detach().cpu().double().numpy()

        def penalty(theta: Tensor) -> float:
            return self.representation.prior(theta)[0] + self._volume_term(self.representation.heights(theta))[0]

        context = SearchContext(lambda theta: self._evaluate(theta, with_grad=False)[0], pixel_misfit, penalty,
                                noise, self.receiver[0], self.receiver[1], self.searched - 1)
        theta, changes = self.representation.search(self.theta, context)
        self.search_changes += changes
        _LOG.info("global search %d: %s", self.searched, "; ".join(changes) if changes else "nothing changed")
        if not changes:
            return False
        self.theta, self._at = theta, None
        self.state.d = self.representation.heights(theta)
        self.memory.reset()
        return True

    def stage(self) -> int:
        return self.stage_index

    def setup_changed(self) -> None:
        self.memory.reset()
        self._at = None

    def set_heights(self, d: Tensor) -> None:
        raise ValueError("solver parametric fits its representation's parameters and cannot take heights from "
                         "outside (joint calibration of the screen distance); calibrate with solver=landweber_pixel")

    def run_metrics(self) -> dict[str, Any]:
        return {**self.representation.summary(self.theta), "stage_reached": self.stage_index,
                "search_changes": len(self.search_changes)}

    def fitted(self) -> tuple[Representation, Tensor]:
        """The representation and its parameters at the current iterate."""
        return self.representation, self.theta.detach().clone()

    # -- checkpoints -----------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "theta": self.theta, "memory": self.memory.state_dict(),
                "stage_index": self.stage_index, "searched": self.searched,
                "search_changes": list(self.search_changes)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.theta = state["theta"].to(self.theta)
        self.memory.load_state_dict(state["memory"])
        self.stage_index = int(state["stage_index"])
        self.searched = int(state["searched"])
        self.search_changes = list(state["search_changes"])
        self._at = None

    # -- the plugin ------------------------------------------------------------------------------------
    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py)."""
        return {"representation": {"name": "pixels"}}

    @classmethod
    def from_config(cls, representation: Mapping[str, Any], memory: int = 10, halvings: int = 12,
                    volume_weight: float = 0.0, searches: int = 0) -> SolverBuilder:
        """The plugin ``solver/parametric``: ``representation`` ({name, **its keys}, kind
        ``representation``) and the L-BFGS settings (class docstring)."""
        name, params = split_name(representation, "solver.representation")
        make = build_plugin("representation", name, params, "solver.representation")
        checked_whole(memory, "solver.memory", 1)
        checked_whole(halvings, "solver.halvings", 1)
        checked_number(volume_weight, "solver.volume_weight", 0.0)
        checked_whole(searches, "solver.searches", 0)

        def build(problem: Any, d0: Tensor) -> ParametricFit:
            receiver = (problem.scene.receiver.half_width, int(problem.operator.output_shape[-1]))
            return cls(problem.fidelity, make(problem, d0.to(problem.operator.dtype)), memory, halvings,
                       problem.data.volume, volume_weight, problem.grid.cell_area, searches, receiver,
                       problem.data.delta)

        return build
