"""The photons of each iteration: few while the fit is far from the noise level, as many as the
noise level needs once it comes near (docs/method.md, "The photon budget"; measured in
docs/performance.md, "Fewer photon-traces").

A render with N photons carries render noise: its relative distance to a render of the same
heights with another photon pattern is sqrt(2) s(N), s(N) ~ N^(-1/2). The squared discrepancy that
Morozov's rule tests is then about delta^2 + misfit^2 + s^2, and the rule allows
(tau_dis^2 - 1) delta^2 above the data noise. Far from the noise level the render only needs to
be precise against the misfit still to be removed, r^2 - delta^2 (r the relative discrepancy).
The budget allows

    s^2 <= noise_share * max(r^2 - delta^2, (tau_dis^2 - 1) delta^2).

The run starts with ``start`` photons (the first iterations only need a direction) and measures s
at the current heights (two renders with different photon patterns) after every change of the
solver's stage, when the discrepancy first comes within ``near`` x tau_dis delta, before
Morozov's rule may accept an iterate, and whenever the last measured noise (scaled by
N^(-1/2) to the photons in force) exceeds what the falling discrepancy allows; it then raises the
budget in powers of two, up to the configured ``photons``. So the rule is never applied to a
discrepancy whose render noise exceeds that share. The budget never falls within a run from one
start.
"""

from __future__ import annotations

import math
from typing import Any

from operators.image_operator import ImageOperator
from framework.core.objective import DataFidelity
from framework.core.problem import Problem
from framework.core.solver_loop import Callback, IterationRecord, IterativeSolver
from framework.reconstruction.parts import Reconstruction

__all__ = ["PhotonBudget", "budget_photons", "photon_budget", "photons_needed", "receiver_scale", "render_noise"]

SEED_OFFSET = 3000  # the second photon pattern: seed + 3000 (the data's references use + 1000, + 2000)


def receiver_scale(operator: Any, photons_resolution: int | None) -> int:
    """The factor on the photons (the budget's start and cap) of ``operator``'s receiver (n x n)
    when the configured photons are meant for one of ``photons_resolution`` pixels a side:
    (n / photons_resolution)^2, rounded up to a doubling so that the budget's doublings reach it;
    1 for a receiver no finer, or without a resolution. A pixel's relative render noise goes as
    1 / sqrt(its photons): a finer receiver needs more photons in all for the same noise per pixel,
    and so for the same share of Morozov's allowance."""
    n = int(operator.output_shape[-1])
    if photons_resolution is None or n <= photons_resolution:
        return 1
    return 2 ** math.ceil(2.0 * math.log2(n / photons_resolution) - 1e-12)


def render_noise(fidelity: DataFidelity, operator: Any, other: Any, d: Any) -> float:
    """s(N): the relative render noise of ``operator`` at heights d (m, m), from the distance of
    its render to that of ``other`` (the same photons, another pattern): ||F_a - F_b||_W /
    (sqrt(2) ||b||_W)."""
    return fidelity.relative_difference(operator.render(d), other.render(d)) / math.sqrt(2.0)


def photons_needed(photons: int, noise: float, allowed: float, cap: int) -> int:
    """The smallest photons x 2^k (k >= 0) whose render noise noise x 2^(-k/2) is <= ``allowed``,
    at most ``cap``."""
    while photons < cap and noise > allowed:
        photons, noise = min(2 * photons, cap), noise / math.sqrt(2.0)
    return photons


class PhotonBudget(Callback):
    """Sets the photons of the data term's operator during a run (see the module docstring).

    Args:
        fidelity: The run's data term; its operator is swapped for variants with other photons.
        operator: The configured operator: ``variant`` builds the others; its ``photons`` are the cap
            unless ``cap`` is larger.
        start: Photons of the first iterations (<= the cap).
        noise_share: Share of Morozov's allowance (tau_dis^2 - 1) delta^2 the render noise may take.
        delta: The data's noise level.
        tau_dis: Morozov's factor.
        seed: The run's seed (photon patterns: seed, and seed + 3000 for the noise estimate).
        near: Discrepancy (in tau_dis delta) below which the budget is checked once more.
        cap: The most photons an iteration may trace (None: the operator's ``photons``; a smaller
            value is raised to those).
    """

    order = -50  # before the stopping rules, which then see the discrepancy with the photons in force

    def __init__(self, fidelity: DataFidelity, operator: Any, start: int, noise_share: float, delta: float,
                 tau_dis: float, seed: int, near: float = 1.5, cap: int | None = None) -> None:
        self.fidelity, self.operator, self.seed = fidelity, operator, seed
        self.cap = max(int(operator.photons), cap or 0)
        self.start = min(int(start), self.cap)
        self.noise_share, self.delta = noise_share, delta
        self.morozov_excess = max(tau_dis * tau_dis - 1.0, 0.0) * delta * delta
        self.near = near * tau_dis * delta
        self.noise: float | None = None  # the render noise last measured, scaled to the photons in force
        self.goal = tau_dis * delta
        self.checked_at_goal: set[int] = set()
        self.photons = self.cap
        self.stage: int | None = None
        self.checked_near = False
        self._operators: dict[int, Any] = {}

    def _use(self, solver: IterativeSolver, photons: int) -> None:
        if photons not in self._operators:
            self._operators[photons] = self.operator.with_photons(photons, self.seed)
        operator = self._operators[photons]
        self.photons = photons
        if self.fidelity.operator is not operator:
            self.fidelity.use_operator(operator)
            solver.setup_changed()

    def on_start(self, solver: IterativeSolver) -> None:
        """Start with ``start`` photons, or (a resumed run) with those of its last iteration."""
        last = solver.history[-1].extras.get("photons") if solver.history else None
        self.stage = solver.stage()
        self.checked_near = bool(solver.history) and solver.history[-1].rel_discrepancy <= self.near
        self._use(solver, int(last) if last else self.start)

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> None:
        """Check the budget after a change of stage, when the discrepancy first comes near the
        noise level, and before Morozov's rule may accept it (once per budget); a raised budget
        measures the iteration's discrepancy again with the new photons. Records the photons in
        force (``photons``) and each measured render noise (``render_noise``)."""
        stage_changed = solver.stage() != self.stage
        near = not self.checked_near and record.rel_discrepancy <= self.near
        at_goal = record.rel_discrepancy <= self.goal and self.photons not in self.checked_at_goal
        outgrown = self.noise is not None and self.noise > self.allowance(record.rel_discrepancy)
        if (stage_changed or near or at_goal or outgrown) and self.photons < self.cap:
            if at_goal:
                self.checked_at_goal.add(self.photons)
            before = self.photons
            record.extras["render_noise"] = self._check(solver, record.rel_discrepancy)
            if self.photons != before:
                self._measure_again(solver, record)
        self.stage = solver.stage()
        self.checked_near = self.checked_near or near
        record.extras["photons"] = float(self.photons)
        return None

    def allowance(self, discrepancy: float) -> float:
        """The render noise allowed at relative discrepancy r: sqrt(noise_share max(r^2 - delta^2,
        (tau_dis^2 - 1) delta^2))."""
        return math.sqrt(self.noise_share * max(discrepancy * discrepancy - self.delta * self.delta,
                                                self.morozov_excess))

    def _check(self, solver: IterativeSolver, discrepancy: float) -> float:
        """Measure the render noise at the solver's heights, raise the budget if the discrepancy
        ``discrepancy`` needs more; returns the noise."""
        current = self.fidelity.operator
        other = self.operator.variant(self.photons, self.seed + SEED_OFFSET, int(self.operator.output_shape[-1]))
        noise = render_noise(self.fidelity, current, other, solver.d)
        self.fidelity.count_passes(renders=2, gradients=0, photons=self.photons)
        measured_at = self.photons
        needed = photons_needed(self.photons, noise, self.allowance(discrepancy), self.cap)
        if needed != self.photons:
            self._use(solver, needed)
        self.noise = noise * math.sqrt(measured_at / needed)
        return noise

    def _measure_again(self, solver: IterativeSolver, record: IterationRecord) -> None:
        """The record's data term and discrepancy with the new photons (the render is kept for the
        solver's next gradient evaluation, framework/core/objective.py)."""
        evaluation = self.fidelity.evaluate(solver.d, with_grad=False)
        regularization = record.objective - record.data_fidelity
        record.data_fidelity, record.rel_discrepancy = evaluation.value, evaluation.rel_discrepancy
        record.objective = evaluation.value + regularization


def budget_photons(parts: Reconstruction, operator: ImageOperator) -> tuple[int, int]:
    """The photon budget's (start, cap) on ``operator``'s receiver: ``photon_budget.start`` and the
    configured photons, both times the receiver's scale (framework/reconstruction/photon_budget.py,
    ``receiver_scale``)."""
    budget = parts.settings.photon_budget
    scale = receiver_scale(operator, budget.photons_resolution)
    return (budget.start or int(operator.photons)) * scale, int(operator.photons) * scale


def photon_budget(parts: Reconstruction, problem: Problem, photons: tuple[int, int] | None = None
                  ) -> PhotonBudget | None:
    """The photon budget of a run on ``problem`` (the run's, one shot of its stack, or a coarse
    level with its own (start, cap) ``photons``; None: ``budget_photons``), or None: every
    iteration traces the configured photons (no ``photon_budget.start``, no noise level, or a joint
    calibration, which updates the configured operator's setup)."""
    budget, delta = parts.settings.photon_budget, problem.data.delta
    if budget.start is None or parts.calibration is not None or not delta or delta <= 0.0:
        return None
    start, cap = photons or budget_photons(parts, problem.operator)
    return PhotonBudget(problem.fidelity, problem.operator, start, budget.noise_share, float(delta),
                        parts.settings.tau_dis, parts.settings.seed, cap=cap)
