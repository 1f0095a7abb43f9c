"""What a run reports of each shot of a stack (framework/stack/stack_data.py): its setup, its
own discrepancy and its share of the summed misfit, for metrics.json, MLflow and the figures."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from framework.core.data import weighted_norm_sq
from framework.core.problem import Problem

__all__ = ["Shot", "shots_of", "shot_metrics", "save_shot_record"]


@dataclass(frozen=True)
class Shot:
    """One image of a run: its label, its setup and its part of the stacked target and prediction.

    Attributes:
        label: ``shot i`` (or ``caustic`` for a run of one image).
        setup: screen_distance, light_x / light_y / light_z (scene units), gain and weight (a
            stack's shot; empty for the one image of a run).
        half_width: The receiver's half width, scene units.
        target, predicted: Its data and the prediction (c, n, n), in the shot's own units (not weighted).
        weights: Its pixel weights (c, n, n), or None (1 everywhere).
    """

    label: str
    setup: dict[str, float]
    half_width: float
    target: torch.Tensor
    predicted: torch.Tensor
    weights: torch.Tensor | None


def _setup(operator: Any, weight: float) -> dict[str, float]:
    scene = operator.scene
    x, y, z = scene.light.position
    return {"screen_distance": -scene.receiver.z, "light_x": x, "light_y": y, "light_z": z,
            "gain": float(operator.gain), "weight": weight}


def shots_of(problem: Problem, prediction: torch.Tensor) -> list[Shot]:
    """The run's images: one per shot of a stack, else the one image."""
    data = problem.data
    if not data.shots:  # one image: its setup is the run's scene (any operator plugin)
        return [Shot("caustic", {}, problem.scene.receiver.half_width, data.target, prediction, data.weights)]
    stack = problem.operator
    blocks = stack.blocks(prediction)
    return [Shot(f"shot {i}", _setup(op, w), op.scene.receiver.half_width, shot.target, block / scale, shot.weights)
            for i, (op, w, scale, shot, block) in enumerate(zip(stack.shots, stack.weights, stack.scales, data.shots,
                                                                  blocks))]


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
