"""The stopping rules of the solver loop: plugins of kind ``stopping`` (``morozov``, ``stagnation``),
built from the config's ``stopping`` group; the contract they keep is
framework/core/contracts/stopping.py.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from torch import Tensor

from framework.core.data import validate_delta
from framework.core.contracts.stopping import StoppingRule
from operators.values import checked_number, checked_whole, is_number

if TYPE_CHECKING:
    from framework.core.problem import Problem

__all__ = ["MorozovStopping", "StagnationStopping"]

# The volume band's edges admit a height sum off by this share: the hold (regularizers/volume_hold.py)
# puts the sum on an edge in float64, and a float32 iterate's sum then lies up to ~1.4e-7 beyond it.
BAND_ROUNDING = 1e-6


class MorozovStopping(StoppingRule):
    """Morozov's discrepancy principle: stop once ||F(d) - b|| / ||b|| <= tau_dis * delta.

    The principle is a regularisation method only for tau_dis > 1 (the residual of the exact
    solution is about delta, so tau_dis <= 1 may never trigger, or only by chance); we therefore
    refuse tau_dis <= 1. The paper uses 1.01 to 1.2.

    When the deposited volume is known (a volume band [q1, q2] of the height sum, the narrowest of
    V1, V2 and the hold), it is data too: an iterate is then admissible only if its height sum lies
    in the band as well. Without that, a smooth print whose caustic barely sees volume spread over
    the mask stops as soon as it fits the image, with a fraction of its volume (a 0.05-high bump:
    at 31%).
    Likewise a jointly calibrated geometry (framework/lab/calibration.py) must have settled:
    an iteration whose calibration update still moved it by more than its standard error
    (``record.extras["calibration_settled"] == 0``) is not accepted.

    Args:
        delta: Relative noise level of the data, 0 < delta < 1 (the paper: 0.05); None: set by
            :meth:`setup`.
        tau_dis: Safety factor > 1.
        volume_band: (q1, q2), bounds of sum(d) for an admissible iterate; None: the solver's
            (:meth:`framework.core.solver_loop.IterativeSolver.volume_band`), if it has one.
    """

    stop_accepts_iterate = True

    def __init__(self, delta: float | None = None, tau_dis: float = 1.1,
                 volume_band: tuple[float, float] | None = None) -> None:
        tau_dis = checked_number(tau_dis, "stopping.morozov.tau_dis", above=1.0,
                                 unit="the discrepancy principle's factor", example="1.01-1.2 (the paper)")
        self.delta = None if delta is None else validate_delta(delta, "stopping.morozov.delta")
        self.tau_dis = tau_dis
        self.volume_band = volume_band

    @classmethod
    def from_config(cls, tau_dis: float = 1.1) -> MorozovStopping:
        """The rule of the config's ``stopping.morozov``; delta comes from the data (:meth:`setup`)."""
        return cls(None, tau_dis)

    def setup(self, problem: Problem) -> None:
        """Take the noise level delta from the problem's data."""
        self.delta = validate_delta(problem.data.delta)

    @property
    def threshold(self) -> float:
        """tau_dis * delta, the relative discrepancy at which the rule stops."""
        if self.delta is None:
            raise RuntimeError("MorozovStopping has no noise level; pass delta or call setup(problem)")
        return self.tau_dis * self.delta

    def on_start(self, solver) -> None:  # noqa: D102 (the solver's volume band, unless one was given)
        _ = self.threshold  # refuses a rule without delta before the first iteration
        if self.volume_band is None:
            self.volume_band = solver.volume_band()

    def on_iteration(self, solver, record) -> bool:  # noqa: D102
        if record.rel_discrepancy > self.threshold or not record.extras.get("calibration_settled", 1.0):
            return False
        volume = ""
        if self.volume_band is not None:
            q1, q2 = self.volume_band
            total = float(solver.d.double().sum())
            if not q1 * (1.0 - BAND_ROUNDING) <= total <= q2 * (1.0 + BAND_ROUNDING):
                return False
            volume = f" with the height sum {total:.4g} in the volume band [{q1:.4g}, {q2:.4g}]"
        self.stop_reason = (
            f"discrepancy principle: rel. discrepancy {record.rel_discrepancy:.4g} <= "
            f"tau_dis * delta = {self.tau_dis:g} * {self.delta:g}{volume} at iteration {record.iteration}"
        )
        return True


class StagnationStopping(StoppingRule):
    """Stop once the discrepancy has not improved for ``patience`` iterations; keep the best iterate.

    The complement of Morozov's rule for data the model cannot fit down to tau_dis * delta (a
    local minimum, features the model cannot resolve): when the relative discrepancy has stayed
    above (1 - min_improvement) times its best value for ``patience`` iterations, more
    iterations only drift (e.g. the volume heuristic V1 pumping height into a stalled fit).
    Before stopping, the solver is offered ``refine(best_d)`` (a coarse-to-fine preconditioner
    schedule, :meth:`framework.reconstruction.solvers.proximal_gradient.ProximalGradientSolver.refine`): if it
    accepts, it continues from the best iterate in a finer stage and the count starts again.
    Otherwise the run stops, and ``best_d`` / ``best_iteration`` hold the iterate with the lowest
    discrepancy, which the caller should report. The best iterate is not part of a checkpoint: a
    resumed run starts tracking afresh.

    With ``refine_share`` the rule also refines before the fit stalls: when the last ``patience``
    iterations of a stage removed less than that share of the misfit above the noise level,
    r^2 - delta^2 (r the relative discrepancy, delta the data's noise level), a coarse metric
    near the noise level only creeps while the next, finer one goes on at its own pace
    (docs/performance.md, "How the cost grows with the grid"). It never stops a run by itself.

    Args:
        patience: Iterations without improvement before refining or stopping (>= 1).
        min_improvement: Relative decrease that counts as an improvement, in [0, 1).
        refine_share: Share in (0, 1) of r^2 - delta^2 that ``patience`` iterations of a stage must
            remove, else the solver is offered its next stage; None: only when the fit stalls
            (or without a noise level).

    Attributes:
        refined_at: Iterations after which this rule switched the solver to a finer stage (a
            solver may also switch by itself when its line search fails; the records'
            ``preconditioner_length`` show every switch, see
            :func:`framework.reconstruction.solvers.proximal_gradient.stage_changes`).
    """

    def __init__(self, patience: int = 8, min_improvement: float = 1e-3, refine_share: float | None = None) -> None:
        patience = checked_whole(patience, "patience", 1, must="must be an integer >= 1 (iterations)",
                                 example="8; null disables the rule")
        if not 0.0 <= float(min_improvement) < 1.0:
            raise ValueError(f"min_improvement={min_improvement!r} must lie in [0, 1), e.g. 1e-3")
        if refine_share is not None and not (is_number(refine_share) and 0.0 < float(refine_share) < 1.0):
            raise ValueError(f"stopping.stagnation.refine_share={refine_share!r} must lie in (0, 1), e.g. 0.25; "
                             "null refines only when the fit stalls")
        self.patience, self.min_improvement = patience, float(min_improvement)
        self.refine_share = None if refine_share is None else float(refine_share)
        self.delta: float | None = None
        self._stage: int | None = None
        self._stage_discrepancies: list[float] = []  # relative discrepancies of the current stage
        self.best_discrepancy = math.inf
        self.best_iteration: int | None = None
        self.best_d: Tensor | None = None
        self._reference = math.inf  # discrepancy that the next improvement must beat by min_improvement
        self._progress_iteration = 0  # iteration of the last such improvement (or refinement)
        self.refined_at: list[int] = []

    def setup(self, problem: Problem) -> None:
        """Take the noise level delta (for ``refine_share``) from the problem's data."""
        delta = problem.data.delta
        self.delta = float(delta) if delta and delta > 0.0 else None

    def on_iteration(self, solver, record) -> bool:  # noqa: D102
        if record.rel_discrepancy < self.best_discrepancy or self.best_d is None:
            self.best_discrepancy = record.rel_discrepancy
            self.best_iteration = record.iteration
            self.best_d = solver.d.detach().clone()
        if self._refined_early(solver, record):
            return False
        if not record.extras.get("calibration_settled", 1.0):  # a calibrated geometry still moving is progress
            self._progress_iteration = record.iteration
            return False
        if record.rel_discrepancy < (1.0 - self.min_improvement) * self._reference:
            self._reference = record.rel_discrepancy
            self._progress_iteration = record.iteration
            return False
        if record.iteration - self._progress_iteration < self.patience:
            return False
        if self._refine(solver, record.iteration):
            return False
        self.stop_reason = (
            f"stagnation: no {self.min_improvement:.2%} improvement of the rel. discrepancy for {self.patience} "
            f"iterations; the best iterate (iteration {self.best_iteration}, {self.best_discrepancy:.4g}) is returned"
        )
        return True

    def _refined_early(self, solver, record) -> bool:
        """With ``refine_share``: whether the current stage's last ``patience`` iterations removed
        too little of r^2 - delta^2 and the solver took its next stage (from the best iterate)."""
        if self.refine_share is None or self.delta is None:
            return False
        if solver.stage() != self._stage:
            self._stage, self._stage_discrepancies = solver.stage(), []
        self._stage_discrepancies.append(record.rel_discrepancy)
        if len(self._stage_discrepancies) <= self.patience:
            return False
        misfit = [r * r - self.delta * self.delta for r in (self._stage_discrepancies[-1 - self.patience],
                                                             record.rel_discrepancy)]
        if not (misfit[0] > 0.0 and misfit[1] > (1.0 - self.refine_share) * misfit[0]):
            return False
        return self._refine(solver, record.iteration)

    def _refine(self, solver, iteration: int) -> bool:
        """Offer the solver its next stage from the best iterate; if it takes it, the count of
        iterations without improvement starts again after ``iteration``."""
        if not solver.refine(self.best_d):
            return False
        self.refined_at.append(iteration)
        self._reference = self.best_discrepancy
        self._progress_iteration = iteration
        return True

    def best_iterate(self) -> tuple[Tensor, int] | None:
        """(d, iteration) of the lowest discrepancy seen, or None before the first iteration."""
        if self.best_d is None or self.best_iteration is None:
            return None
        return self.best_d, self.best_iteration
