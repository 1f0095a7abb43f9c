"""The runs from each start of one reconstruction (``initial=auto`` tries several; a run whose
calibration moved what the heights absorb runs its start again, a refit): how each ended
(:class:`PhaseOutcome`), and the record that lets an interrupted run resume in the start its
checkpoint belongs to (:data:`PHASES`, :func:`resumed_phases`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from framework.core.solver_loop import IterationRecord, RunResult
from framework.reconstruction.run_checks import CHECKPOINT

__all__ = ["PHASES", "PhaseOutcome", "resumed_phases"]

PHASES = "phases.pt"  # the finished starts of a run, the refits added, and which one is under way


@dataclass
class PhaseOutcome:
    """How the run from one start ended (initial=auto runs several).

    Attributes:
        name: The start's name.
        result: The solver's run result.
        d: The returned heights (m, m): the accepted iterate, else the best one a stopping rule kept.
        returned_iteration: The iteration of ``d``.
        rel_discrepancy: The discrepancy of ``d``.
        history: Metric name -> values per iteration, for the figures.
        seconds: Start plus solve time, seconds.
        start_seconds: Computing the start, seconds.
        start_metrics: What computing the start measured.
        errors: The errors of ``d`` against the ground truth (synthetic data), else empty.
    """

    name: str
    result: RunResult
    d: torch.Tensor
    returned_iteration: int
    rel_discrepancy: float
    history: dict[str, list[float]]
    seconds: float
    start_seconds: float
    start_metrics: dict[str, float]
    errors: dict[str, float]

    def summary(self, prefixed: bool) -> dict[str, Any]:
        """The start's metrics (``start_*``), with this run's outcome under ``start_<name>_*`` when
        several starts ran."""
        out = {f"start_{k}": v for k, v in self.start_metrics.items()}
        if prefixed:
            out.update({f"start_{self.name}_rel_discrepancy": self.rel_discrepancy,
                        f"start_{self.name}_iterations": self.result.iterations,
                        f"start_{self.name}_reached_noise_level": float(self.result.accepted),
                        **{f"start_{self.name}_{k}": v for k, v in self.errors.items()}})
        return out

    def saved(self) -> dict[str, Any]:
        """Plain data and tensors for :data:`PHASES` (torch.save with weights_only loading)."""
        r = self.result
        return {"name": self.name, "d": self.d, "returned_iteration": self.returned_iteration,
                "rel_discrepancy": self.rel_discrepancy, "history": self.history, "seconds": self.seconds,
                "start_seconds": self.start_seconds, "start_metrics": self.start_metrics, "errors": self.errors,
                "result": {"iterations": r.iterations, "stop_reason": r.stop_reason, "stopped_by": r.stopped_by,
                           "records": [asdict(x) for x in r.history], "elapsed_s": r.elapsed_s, "accepted": r.accepted,
                           "solver_metrics": r.solver_metrics}}

    @classmethod
    def restored(cls, saved: dict[str, Any]) -> PhaseOutcome:
        """The inverse of :meth:`saved`."""
        r = saved["result"]
        result = RunResult(saved["d"], r["iterations"], r["stop_reason"], r["stopped_by"],
                           [IterationRecord(**x) for x in r["records"]], r["elapsed_s"], r["accepted"],
                           r.get("solver_metrics", {}))
        return cls(saved["name"], result, saved["d"], saved["returned_iteration"], saved["rel_discrepancy"],
                   saved["history"], saved["seconds"], saved["start_seconds"], saved["start_metrics"], saved["errors"])


def resumed_phases(output_dir: Path, checkpoint: Path | None) -> tuple[list[PhaseOutcome], int, list[int]]:
    """The starts an interrupted run in ``output_dir`` had finished, the index of the one its own
    checkpoint belongs to, and the starts (indices) it had added refits of; ([], 0, []) for a fresh
    run or another run's checkpoint."""
    record = output_dir / PHASES
    if checkpoint is None or checkpoint != output_dir / CHECKPOINT or not record.is_file():
        return [], 0, []
    saved = torch.load(record, weights_only=True)
    return ([PhaseOutcome.restored(x) for x in saved["done"]], int(saved["phase"]),
            [int(i) for i in saved.get("refits", [])])
