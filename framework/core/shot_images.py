"""The images of a run, each with its setup: one per shot of a stack (framework/stack/), else the
run's one image; what the figures and the per-shot report show."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from framework.core.problem import Problem
from operators.stack import StackOperator

__all__ = ["Shot", "shots_of"]


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
    if not isinstance(stack, StackOperator):
        raise ValueError(f"data of {len(data.shots)} shots need a stacked operator, not {type(stack).__name__}")
    blocks = stack.blocks(prediction)
    return [Shot(f"shot {i}", _setup(op, w), op.scene.receiver.half_width, shot.target, block / scale, shot.weights)
            for i, (op, w, scale, shot, block) in enumerate(zip(stack.shots, stack.weights, stack.scales, data.shots,
                                                                  blocks))]
