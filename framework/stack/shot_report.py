"""What a run reports of each shot of a stack (framework/stack/stack_data.py): its setup, its
own discrepancy and its share of the summed misfit, for metrics.json, MLflow and the figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch

from framework.core.data import weighted_norm_sq
from framework.core.problem import Problem
from framework.core.shot_images import shots_of

__all__ = ["shot_metrics", "save_shot_record"]


def shot_metrics(problem: Problem, prediction: torch.Tensor) -> dict[str, float]:
    """``shot<i>_rel_discrepancy`` (||F_i - b_i|| / ||b_i||), ``shot<i>_misfit_share`` (its part
    of the summed weighted squared misfit), ``shot<i>_delta`` and its setup, for a stack; none for
    one image."""
    if not problem.data.shots:
        return {}
    shots = shots_of(problem, prediction)
    misfits = [s.setup["weight"] * weighted_norm_sq(s.predicted.double() - s.target.double(), s.weights) for s in shots]
    total = sum(misfits) or 1.0
    out: dict[str, float] = {}
    for i, (shot, misfit, data) in enumerate(zip(shots, misfits, problem.data.shots)):
        out[f"shot{i}_rel_discrepancy"] = math.sqrt(
            misfit / shot.setup["weight"] / weighted_norm_sq(shot.target, shot.weights)
        )
        out[f"shot{i}_misfit_share"] = misfit / total
        out[f"shot{i}_delta"] = data.delta
        out.update({f"shot{i}_{key}": value for key, value in shot.setup.items()})
    return out


def save_shot_record(output_dir: Path, metrics: dict[str, float], count: int) -> Path | None:
    """shots.json in ``output_dir``: every shot's setup, noise level, discrepancy and misfit share
    from :func:`shot_metrics` of a stack of ``count`` shots (None for one image)."""
    if not metrics:
        return None
    record = [{key[len(f"shot{i}_"):]: value for key, value in metrics.items() if key.startswith(f"shot{i}_")}
              for i in range(count)]
    path = output_dir / "shots.json"
    path.write_text(json.dumps(record, indent=2))
    return path
