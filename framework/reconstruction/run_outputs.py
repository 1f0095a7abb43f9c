"""What a finished reconstruction leaves in its run directory besides metrics.json and the
figures: the arrays, the millimetre outputs with the deviation from the design, and the verdict."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any
from collections.abc import Sequence

import numpy as np
import torch

from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid
from framework.core.truth import GroundTruth
from framework.files.mm_outputs import export_outputs
from framework.reconstruction.verdict import run_verdict

__all__ = ["save_outputs", "report_verdict"]


def save_outputs(output_dir: Path, d: torch.Tensor, prediction: torch.Tensor, data: ReconstructionData,
                 grid: HeightGrid, mm_per_unit: float, truth: GroundTruth | None) -> dict[str, Any]:
    """Write height_field.npy (float64, scene units), the target, predicted (and weights) caustics
    and the ground truth of synthetic data (``truth``) as .npy, and the mm outputs (export/);
    returns the ``deviation_*`` metrics against the print's design, or for synthetic data of the
    configured print against its truth (none without either, which is then said on stdout)."""
    np.save(output_dir / "height_field.npy", d.cpu().numpy().astype(np.float64))
    np.save(output_dir / "caustic_target.npy", data.target.cpu().numpy().astype(np.float32))
    np.save(output_dir / "caustic_predicted.npy", prediction.detach().cpu().numpy().astype(np.float32))
    if data.weights is not None:
        np.save(output_dir / "caustic_weights.npy", data.weights.cpu().numpy().astype(np.float32))
    truth_heights = None if truth is None else truth.read()
    if truth_heights is not None:
        np.save(output_dir / "ground_truth.npy", truth_heights.cpu().numpy().astype(np.float64))
    design = data.design if data.design is not None else truth_heights
    exported = export_outputs(output_dir / "export", d.cpu().numpy(), grid.half_width, grid.base, mm_per_unit,
                              design=None if design is None else design.cpu().numpy())
    if design is None:
        print("no design given (height_field.path, data.mask=design or initial=design): no deviation report",
              flush=True)
    return {f"deviation_{key}": value for key, value in exported["deviation"].items()}


def report_verdict(rel_discrepancy: float, data: ReconstructionData, tau_dis: float, returned_iteration: int,
                   stop_reason: str, volume: dict[str, Any], never_calibrated: Sequence[str] = ()) -> dict[str, Any]:
    """The run's verdict (framework/reconstruction/verdict.py): ``verdict:`` lines on stdout, a
    ``warning:`` line on stderr for each goal missed; ``never_calibrated``: calibrated parameters
    no update moved. Returns its metrics (the stages add theirs, framework/core/contracts/stage.py)."""
    verdict = run_verdict(rel_discrepancy, data.delta, tau_dis, returned_iteration, stop_reason, volume,
                          data.weights, data.left_out, never_calibrated)
    for line in verdict.lines:
        print(f"verdict: {line}", flush=True)
    for line in verdict.warnings:
        print(f"warning: {line}", file=sys.stderr, flush=True)
    return verdict.metrics()
