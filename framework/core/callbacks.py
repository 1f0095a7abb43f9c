"""Callbacks the pipeline adds to every solver loop (:class:`framework.core.solver_loop.Callback`):
the metrics history, the progress bar, checkpoints and the error against a ground truth. The
stopping rules are plugins (framework/reconstruction/stopping.py).
"""

from __future__ import annotations

import math
import os
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torch import Tensor

from framework.core.checkpoint import save_checkpoint
from framework.core.progress import report
from framework.core.solver_loop import Callback
from framework.core.truth import GroundTruth
from operators.values import checked_number, checked_whole, described

if TYPE_CHECKING:
    from framework.core.solver_loop import IterationRecord

__all__ = ["MetricsHistory", "ProgressBar", "Checkpointer", "GroundTruthError"]


class MetricsHistory(Callback):
    """Collects every record (including those before a resume) for plots and tables.

    Attributes:
        records: The iteration records in order.
    """

    def __init__(self) -> None:
        self.records: list[IterationRecord] = []

    def on_start(self, solver) -> None:  # noqa: D102
        self.records = list(solver.history)

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
    """A tqdm bar over iterations with the discrepancy (and the errors, if computed) in the postfix;
    where stderr is not a terminal, the same figures and the time left in the lines of
    :class:`framework.core.progress.Heartbeat`.

    Args:
        desc: Bar label (e.g. the method name).
        disable: Passed to tqdm (None: disable when not a terminal).
        seconds: The run's time budget, if it has one (s): the time left is at most what remains of it.
    """

    def __init__(self, desc: str | None = None, disable: bool | None = None, seconds: float | None = None) -> None:
        self.desc, self.disable, self.seconds = desc, disable, seconds
        self._bar: Any = None
        self._first = (0, 0.0)  # (iteration, elapsed s) when the bar started

    def on_start(self, solver) -> None:  # noqa: D102
        from tqdm.auto import tqdm

        self._bar = tqdm(
            total=solver.max_iter, initial=solver.iteration, desc=self.desc or solver.name,
            disable=self.disable, unit="it",
        )
        self._first = (solver.iteration, solver.state.elapsed_s)

    def seconds_left(self, iteration: int, elapsed_s: float, max_iter: int) -> float:
        """The most the run can still take (s): the remaining iterations at the mean pace so far,
        capped by the time budget."""
        done = iteration - self._first[0]
        pace = (elapsed_s - self._first[1]) / done if done > 0 else math.inf
        left = pace * max(max_iter - iteration, 0)
        return min(left, self.seconds - elapsed_s) if self.seconds is not None else left

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        postfix = {"dis": f"{record.rel_discrepancy:.4g}", "tau": f"{record.step_size:.3g}"}
        for key, label in (("rel_error", "err"), ("rel_error_d", "err_d")):
            if key in record.extras:
                postfix[label] = f"{record.extras[key]:.4g}"
        self._bar.set_postfix(postfix, refresh=False)
        self._bar.update(1)
        left = self.seconds_left(record.iteration, record.elapsed_s, solver.max_iter)
        figures = ", ".join(f"{label} {value}" for label, value in postfix.items())
        report(f"{self.desc or solver.name}: iteration {record.iteration}/{solver.max_iter}, {figures}, "
               f"at most {max(left, 0.0):.0f} s left")

    def on_end(self, solver, result) -> None:  # noqa: D102
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        report(f"{self.desc or solver.name}: stopped at iteration {solver.iteration}; writing the outputs")

class Checkpointer(Callback):
    """Saves the solver state to ``path`` every ``every`` iterations and at the end of the run.

    Runs last (order 100), after the loggers, so the saved history holds every metric.

    Args:
        path: Checkpoint file (overwritten atomically each time).
        every: Save when ``iteration % every == 0``.
        at_end: Also save when the run ends.
        run: The fingerprint of the run (framework/reconstruction/run_identity.py), stored with the state.
    """

    order = 100

    def __init__(self, path: str | os.PathLike[str], every: int = 10, at_end: bool = True,
                 run: dict[str, str] | None = None) -> None:
        every = checked_whole(every, "every", 1)
        self.path, self.every, self.at_end, self.run = Path(path), every, at_end, run

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        if record.iteration % self.every == 0:
            save_checkpoint(solver, self.path, self.run)

    def on_end(self, solver, result) -> None:  # noqa: D102
        if self.at_end:
            save_checkpoint(solver, self.path, self.run)


class GroundTruthError(Callback):
    """Adds the relative height errors against the ground truth of synthetic data to each record
    (``rel_error``, ``rel_error_d``: framework/core/truth.py, :func:`height_errors`).

    Args:
        truth: The sealed ground truth (m, m).
        substrate_thickness: h >= 0, scene units (official default 0.1).
    """

    order = -100

    def __init__(self, truth: GroundTruth, substrate_thickness: float) -> None:
        if not isinstance(truth, GroundTruth):
            raise ValueError(f"truth must be a GroundTruth (framework/core/truth.py), got {described(truth)}")
        h = checked_number(substrate_thickness, "substrate_thickness", least=0.0, unit="scene units")
        self.truth, self.h = truth, h

    def errors(self, d: Tensor) -> dict[str, float]:
        """Both relative errors of the height field d (m, m)."""
        return self.truth.errors(d, self.h)

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        record.extras.update(self.errors(solver.d))
