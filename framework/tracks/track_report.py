"""The report of a tracks fit: tracks.json (the fitted beads, mm) and tracks_nominal.json
(:func:`tracks_verdict`), and the defects read from the tracks against their nominal profiles
(framework/tracks/track_defects.py) as defects.json / defects.csv / defects.png and ``verdict:``
lines.

A defect's evidence is what the photo loses when the defect is undone: the run's knots set back to
their nominal values, rendered once, the misfit's growth in pixel noise variances (the secant
curvature of the data term along the change); its confidence is the square root (standard
deviations of the change).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from framework.core.problem import Problem
from framework.defects.fit import Defect
from framework.core.pixel_noise import pixel_noise
from framework.defects.report import defect_lines, kind_counts, save_defect_figure, save_defect_table
from framework.tracks.track_defects import (KnotRun, TrackTolerances, drop_defects, gap_defects, placed_drop_defects,
                                           track_defects)
from framework.tracks.track_heights import TrackHeights

__all__ = ["TrackReport", "report_tracks", "fitted_tracks", "track_tolerances", "tracks_verdict"]


def fitted_tracks(fitted: Any) -> tuple[TrackHeights, torch.Tensor] | None:
    """(representation, theta) where a run fitted tracks (RunResult.fitted), else None."""
    if isinstance(fitted, tuple) and len(fitted) == 2 and isinstance(fitted[0], TrackHeights):
        return fitted[0], fitted[1]
    return None


def track_tolerances(settings: Any) -> TrackTolerances:
    """The ``defects`` group's settings for tracks (conf/reconstruct.yaml)."""
    return TrackTolerances(height=settings.track_height, width=settings.track_width,
                           offset_mm=settings.track_offset_mm, min_drop_mm3=settings.min_drop_mm3,
                           z_min=settings.z_min)


def tracks_verdict(representation: TrackHeights, theta: torch.Tensor, output_dir: Path) -> list[str]:
    """Write the fitted tracks (tracks.json, mm) and the nominal ones (tracks_nominal.json) into
    ``output_dir``; what the run fitted, in one sentence."""
    fitted = representation.track_set(theta)
    fitted.save(output_dir / "tracks.json")
    representation.nominal.save(output_dir / "tracks_nominal.json")
    source = representation.source
    return [f"Fitted as {len(fitted.tracks)} tracks ({source}) with a residual grid of "
            f"{representation.settings.residual_mm:g} mm; the beads' heights "
            f"{min(float(t.height.mean()) for t in fitted.tracks):.2f}-"
            f"{max(float(t.height.mean()) for t in fitted.tracks):.2f} mm, widths "
            f"{min(float(t.width.mean()) for t in fitted.tracks):.2f}-"
            f"{max(float(t.width.mean()) for t in fitted.tracks):.2f} mm (tracks.json)."]


@dataclass(frozen=True)
class TrackReport:
    """The defects (most evident first) and the report's sentences."""

    defects: list[Defect]
    lines: list[str]
    seconds: float

    def metrics(self) -> dict[str, Any]:
        return {**kind_counts(self.defects), "defects_from": "tracks", "defects_time_s": self.seconds}


def _misfit(problem: Problem, d: torch.Tensor) -> float:
    """||F(d) - b||_W^2, by the problem's data term (framework/core/objective.py)."""
    fidelity = problem.fidelity
    discrepancy = fidelity.evaluate(d.to(problem.operator.dtype), with_grad=False).rel_discrepancy
    return discrepancy**2 * fidelity.target_norm_sq


def report_tracks(problem: Problem, representation: TrackHeights, theta: torch.Tensor, tolerances: TrackTolerances,
                  output_dir: Path) -> TrackReport:
    """Write the fitted tracks and their defect report into ``output_dir`` (module docstring)."""
    began = time.perf_counter()
    mm = representation.mm
    nominal, fitted = representation.nominal, representation.track_set(theta)
    variance = pixel_noise(problem.data.target, problem.data.delta, problem.data.weights) ** 2
    at_fit = _misfit(problem, representation.heights(theta))
    start = representation.initial()

    def confidence(run: KnotRun) -> float:
        reverted = theta.clone()
        for block in representation.profile_slices(run.track):
            span = slice(block.start + run.first, block.start + run.last + 1)
            reverted[span] = start[span]
        return gain(reverted)

    def gain(reverted: torch.Tensor) -> float:
        grown = (_misfit(problem, representation.heights(reverted)) - at_fit) / variance
        return float(np.sqrt(max(grown, 0.0)))

    def drop_confidence(blob: np.ndarray) -> float:
        reverted = theta.clone()
        reverted[representation.residual_indices(blob)] = 0.0
        return gain(reverted)

    placed = representation.placed_drops(theta)

    def placed_confidence(i: int) -> float:
        reverted = theta.clone()
        reverted[placed[i][0] + 3] = 0.0
        return gain(reverted)

    values = theta.detach().cpu().double().numpy()
    opened = [(k, j) for k in range(len(nominal.tracks))
              for j in representation.gap_slots(k) if values[j + 1] > 0.0]

    def gap_confidence(i: int) -> float:
        reverted = theta.clone()
        reverted[opened[i][1] + 1] = 0.0
        return gain(reverted)

    defects = track_defects(nominal, fitted, tolerances, confidence)
    defects += gap_defects(fitted, [(k, values[j] * mm, values[j + 1] * mm) for k, j in opened], tolerances,
                           gap_confidence)
    defects += placed_drop_defects([drop for _, drop in placed], tolerances, placed_confidence)
    cell_mm = representation.cell * mm
    defects += drop_defects(representation.residual(theta).cpu().numpy() * mm, cell_mm, tolerances, drop_confidence)
    defects.sort(key=lambda d: -d.confidence)
    lines = defect_lines(defects, tolerances.z_min**2, 0, tolerances.height, tolerances.offset_mm)
    report = TrackReport(defects, lines, time.perf_counter() - began)
    save_defect_table(output_dir, defects, tolerances, report.metrics())
    d = representation.heights(theta).cpu().numpy() * mm
    design = representation.heights(start).cpu().numpy() * mm
    save_defect_figure(output_dir / "defects.png", d - design, design, defects, representation.half_width * mm,
                       tolerances.z_min**2)
    for line in lines:
        print(f"verdict: {line}", flush=True)
    return report
