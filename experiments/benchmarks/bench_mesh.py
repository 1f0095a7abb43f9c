"""sfc-bench's mesh-scene section (experiments/benchmarks/bench.py): the mesh-scene operator on the plain
scene and through the paper's two lenses, beside the height-field operator, forward, forward +
backward and a solver's iteration, side by side in one run."""

from __future__ import annotations

import math

import numpy as np
import torch

from experiments.benchmarks.timing import best_seconds
from operators.emission import CELL_FOOTPRINT, check_footprint

__all__ = ["mesh_footprint", "mesh_scene_operators", "time_mesh_scenes"]


def mesh_footprint(value: str) -> float | str | None:
    """--mesh-footprint's value as the operators check a footprint (operators/emission.py): 'cell'
    or a number of pixels > 0; None where it is neither."""
    try:
        return check_footprint(value if value == CELL_FOOTPRINT else float(value))
    except ValueError:
        return None


def mesh_scene_operators(photons: int, footprint_px: float | str, supersample: int) -> dict[str, object]:
    """The height-field operator (conf/operator/height_field.yaml) and the mesh-scene operator on
    the plain scene and through the paper's two lenses (conf/operator/mesh_scene.yaml,
    two_lenses.yaml; with the C event kernels, the numba ones, and the torch tracer that both are
    tested against), each from its config with the same photons, footprint and receiver
    (``supersample`` x finer, operators/supersample.py)."""
    from experiments.apps.configs import app_config
    from framework.scene.scene_config import build_operator, build_scene

    def configured(name: str, *extra: str) -> object:
        cfg = app_config("simulate", [f"operator={name}", f"photons={photons}", f"operator.footprint_px={footprint_px}",
                                      f"operator.supersample={supersample}", *extra])
        return build_operator(cfg, build_scene(cfg))

    return {"height_field": configured("height_field"),
            "mesh_scene_plain": configured("mesh_scene"), "mesh_scene_two_lenses": configured("two_lenses"),
            "mesh_scene_two_lenses_numba": configured("two_lenses", "operator.kernels=numba"),
            "mesh_scene_two_lenses_torch_tracer": configured("two_lenses", "operator.native=false")}


def time_mesh_scenes(heights: torch.Tensor, photons: int, footprint_px: float | str,
                     supersample: int, pairs: int = 5) -> dict[str, dict[str, float]]:
    """Forward and forward + backward photons/s of :func:`mesh_scene_operators`, side by side
    (the best of two rounds that run them in turn), and a solver's iteration: a render, then the
    gradient at the same heights from that render's image (framework/core/objective.py), which
    the mesh operator takes from the render's logged events. Its time over the height-field
    operator's is the median of ``pairs`` ratios, each of an iteration and the height-field
    operator's iteration run just before it, so that both see the same background load;
    ``iteration_seconds`` is the best of those iterations."""
    ops = mesh_scene_operators(photons, footprint_px, supersample)
    names = list(ops)
    targets = {name: op.render(torch.zeros_like(heights)) for name, op in ops.items()}
    best = {name: [math.inf, math.inf, math.inf] for name in names}

    def iteration(name: str) -> float:
        op, target = ops[name], targets[name]
        return best_seconds(lambda: op.loss_and_grad(heights, target, image=op.render(heights)), repeats=1)

    for _ in range(2):
        for name in names:
            op, target = ops[name], targets[name]
            best[name][0] = min(best[name][0], best_seconds(lambda: op.render(heights), repeats=1))
            best[name][1] = min(best[name][1], best_seconds(lambda: op.loss_and_grad(heights, target), repeats=1))
    ratios: dict[str, list[float]] = {name: [] for name in names}
    for _ in range(pairs):
        for name in names:
            reference = iteration("height_field")
            step = reference if name == "height_field" else iteration(name)
            best["height_field"][2] = min(best["height_field"][2], reference)
            best[name][2] = min(best[name][2], step)
            ratios[name].append(step / reference)
    plain, height_field = best["mesh_scene_plain"], best["height_field"]
    return {name: {"forward_photons_per_s": photons / forward, "forward_backward_photons_per_s": photons / gradient,
                   "gradient_time_over_plain_mesh_scene": gradient / plain[1],
                   "gradient_time_over_height_field": gradient / height_field[1],
                   "iteration_seconds": step,
                   "iteration_ratios": ratios[name],
                   "iteration_time_over_height_field": float(np.median(ratios[name]))}
            for name, (forward, gradient, step) in best.items()}
