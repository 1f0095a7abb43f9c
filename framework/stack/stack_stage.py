"""The run's stage for a stack of shots (a stage of the run: framework/core/contracts/stage.py):
the nearest shot fitted first where the start lacks the print's shape
(framework/stack/first_fit.py); with ``data.first_fit=lines`` one last start, the nearest shot's
lines searched across basins by every shot's misfit (framework/stack/line_search.py); after the
run every shot's own discrepancy, its share of the misfit and its setup
(framework/stack/shot_report.py, shots.json), with a sentence for each shot the heights do not
explain. A run of one image passes through untouched."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor

from framework.core.contracts.stage import RunStage, SolvedRun, StageReport, StartingRun
from framework.core.contracts.start import Start, StartRequest
from framework.core.problem import Problem
from framework.stack.first_fit import fit_first_shot
from framework.stack.line_search import FeatureSearch, SearchedLines
from framework.stack.shot_report import save_shot_record, shot_metrics

__all__ = ["FIRST_FIT_CALIBRATION", "LINE_SEARCH_PHOTONS", "SHOT_FIT_FACTOR", "StackStage", "unexplained_shots"]

FIRST_FIT_CALIBRATION = "first_fit_calibration.json"  # the nearest shot's gain, fitted before the stack
LINE_SEARCH_PHOTONS = 1 << 18  # photons per shot and hypothesis of the line search
SHOT_FIT_FACTOR = 1.5  # a shot whose own discrepancy exceeds this times its noise level is named


def unexplained_shots(metrics: Mapping[str, float], count: int) -> list[str]:
    """A sentence for each of ``count`` shots whose own discrepancy in ``metrics``
    (:func:`framework.stack.shot_report.shot_metrics`) exceeds :data:`SHOT_FIT_FACTOR` times its
    noise level: the stack may meet its noise level while one photo stays unexplained."""
    lines = []
    for i in range(count):
        discrepancy, delta = metrics[f"shot{i}_rel_discrepancy"], metrics[f"shot{i}_delta"]
        if discrepancy > SHOT_FIT_FACTOR * delta:
            lines.append(f"Shot {i} (screen {metrics[f'shot{i}_screen_distance']:.4g}) is not explained: its own "
                         f"discrepancy {discrepancy:.4g} = {discrepancy / delta:.2f} x its noise level {delta:g} "
                         f"(more than {SHOT_FIT_FACTOR:g} x); check its setup (screen distance or offset, light) "
                         "or raise its weight.")
    return lines


class StackStage(RunStage):
    """The nearest shot first, its lines searched last, and the shots' report (module docstring)."""

    order = 5

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> StackStage:
        return cls()

    def phases(self, problem: Problem, runnable: list[tuple[str, Start]], request: StartRequest
               ) -> list[tuple[str, Start]]:
        """With ``data.first_fit=lines``, one last start: the first start these data can run,
        computed on the nearest shot and searched there (:class:`SearchedLines`)."""
        index = problem.data.first_fit_shot
        if not (problem.data.line_search and runnable and index is not None):
            return []
        nearest = replace(request, problem=problem.shot(index))
        return [(f"{runnable[0][0]}_lines", SearchedLines(runnable[0][1], nearest))]

    def begin(self, run: StartingRun) -> tuple[Tensor, dict[str, float]] | None:
        """The heights that fit the nearest shot alone (``data.first_fit_shot``), from a start
        without the print's shape or a search across basins (whose lines are then searched by
        every shot's misfit); None otherwise."""
        index = run.problem.data.first_fit_shot
        searched = isinstance(run.start, SearchedLines)
        if index is None or (run.shaped and not searched):
            return None
        shot = run.problem.shot(index)
        gain = None if run.calibration is None else run.calibration.gain_of_shot(index)
        if gain is not None:
            gain.setup(shot.data.target, shot.data.weights, shot.data.delta, run.output_dir / FIRST_FIT_CALIBRATION)
        d, metrics = fit_first_shot(run.problem, run.heights, run.solve, [] if gain is None else [gain])
        if searched:
            found, searched_metrics = FeatureSearch(run.problem, LINE_SEARCH_PHOTONS, run.seed)(
                d.detach().cpu().double().numpy())
            d = torch.from_numpy(found).to(d.dtype)
            metrics.update(searched_metrics)
            print(f"line search: {searched_metrics['feature_search_changed']:.0f} of "
                  f"{searched_metrics['feature_search_lines']:.0f} lines remade; the stack's discrepancy "
                  f"{searched_metrics['feature_search_misfit_before']:.4f} -> "
                  f"{searched_metrics['feature_search_misfit_after']:.4f}", flush=True)
        return d, metrics

    def report(self, run: SolvedRun) -> StageReport:
        count = len(run.problem.data.shots)
        if count == 0 or run.prediction is None:
            return StageReport()
        metrics = shot_metrics(run.problem, run.prediction)
        save_shot_record(run.output_dir, metrics, count)
        lines = unexplained_shots(metrics, count)
        for line in lines:
            print(f"verdict: {line}", flush=True)
            print(f"warning: {line}", file=sys.stderr, flush=True)
        return StageReport(metrics, lines)
