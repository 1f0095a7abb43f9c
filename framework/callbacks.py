"""Callbacks of the solver loop (:class:`framework.solvers.base.Callback`): stopping rules,
metrics, progress, checkpoints.

The stopping rules are plugins of kind ``stopping`` (``morozov``, ``stagnation``), built from the
config's ``stopping`` group; a rule that needs the problem (the noise level delta) gets it from
``setup(problem)`` before the run.
"""

from __future__ import annotations

import math
import os
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from framework.checkpoint import save_checkpoint
from framework.solvers.base import Callback

if TYPE_CHECKING:
    from framework.problem import Problem
    from framework.solvers.base import IterationRecord

__all__ = ["Callback", "MorozovStopping", "StagnationStopping", "MetricsHistory", "ProgressBar", "Checkpointer",
           "GroundTruthError"]


def _checked_delta(delta: float) -> float:
    delta = float(delta)
    if not (math.isfinite(delta) and 0.0 < delta < 1.0):
        raise ValueError(f"delta (relative noise level) must lie in (0, 1), got {delta!r}; 5% noise is 0.05")
    return delta


class MorozovStopping(Callback):
    """Morozov's discrepancy principle: stop once ||F(d) - b|| / ||b|| <= tau_dis * delta.

    The principle is a regularisation method only for tau_dis > 1 (the residual of the exact
    solution is about delta, so tau_dis <= 1 may never trigger, or only by chance); we therefore
    refuse tau_dis <= 1. The paper uses 1.01 to 1.2.

    When the deposited volume is known (a volume band [q1, q2] of the height sum, from V1 or V2),
    it is data too: an iterate is then admissible only if its height sum lies in the band as
    well. Without that, a smooth print whose caustic barely sees volume spread over the mask stops
    as soon as it fits the image, with a fraction of its volume (a 0.05-high bump: at 31%).

    Args:
        delta: Relative noise level of the data, 0 < delta < 1 (the paper: 0.05); None: set by
            :meth:`setup`.
        tau_dis: Safety factor > 1.
        volume_band: (q1, q2), bounds of sum(d) for an admissible iterate; None: the solver's
            (:meth:`framework.solvers.base.IterativeSolver.volume_band`), if it has one.
    """

    stop_accepts_iterate = True

    def __init__(self, delta: float | None = None, tau_dis: float = 1.1,
                 volume_band: tuple[float, float] | None = None) -> None:
        tau_dis = float(tau_dis)
        if not (math.isfinite(tau_dis) and tau_dis > 1.0):
            raise ValueError(
                f"tau_dis must be > 1 for the discrepancy principle, got {tau_dis!r}; the paper uses 1.01-1.2"
            )
        self.delta = None if delta is None else _checked_delta(delta)
        self.tau_dis = tau_dis
        self.volume_band = volume_band

    @classmethod
    def from_config(cls, tau_dis: float = 1.1) -> MorozovStopping:
        """The rule of the config's ``stopping.morozov``; delta comes from the data (:meth:`setup`)."""
        return cls(None, tau_dis)

    def setup(self, problem: Problem) -> None:
        """Take the noise level delta from the problem's data."""
        self.delta = _checked_delta(problem.data.delta)

    @property
    def threshold(self) -> float:
        """tau_dis * delta, the relative discrepancy at which the rule stops."""
        if self.delta is None:
            raise RuntimeError("MorozovStopping has no noise level; pass delta or call setup(problem)")
        return self.tau_dis * self.delta

    def on_start(self, solver) -> None:  # noqa: D102 (the solver's volume band, unless one was given)
        self.threshold  # refuses a rule without delta before the first iteration
        if self.volume_band is None:
            self.volume_band = solver.volume_band()

    def on_iteration(self, solver, record) -> bool:  # noqa: D102
        if record.rel_discrepancy > self.threshold:
            return False
        volume = ""
        if self.volume_band is not None:
            q1, q2 = self.volume_band
            total = float(solver.d.sum())
            if not q1 <= total <= q2:
                return False
            volume = f" with the height sum {total:.4g} in the volume band [{q1:.4g}, {q2:.4g}]"
        self.stop_reason = (
            f"discrepancy principle: rel. discrepancy {record.rel_discrepancy:.4g} <= "
            f"tau_dis * delta = {self.tau_dis:g} * {self.delta:g}{volume} at iteration {record.iteration}"
        )
        return True


class StagnationStopping(Callback):
    """Stop once the discrepancy has not improved for ``patience`` iterations; keep the best iterate.

    The complement of Morozov's rule for data the model cannot fit down to tau_dis * delta (a
    local minimum, features the model cannot resolve): when the relative discrepancy has stayed
    above (1 - min_improvement) times its best value for ``patience`` iterations, more
    iterations only drift (e.g. the volume heuristic V1 pumping height into a stalled fit).
    Before stopping, the solver is offered ``refine(best_d)`` (a coarse-to-fine preconditioner
    schedule, :meth:`framework.solvers.proximal_gradient.ProximalGradientSolver.refine`): if it
    accepts, it continues from the best iterate in a finer stage and the count starts again.
    Otherwise the run stops, and ``best_d`` / ``best_iteration`` hold the iterate with the lowest
    discrepancy, which the caller should report. The best iterate is not part of a checkpoint: a
    resumed run starts tracking afresh.

    Args:
        patience: Iterations without improvement before refining or stopping (>= 1).
        min_improvement: Relative decrease that counts as an improvement, in [0, 1).

    Attributes:
        refined_at: Iterations after which this rule switched the solver to a finer stage (a
            solver may also switch by itself when its line search fails; the records'
            ``preconditioner_length`` show every switch, see
            :func:`framework.reconstruction.stage_changes`).
    """

    def __init__(self, patience: int = 8, min_improvement: float = 1e-3) -> None:
        if isinstance(patience, bool) or int(patience) != patience or int(patience) < 1:
            raise ValueError(f"patience={patience!r} must be an integer >= 1 (iterations), e.g. 8; null disables the rule")
        if not 0.0 <= float(min_improvement) < 1.0:
            raise ValueError(f"min_improvement={min_improvement!r} must lie in [0, 1), e.g. 1e-3")
        self.patience, self.min_improvement = int(patience), float(min_improvement)
        self.best_discrepancy = math.inf
        self.best_iteration: int | None = None
        self.best_d: Tensor | None = None
        self._reference = math.inf  # discrepancy that the next improvement must beat by min_improvement
        self._progress_iteration = 0  # iteration of the last such improvement (or refinement)
        self.refined_at: list[int] = []

    def on_iteration(self, solver, record) -> bool:  # noqa: D102
        if record.rel_discrepancy < self.best_discrepancy or self.best_d is None:
            self.best_discrepancy = record.rel_discrepancy
            self.best_iteration = record.iteration
            self.best_d = solver.d.detach().clone()
        if record.rel_discrepancy < (1.0 - self.min_improvement) * self._reference:
            self._reference = record.rel_discrepancy
            self._progress_iteration = record.iteration
            return False
        if record.iteration - self._progress_iteration < self.patience:
            return False
        refine = getattr(solver, "refine", None)
        if callable(refine) and refine(self.best_d):
            self.refined_at.append(record.iteration)
            self._reference = self.best_discrepancy
            self._progress_iteration = record.iteration
            return False
        self.stop_reason = (
            f"stagnation: no {self.min_improvement:.2%} improvement of the rel. discrepancy for {self.patience} "
            f"iterations; the best iterate (iteration {self.best_iteration}, {self.best_discrepancy:.4g}) is returned"
        )
        return True

    def best_iterate(self) -> tuple[Tensor, int] | None:
        """(d, iteration) of the lowest discrepancy seen, or None before the first iteration."""
        if self.best_d is None or self.best_iteration is None:
            return None
        return self.best_d, self.best_iteration


class MetricsHistory(Callback):
    """Collects every record (including those before a resume) for plots and tables.

    Attributes:
        records: The iteration records in order.
    """

    def __init__(self) -> None:
        self.records: list["IterationRecord"] = []

    def on_start(self, solver) -> None:  # noqa: D102
        self.records = list(getattr(solver, "history", []))

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        self.records.append(record)

    def columns(self) -> dict[str, list[float]]:
        """Metric name -> values per iteration (NaN where an iteration lacks the metric)."""
        names: dict[str, None] = {}
        for r in self.records:
            names.update(dict.fromkeys(r.metrics()))
        cols: dict[str, list[float]] = defaultdict(list)
        for r in self.records:
            m = r.metrics()
            for name in names:
                cols[name].append(m.get(name, math.nan))
        return dict(cols)

    def __getitem__(self, name: str) -> list[float]:
        return self.columns()[name]


class ProgressBar(Callback):
    """A tqdm bar over iterations with the discrepancy (and the errors, if computed) in the postfix.

    Args:
        desc: Bar label (e.g. the method name).
        disable: Passed to tqdm (None: disable when not a terminal).
    """

    def __init__(self, desc: str | None = None, disable: bool | None = None) -> None:
        self.desc, self.disable = desc, disable
        self._bar: Any = None

    def on_start(self, solver) -> None:  # noqa: D102
        from tqdm.auto import tqdm

        self._bar = tqdm(
            total=solver.max_iter, initial=solver.iteration, desc=self.desc or getattr(solver, "name", None),
            disable=self.disable, unit="it",
        )

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        postfix = {"dis": f"{record.rel_discrepancy:.4g}", "tau": f"{record.step_size:.3g}"}
        for key, label in (("rel_error", "err"), ("rel_error_d", "err_d")):
            if key in record.extras:
                postfix[label] = f"{record.extras[key]:.4g}"
        self._bar.set_postfix(postfix, refresh=False)
        self._bar.update(1)

    def on_end(self, solver, result) -> None:  # noqa: D102
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class Checkpointer(Callback):
    """Saves the solver state to ``path`` every ``every`` iterations and at the end of the run.

    Runs last (order 100), after the loggers, so the saved history holds every metric.

    Args:
        path: Checkpoint file (overwritten atomically each time).
        every: Save when ``iteration % every == 0``.
        at_end: Also save when the run ends.
        run: The fingerprint of the run (framework/run_identity.py), stored with the state.
    """

    order = 100

    def __init__(self, path: str | os.PathLike[str], every: int = 10, at_end: bool = True,
                 run: dict[str, str] | None = None) -> None:
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"every must be an int >= 1, got {every!r}")
        self.path, self.every, self.at_end, self.run = Path(path), every, at_end, run

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        if record.iteration % self.every == 0:
            save_checkpoint(solver, self.path, self.run)

    def on_end(self, solver, result) -> None:  # noqa: D102
        if self.at_end:
            save_checkpoint(solver, self.path, self.run)


class GroundTruthError(Callback):
    """Adds the relative height errors to each record (for simulated data with known d_true).

    ``rel_error``   = ||(h + d) - (h + d_true)|| / ||h + d_true||  (the paper's / official definition,
    relative to the total height including the substrate thickness h);
    ``rel_error_d`` = ||d - d_true|| / ||d_true||  (relative to the printed part alone).

    Args:
        d_true: Ground-truth height field (m, m), scene units.
        substrate_thickness: h >= 0, scene units (official default 0.1).
    """

    order = -100

    def __init__(self, d_true: Tensor, substrate_thickness: float) -> None:
        if not isinstance(d_true, Tensor) or d_true.ndim != 2:
            raise ValueError(f"d_true must be an (m, m) tensor, got {getattr(d_true, 'shape', type(d_true).__name__)}")
        h = float(substrate_thickness)
        if not (math.isfinite(h) and h >= 0.0):
            raise ValueError(f"substrate_thickness h must be finite and >= 0, got {substrate_thickness!r}")
        self.d_true, self.h = d_true.detach(), h
        self._norm_total = float(torch.linalg.vector_norm((h + self.d_true).double()))
        self._norm_d = float(torch.linalg.vector_norm(self.d_true.double()))
        if self._norm_total == 0.0:
            raise ValueError("h + d_true is zero everywhere; the relative error is undefined")

    def errors(self, d: Tensor) -> dict[str, float]:
        """Both relative errors of the height field d (same shape as d_true)."""
        if tuple(d.shape) != tuple(self.d_true.shape):
            raise ValueError(f"d has shape {tuple(d.shape)}, d_true {tuple(self.d_true.shape)}")
        diff = float(torch.linalg.vector_norm((d - self.d_true.to(d.device)).double()))
        # (h + d) - (h + d_true) = d - d_true; only the normalisation differs.
        return {"rel_error": diff / self._norm_total, "rel_error_d": diff / self._norm_d if self._norm_d else math.inf}

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        record.extras.update(self.errors(solver.d))
