"""Step-size policies for the proximal-gradient iteration x+ = P(x - tau grad f(x), tau).

A policy gets three callables from the solver and returns the accepted step and candidate:
``propose(tau)`` builds the proximal point (cheap: no operator call), ``objective(candidate)``
evaluates F = f + g at it (one *forward-only* operator evaluation), and ``sq_distance(candidate)``
is ||d+ - d||_2^2. The gradient at the accepted point is computed afterwards by the solver
(one gradient evaluation per iteration, whatever the policy).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any
from collections.abc import Callable

from operators.plugin import Plugin
from operators.values import checked_number, is_number

__all__ = ["StepChoice", "StepSizePolicy", "ConstantStep", "BacktrackingStep", "LineSearchFailed", "as_step_policy",
           "backtrack"]


class LineSearchFailed(RuntimeError):
    """No trial step gave sufficient decrease; the solver stops and keeps the current iterate."""


def backtrack(evaluate: Callable[[float], tuple[float, Any]], bound: Callable[[float, Any], float], tau: float,
              shrink: float, max_trials: int) -> tuple[float, Any, int]:
    """The sufficient-decrease (Armijo) search shared by every solver: try ``tau``, ``shrink`` x
    tau, ... until a trial's objective is finite and at most its ``bound``.

    Args:
        evaluate: tau -> (objective value, the trial) (the trial: whatever the solver keeps).
        bound: (tau, trial) -> the largest objective value the test accepts at that step.
        tau: The first step.
        shrink: The step's factor after a rejection.
        max_trials: The trials at most.

    Returns:
        (the accepted tau, its trial, the trials spent); :class:`LineSearchFailed` after
        ``max_trials`` rejections, naming the last step and value.
    """
    value = math.nan
    for trials in range(1, max_trials + 1):
        value, trial = evaluate(tau)
        if math.isfinite(value) and value <= bound(tau, trial):
            return tau, trial, trials
        tau *= shrink
    raise LineSearchFailed(f"no sufficient decrease after {max_trials} trials (last tau={tau / shrink:.3g}, "
                           f"value {value:.6g})")


@dataclass(frozen=True)
class StepChoice:
    """The outcome of one step-size selection.

    Attributes:
        step: The accepted step tau.
        candidate: The proximal point built with ``step`` (solver-specific object).
        trials: Number of proximal points built.
        forward_evaluations: Forward-only operator evaluations spent.
    """

    step: float
    candidate: Any
    trials: int
    forward_evaluations: int


class StepSizePolicy(Plugin, ABC):
    """Chooses tau for each proximal-gradient iteration; its state is saved in checkpoints.

    Attributes:
        sufficient_decrease: The Armijo constant c a momentum trial's decrease is held to (0: any
            decrease; a backtracking policy's own c).
        searches: Whether :meth:`select` tests its trials by the objective (a line search): the
            solver may then test a first trial of its own, the finished iterate
            (framework/reconstruction/solvers/proximal_gradient.py).
    """

    sufficient_decrease: float = 0.0
    searches: bool = False

    @property
    @abstractmethod
    def current_step(self) -> float:
        """The step the next iteration will try first."""

    @abstractmethod
    def select(
        self,
        propose: Callable[[float], Any],
        objective: Callable[[Any], float],
        sq_distance: Callable[[Any], float],
        objective_now: float,
    ) -> StepChoice:
        """Pick tau and the candidate x+(tau); may raise :class:`LineSearchFailed`."""

    def reset(self) -> None:
        """Forget what earlier iterations learnt about the step (the metric changed)."""

    def start_from(self, tau: float) -> None:
        """Make ``tau`` (> 0) the next search's first trial: a method that knows its natural step
        (Gauss-Newton's full step) says so; a policy that does not search ignores it."""

    def momentum_trials(self) -> list[float]:
        """The steps a momentum trial tries, in order (framework/reconstruction/solvers/proximal_gradient.py)."""
        return [self.current_step]

    def accepted_elsewhere(self, step: float) -> None:
        """A step accepted outside :meth:`select` (a momentum trial): go on as after ``select``."""

    def state_dict(self) -> dict[str, float]:
        """Mutable state (for checkpoints)."""
        return {}

    def load_state_dict(self, state: dict[str, float]) -> None:
        """Restore :meth:`state_dict`."""


class ConstantStep(StepSizePolicy):
    """tau fixed (the paper's choice: tau_p = tau_w = 0.1 in the official code's units).

    Cost: no operator evaluation beyond the solver's one gradient evaluation per iteration.

    Args:
        tau: Step size > 0, in the unit of :mod:`framework.core.objective` (normalised data term).
    """

    def __init__(self, tau: float) -> None:
        self.tau = checked_number(tau, "tau", above=0.0)

    @property
    def current_step(self) -> float:
        return self.tau

    def select(self, propose, objective, sq_distance, objective_now) -> StepChoice:  # noqa: D102
        return StepChoice(step=self.tau, candidate=propose(self.tau), trials=1, forward_evaluations=0)

    def __repr__(self) -> str:
        return f"ConstantStep(tau={self.tau})"


class BacktrackingStep(StepSizePolicy):
    """Backtracking with a sufficient-decrease (Armijo) test on F = f + g at the proximal point.

    Accept tau when  F(x+) <= F(x) - c / (2 tau) ||x+ - x||_2^2  (x = d, the height field),
    else tau <- shrink * tau. After acceptance the next iteration starts from
    min(grow * tau, tau_max). For L-smooth f, convex g and exact proxes every tau <= 1/L passes
    (the Beck-Teboulle bound gives the test with c = 1), so the search terminates.

    Cost: each trial is one forward-only operator evaluation (no backward), on top of the
    solver's one gradient evaluation per iteration; typically 1 trial, 2 when ``grow`` > 1
    overshoots. Post-step heuristics are applied after acceptance and are not part of the test.

    Args:
        tau: First trial step tau0 > 0 (the config's ``step_size.tau``).
        shrink: Factor in (0, 1) applied after a rejected trial.
        grow: Factor >= 1 applied after an accepted step (1 = never grow).
        sufficient_decrease: c in (0, 1].
        max_trials: Trials per iteration before :class:`LineSearchFailed`.
        tau_max: Upper bound for grown steps.
    """

    searches = True

    def __init__(
        self,
        tau: float,
        shrink: float = 0.5,
        grow: float = 1.25,
        sufficient_decrease: float = 1e-4,
        max_trials: int = 30,
        tau_max: float = math.inf,
    ) -> None:
        self.tau0 = checked_number(tau, "tau", above=0.0)
        if not 0.0 < float(shrink) < 1.0:
            raise ValueError(f"shrink must lie in (0, 1), got {shrink!r}")
        checked_number(grow, "grow", least=1.0, unit="1: never grow")
        if not 0.0 < float(sufficient_decrease) <= 1.0:
            raise ValueError(f"sufficient_decrease must lie in (0, 1], got {sufficient_decrease!r}")
        if int(max_trials) < 1:
            raise ValueError(f"max_trials must be >= 1, got {max_trials!r}")
        if not float(tau_max) >= self.tau0:
            raise ValueError(f"tau_max ({tau_max!r}) must be >= tau ({tau!r})")
        self.shrink, self.grow = float(shrink), float(grow)
        self.sufficient_decrease, self.max_trials, self.tau_max = (
            float(sufficient_decrease),
            int(max_trials),
            float(tau_max),
        )
        self.tau = self.tau0

    @property
    def current_step(self) -> float:
        return self.tau

    def select(self, propose, objective, sq_distance, objective_now) -> StepChoice:  # noqa: D102
        def evaluate(tau: float) -> tuple[float, Any]:
            candidate = propose(tau)
            return objective(candidate), candidate

        def bound(tau: float, candidate: Any) -> float:
            return objective_now - self.sufficient_decrease / (2.0 * tau) * sq_distance(candidate)

        try:
            tau, candidate, trials = backtrack(evaluate, bound, self.tau, self.shrink, self.max_trials)
        except LineSearchFailed as failed:
            raise LineSearchFailed(f"{failed} against F(x)={objective_now:.6g}; the objective may be non-smooth "
                                   "here") from None
        self.tau = min(tau * self.grow, self.tau_max)
        return StepChoice(step=tau, candidate=candidate, trials=trials, forward_evaluations=trials)

    def momentum_trials(self) -> list[float]:
        """The current step, then one shrunk: momentum survives a step that was a little too long."""
        return [self.tau, self.tau * self.shrink]

    def accepted_elsewhere(self, step: float) -> None:
        """The next search starts from ``grow`` x the accepted step, as after :meth:`select`."""
        self.tau = min(step * self.grow, self.tau_max)

    def start_from(self, tau: float) -> None:  # noqa: D102
        self.tau = min(float(tau), self.tau_max)

    def reset(self) -> None:
        """Start the next search from tau0 again (e.g. after a change of preconditioner, when the
        steps that suited the old metric say nothing about the new one)."""
        self.tau = self.tau0

    def state_dict(self) -> dict[str, float]:
        return {"tau": self.tau}

    def load_state_dict(self, state: dict[str, float]) -> None:
        self.tau = checked_number(state["tau"], "tau", above=0.0)

    def __repr__(self) -> str:
        return f"BacktrackingStep(tau0={self.tau0}, shrink={self.shrink}, grow={self.grow}, tau={self.tau})"


def as_step_policy(step_size: StepSizePolicy | float) -> StepSizePolicy:
    """A policy from a policy or a number (a number means :class:`ConstantStep`)."""
    if isinstance(step_size, StepSizePolicy):
        return step_size
    if is_number(step_size):
        return ConstantStep(step_size)
    raise ValueError(
        f"step_size must be a StepSizePolicy or a positive number, got {type(step_size).__name__}; "
        "use ConstantStep(tau) or BacktrackingStep(tau)"
    )
