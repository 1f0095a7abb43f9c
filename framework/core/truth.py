"""The ground truth of synthetic data, sealed: the error metrics read it, nothing that shapes the
result does (docs/method.md, "The truth of synthetic data").

Synthetic data are rendered from known heights. Those heights reach a reconstruction only as a
:class:`GroundTruth`, which the run keeps beside the :class:`framework.core.problem.Problem`, never
inside it: a start, a solver, a stopping rule, a calibration, the defect report and a search see
the problem and nothing else. The truth answers one question, how far given heights are from it
(:meth:`GroundTruth.errors`, the metrics), and hands its heights out only to the run's evaluation
outputs (:data:`READERS`: ground_truth.npy, the millimetre deviation maps, the figures' truth
panels); any other module that asks gets :class:`TruthLeak`.
"""

from __future__ import annotations

import math
import sys

import torch
from torch import Tensor

from operators.values import checked_number, described

__all__ = ["GroundTruth", "READERS", "TruthLeak", "height_errors"]

# The modules that may read the truth's heights: the run's evaluation outputs, written after the solve.
READERS = frozenset({"framework.reconstruction.run_outputs", "framework.reconstruction.report_figures"})


class TruthLeak(RuntimeError):
    """A module outside :data:`READERS` asked for the heights of the ground truth."""


def height_errors(d: Tensor, d_true: Tensor, substrate_thickness: float) -> dict[str, float]:
    """The relative errors of heights ``d`` (m, m) against ``d_true`` (m, m), scene units.

    ``rel_error``   = ||(h + d) - (h + d_true)|| / ||h + d_true|| (the paper's and the official code's
    definition, relative to the glass's whole thickness over the substrate of thickness h);
    ``rel_error_d`` = ||d - d_true|| / ||d_true|| (relative to the printed part alone; inf for a
    flat truth).
    """
    if tuple(d.shape) != tuple(d_true.shape):
        raise ValueError(f"d has shape {tuple(d.shape)}, the ground truth {tuple(d_true.shape)}")
    h = checked_number(substrate_thickness, "substrate_thickness", least=0.0, unit="scene units")
    truth = d_true.double()
    norm_total = float(torch.linalg.vector_norm(h + truth))
    if norm_total == 0.0:
        raise ValueError("h + d_true is zero everywhere; the relative error is undefined")
    norm_d = float(torch.linalg.vector_norm(truth))
    diff = float(torch.linalg.vector_norm(d.detach().double().to(truth.device) - truth))
    return {"rel_error": diff / norm_total, "rel_error_d": diff / norm_d if norm_d else math.inf}


class GroundTruth:
    """The heights (m, m), scene units, that synthetic data were rendered from.

    Args:
        heights: The printed heights (m, m); kept as float64.
    """

    __slots__ = ("_heights",)

    def __init__(self, heights: Tensor) -> None:
        if not isinstance(heights, Tensor) or heights.ndim != 2:
            raise ValueError(f"the ground truth must be an (m, m) tensor of heights, got {described(heights)}")
        self._heights = heights.detach().double().clone()

    @property
    def shape(self) -> tuple[int, int]:
        """(m, m)."""
        return (int(self._heights.shape[0]), int(self._heights.shape[1]))

    def errors(self, d: Tensor, substrate_thickness: float) -> dict[str, float]:
        """``rel_error`` and ``rel_error_d`` of heights ``d`` (m, m) (:func:`height_errors`)."""
        return height_errors(d, self._heights, substrate_thickness)

    def read(self) -> Tensor:
        """A copy of the heights (m, m), float64, for the run's evaluation outputs alone; raises
        :class:`TruthLeak` for a caller outside :data:`READERS`."""
        reader = sys._getframe(1).f_globals.get("__name__", "<unknown>")
        if reader not in READERS:
            raise TruthLeak(f"{reader} asked for the ground truth's heights, which only the evaluation outputs "
                            f"({', '.join(sorted(READERS))}) may read: work from the problem's data "
                            "(framework/core/truth.py)")
        return self._heights.clone()
