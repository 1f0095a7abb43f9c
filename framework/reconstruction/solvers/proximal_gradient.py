"""The one proximal-gradient iteration (docs/method.md, "One proximal-gradient iteration"); M1 and
M2 are configurations of it (framework/reconstruction/solvers/pixel_methods.py), M3 a wavelet variant
(framework/reconstruction/solvers/wavelet_landweber.py).

One iteration from d (with g = sum of the regularisers, P = their proxes applied in list order):

    d+ = P(d - tau K grad f(d), tau)          (the step-size policy picks tau; K = I or a preconditioner)
    d+ = u_K(... u_1(d+))                     (post-step updates, e.g. the volume heuristic V1)
    evaluate f, grad f at d+                  (one gradient evaluation per iteration)

M1 ``gradient_descent``: no regulariser (P = identity). M2 ``landweber_pixel``, eq. (4)-(7):
regularisers e.g. [L1 with alpha_p, bounds [p1, p2] with mask]. Applying the proxes one after
the other equals the prox of the sum for the paper's separable choices (shrink, then clamp to
[p1, p2], then zero off the mask); for other combinations it is a splitting heuristic.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping
from typing import Any
from collections.abc import Sequence

import torch
from torch import Tensor

from framework.core.objective import DataEvaluation, DataFidelity
from framework.core.solver_loop import IterationFailed, IterationRecord, IterativeSolver
from framework.optimization.preconditioner import GradientPreconditioner
from framework.optimization.quasi_newton import LbfgsMemory, check_quasi_newton
from framework.optimization.step_size import LineSearchFailed, StepSizePolicy, as_step_policy
from framework.reconstruction.solvers.momentum import NesterovMomentum, check_momentum_from
from framework.reconstruction.solvers.proximal_parts import (check_post_steps, check_regularizers,
                                                             check_shaped_start_from, check_two_metric_from)
from framework.reconstruction.solvers.trial_steps import Candidate, extrapolated_trial, finished_first_trial

__all__ = ["ProximalGradientSolver", "stage_changes"]


def stage_changes(history: Sequence[IterationRecord]) -> list[int]:
    """Iterations after which the preconditioner moved to its next length, whether the stagnation
    rule or a failed line search asked for it (from the records' ``preconditioner_length``)."""
    lengths = [(r.iteration, r.extras.get("preconditioner_length")) for r in history]
    return [i for (i, a), (_, b) in zip(lengths, lengths[1:]) if a is not None and b is not None and a != b]


class ProximalGradientSolver(IterativeSolver):
    """Generic proximal gradient with post-step updates; M1, M2 and M3 specialise it.

    Args:
        data: The data term f (:class:`framework.core.objective.DataFidelity`).
        d0: Initial height field (m, m) (the paper starts from zeros).
        step_size: A :class:`StepSizePolicy`, or a number for a constant step.
        regularizers: Regularisers with ``value(d)`` and ``prox(d, step)``, applied in order.
        post_steps: Heuristic updates ``u(d) -> d`` applied after the prox, in order.
        preconditioner: If given, the step goes along P grad f instead of grad f (a variable
            metric, e.g. :class:`framework.optimization.preconditioner.SobolevPreconditioner`).
        two_metric_from: Preconditioner stage from which P acts on the free samples only
            (:meth:`_pinned`); None: P acts on the whole gradient at every stage.
        momentum_from: Preconditioner stage from which the data term is evaluated at Nesterov's
            extrapolated point (:mod:`framework.reconstruction.solvers.momentum`); None: never. Without
            a preconditioner the stage is 0.
        quasi_newton: ``{memory: k, from_stage: s}``: from preconditioner stage s on, the step
            direction is the L-BFGS direction of the last k steps
            (:mod:`framework.optimization.quasi_newton`), and no momentum; None: never.
        shaped_start_from: From a start that holds the broad shape (:meth:`begin_from_shaped_start`)
            the schedule begins at its ``first`` stage or its ``finest``.
        context: If given, ``setup(context)`` is called on every regulariser and post step that
            has ``setup`` (e.g. a :class:`regularizers.base.RegularizerContext`); if None the
            caller must have set them up.
    """

    def __init__(
        self,
        data: DataFidelity,
        d0: Tensor,
        step_size: StepSizePolicy | float,
        regularizers: Sequence[Any] = (),
        post_steps: Sequence[Any] = (),
        preconditioner: GradientPreconditioner | None = None,
        context: Any = None,
        two_metric_from: int | None = None,
        momentum_from: int | None = None,
        quasi_newton: Mapping[str, Any] | None = None,
        shaped_start_from: str = "first",
    ) -> None:
        super().__init__(d0)
        if not isinstance(data, DataFidelity):
            raise ValueError(f"{self.name}: data must be a DataFidelity, got {type(data).__name__}")
        self.data = data
        self.step_size = as_step_policy(step_size)
        self.regularizers = check_regularizers(regularizers, self.name)
        self.post_steps = check_post_steps(post_steps, self.name)
        if preconditioner is not None and not isinstance(preconditioner, GradientPreconditioner):
            raise ValueError(
                f"{self.name}: preconditioner {type(preconditioner).__name__} is not a GradientPreconditioner "
                "(framework/optimization/preconditioner.py)"
            )
        self.preconditioner = preconditioner
        self.two_metric_from = check_two_metric_from(two_metric_from)
        self.momentum_from = check_momentum_from(momentum_from)
        self.momentum = NesterovMomentum()
        self.quasi_newton = check_quasi_newton(quasi_newton)
        self.lbfgs = LbfgsMemory(self.quasi_newton["memory"]) if self.quasi_newton else None
        self.shaped_start_from = check_shaped_start_from(shaped_start_from)
        self._evaluation: DataEvaluation | None = None
        self._direction: Tensor | None = None
        if context is not None:
            for item in self._context_users():
                item.setup(context)

    def _context_users(self) -> list[Any]:
        return [*self.regularizers, *self.post_steps, *([self.preconditioner] if self.preconditioner else [])]

    # -- the pieces a subclass may change ------------------------------------------------------
    def regularization_value(self, d: Tensor) -> float:
        """g(d) = sum of the regularisers' values (inf outside an indicator's set)."""
        return float(sum(float(r.value(d)) for r in self.regularizers))

    def _prox_pixels(self, x: Tensor, tau: float) -> Tensor:
        for r in self.regularizers:
            x = r.prox(x, tau)
        return x

    def _step_direction(self) -> Tensor:
        """The step direction at the current iterate (computed once per iterate): grad f, or with a
        preconditioner P (or quasi-Newton steps) the two-metric direction of :meth:`_pinned`: P (or
        L-BFGS) acts on the free samples only, and the pinned ones take their plain gradient (which
        the prox then stops at the constraint)."""
        if self._direction is None:
            grad = self._current_evaluation().grad
            if self._plain_gradient():
                self._direction = grad
            elif not self._two_metric():
                self._direction = self._free_direction(grad)
            else:
                pinned = self._pinned(grad)
                self._direction = torch.where(pinned, grad, self._free_direction(grad, ~pinned))
        return self._direction

    def _plain_gradient(self) -> bool:
        """Whether the direction is grad f itself (no preconditioner, no quasi-Newton stage)."""
        return self.preconditioner is None and not self._quasi_newton_active()

    def _free_direction(self, grad: Tensor, free: Tensor | None = None) -> Tensor:
        """The direction on the ``free`` samples (m, m, bool; None: all): in the quasi-Newton stages
        the L-BFGS direction H grad / gamma, else P applied to the gradient with the other samples
        zeroed."""
        if self._quasi_newton_active():
            return self.lbfgs.direction(grad, self._apply_metric, free)
        return self._apply_metric(grad if free is None else torch.where(free, grad, torch.zeros_like(grad)))

    def _apply_metric(self, x: Tensor) -> Tensor:
        """P x (x itself without a preconditioner)."""
        return x if self.preconditioner is None else self.preconditioner(x)

    def _quasi_newton_active(self) -> bool:
        """Whether the current preconditioner stage takes the L-BFGS direction."""
        return self.lbfgs is not None and self.stage() >= self.quasi_newton["from_stage"]

    def stage(self) -> int:
        """The preconditioner's stage (0 without one or for a single length)."""
        return 0 if self.preconditioner is None else int(self.preconditioner.stage)

    def _two_metric(self) -> bool:
        """Whether the current preconditioner stage takes the two-metric direction."""
        return self.two_metric_from is not None and self.stage() >= self.two_metric_from

    def _with_momentum(self) -> bool:
        """Whether the current preconditioner stage evaluates at the extrapolated point."""
        return (self.momentum_from is not None and self.stage() >= self.momentum_from
                and not self._quasi_newton_active())

    def _pinned(self, grad: Tensor) -> Tensor:
        """Samples (m, m, bool) that the regularisers hold where they are: a plain gradient step of
        the current step size, followed by the proxes, leaves them unchanged (a bound pressed
        against, zero under an L1 term whose weight outweighs the gradient, the outside of the
        mask).

        Why: a smoothing metric P followed by a pixel-wise prox is not a descent method. Where a
        bound is active, P spreads its gradient into the free samples beside it, the prox then
        cuts the step back, and the iteration stalls at points that are not constrained minima
        (Bertsekas 1982, "Projected Newton methods for optimization problems with simple
        constraints"). Restricting P to the free samples, with the pinned ones stepping along
        their own gradient, makes every fixed point a stationary point of f + g again
        (docs/method.md, "Two-metric steps", with what was measured without it).
        """
        d = self.state.d
        step = self.step_size.current_step
        return self._prox_pixels(d - step * grad, step) == d

    def _propose(self, tau: float) -> Candidate:
        """The proximal point for step tau (no operator call)."""
        return {"d": self._prox_pixels(self.state.d - tau * self._step_direction(), tau)}

    def _finalize(self, candidate: Candidate) -> Candidate:
        """Apply the post-step updates to the accepted candidate, then bring the result back into
        the regularisers' constraint sets (a heuristic such as V1 may push a sample past a bound;
        an infeasible iterate would make F infinite and the next step-size test meaningless)."""
        d = candidate["d"]
        if self.post_steps:
            for u in self.post_steps:
                d = u(d)
            d = self._project(d)
        return {**candidate, "d": d}

    def _accept(self, candidate: Candidate) -> None:
        """Make the finalised candidate the current iterate."""
        self.state.d = candidate["d"]

    def _project(self, d: Tensor) -> Tensor:
        """d brought into every regulariser's constraint set (an extrapolated point may leave it)."""
        for r in self.regularizers:
            d = r.project(d)
        return d

    def volume_band(self) -> tuple[float, float] | None:
        """The narrowest band of the regularisers and post steps that enforce the deposited volume
        (V1, V2, the hold: a ``band`` (q1, q2)), or None."""
        bands = [band for part in [*self.regularizers, *self.post_steps]
                 if (band := part.band) is not None]
        return min(bands, key=lambda band: band[1] - band[0]) if bands else None

    def refine(self, d: Tensor) -> bool:
        """Switch the preconditioner to its next, finer stage and continue from ``d`` (m, m) (the
        best iterate so far); the step-size search starts afresh. False, and nothing changes, when
        the preconditioner has no finer stage (or there is none)."""
        if self.preconditioner is None or not self.preconditioner.refine():
            return False
        self.state.d = d.detach().clone()
        self._evaluation = None
        self._direction = None
        self.momentum.reset()
        self.step_size.reset()
        self._forget_curvature()
        return True

    def begin_from_shaped_start(self, schedule_from: str | None = None) -> None:
        """With ``schedule_from`` (None: ``shaped_start_from``) ``'finest'`` move the preconditioner
        to its finest length before the first iteration; with ``'first'`` keep the whole schedule."""
        begin = self.shaped_start_from if schedule_from is None else schedule_from
        while begin == "finest" and self.refine(self.state.d):
            pass

    def setup_changed(self) -> None:
        """Drop the cached evaluation, direction, momentum and curvature pairs: they belong to the old
        setup."""
        self._evaluation = None
        self._direction = None
        self.momentum.reset()
        self._forget_curvature()

    def _forget_curvature(self) -> None:
        if self.lbfgs is not None:
            self.lbfgs.reset()

    # -- the iteration -------------------------------------------------------------------------
    def _current_evaluation(self) -> DataEvaluation:
        if self._evaluation is None:
            self._evaluation = self.data.evaluate(self.state.d, with_grad=True)
        return self._evaluation

    def _objective(self, candidate: Candidate) -> float:
        d = candidate["d"]
        return self.data.evaluate(d, with_grad=False).value + self.regularization_value(d)

    def step(self) -> IterationRecord:
        """One proximal-gradient iteration; raises :class:`IterationFailed` (run() stops on it)."""
        t0 = time.perf_counter()
        current = self._current_evaluation()
        d = self.state.d
        objective_now = current.value + self.regularization_value(d)

        def sq_distance(c: Candidate) -> float:
            return float(torch.sum((c.get("prox_point", c["d"]) - d) ** 2))

        momentum = self._with_momentum()
        choice, spent = extrapolated_trial(self, objective_now, sq_distance) if momentum else (None, 0)
        if choice is None and self.post_steps and self.step_size.searches:
            choice, tried = finished_first_trial(self, objective_now, sq_distance)
            spent += tried
            if choice is not None:
                choice = dataclasses.replace(choice, trials=spent, forward_evaluations=spent)
        try:
            if choice is None:
                choice = self.step_size.select(self._propose, self._objective, sq_distance, objective_now)
                choice = dataclasses.replace(choice, trials=choice.trials + spent,
                                             forward_evaluations=choice.forward_evaluations + spent)
        except LineSearchFailed as err:
            # No step of this metric decreases F any more (typically the last digits of the
            # render): go on from here with the next, finer preconditioner stage if there is one.
            if self.refine(d):
                self.state.elapsed_s += time.perf_counter() - t0
                return self.step()
            raise IterationFailed(str(err)) from err
        finished = "finished" in choice.candidate
        new = choice.candidate if finished else self._finalize(choice.candidate)
        if momentum:  # a post step that moved the iterate restarts the momentum from where it put it
            moved = finished or (bool(self.post_steps) and not torch.equal(new["d"], choice.candidate["d"]))
            self.momentum.accepted(new["d"] if moved else choice.candidate.get("prox_point", new["d"]),
                                   keep=not moved)
        if not bool(torch.isfinite(new["d"]).all()):
            raise IterationFailed(f"the new iterate has non-finite entries (tau={choice.step:.3g}); reduce the step")
        try:
            evaluation = self.data.evaluate(new["d"], with_grad=True)
        except ValueError as err:  # e.g. an M1 iterate that dips below the substrate bottom
            raise IterationFailed(f"the new iterate cannot be evaluated (tau={choice.step:.3g}): {err}") from err
        if not math.isfinite(evaluation.value):
            raise IterationFailed(f"data term is {evaluation.value} at the new iterate; reduce the step size")
        regularization = self.regularization_value(new["d"])
        if self._quasi_newton_active():
            self.lbfgs.update(new["d"] - d, evaluation.grad - current.grad, self._apply_metric)
        self._accept(new)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        self._evaluation = evaluation
        self._direction = None
        record = IterationRecord(
            iteration=self.state.iteration,
            objective=evaluation.value + regularization,
            data_fidelity=evaluation.value,
            rel_discrepancy=evaluation.rel_discrepancy,
            step_size=choice.step,
            elapsed_s=self.state.elapsed_s,
            extras={
                "regularization": regularization,
                "trials": float(choice.trials),
                "forward_evaluations": float(choice.forward_evaluations),
                "extrapolated": float("prox_point" in choice.candidate and not finished),
                **({"preconditioner_length": float(self.preconditioner.length)}
                   if self.preconditioner is not None and self.preconditioner.length is not None else {}),
            },
        )
        self.history.append(record)
        return record

    # -- checkpoints ---------------------------------------------------------------------------
    def run_metrics(self) -> dict[str, Any]:
        """``refined_at``: the iterations after which the preconditioner moved to a finer length."""
        return {"refined_at": stage_changes(self.history)}

    def state_dict(self) -> dict[str, Any]:
        """Adds the step-size state and the cached evaluation at d (so a resume re-evaluates nothing)."""
        state = super().state_dict()
        state["step_size"] = self.step_size.state_dict()
        state["momentum"] = self.momentum.state_dict()
        if self.lbfgs is not None:
            state["quasi_newton"] = self.lbfgs.state_dict()
        if self.preconditioner is not None:
            state["preconditioner"] = self.preconditioner.state_dict()
        ev = self._evaluation
        state["evaluation"] = None if ev is None else {
            "value": ev.value, "grad": ev.grad, "image": ev.image, "rel_discrepancy": ev.rel_discrepancy,
        }
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        super().load_state_dict(state)
        self.step_size.load_state_dict(state.get("step_size", {}))
        self.momentum.load_state_dict(state.get("momentum", {}))
        if self.lbfgs is not None:
            self.lbfgs.load_state_dict(state.get("quasi_newton", {}))
        if self.preconditioner is not None:
            self.preconditioner.load_state_dict(state.get("preconditioner", {}))
        self._direction = None
        ev = state.get("evaluation")
        like = self.state.d
        self._evaluation = None if ev is None else DataEvaluation(
            value=float(ev["value"]),
            grad=ev["grad"].to(device=like.device, dtype=like.dtype),
            image=ev["image"].to(device=like.device),
            rel_discrepancy=float(ev["rel_discrepancy"]),
        )
