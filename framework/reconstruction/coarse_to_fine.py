"""Coarse to fine: a run's start solved first on coarser grids, each level started from the last
(docs/method.md, "Coarse to fine").

Level k of L (k = 1 .. L - 1) solves the same problem with the height grid m / 2^(L - k) and the
receiver n / 2^(L - k): the data are the run's own image area-averaged to that receiver (so the
coarse levels see the photo itself, never a new render), the weights likewise, the printed mask
dilated by one sample before it is resampled (a stroke one sample wide stays in it), and the
operator is the run's own with the same photons per receiver pixel (photons x 4^(k - L)). Heights
pass between levels by bilinear interpolation of the samples at linspace(-W, W, m). Each level
runs the configured solver and stopping rules; the noise level a coarse level is held to is the
run's delta (averaging lowers the data's relative noise, so a coarse level stops no later than its
own noise level allows). The finest level is the run itself, from the upsampled heights.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import torch
import torch.nn.functional as F

from framework.core.data import ReconstructionData, resample_image
from framework.core.problem import HeightGrid, Problem
from framework.core.plugin_config import as_mapping
from framework.reconstruction.solvers.proximal_parts import SHAPED_START_FROM
from operators.values import checked_whole

__all__ = ["CoarseToFineSettings", "coarser_problem", "resample_heights"]


@dataclass(frozen=True)
class CoarseToFineSettings:
    """``coarse_to_fine``: ``levels`` grids in all (1: the run's grid alone; 3: 1/4, 1/2 and the full
    resolution), none coarser than ``coarsest`` samples (and receiver pixels) a side; each level
    after the coarsest begins the solver's preconditioner schedule at ``fine_levels_from``
    (``finest``: its last length, as the coarser level placed the broad shape; ``first``: the whole
    schedule again)."""

    levels: int = 1
    coarsest: int = 32
    fine_levels_from: str = "finest"

    @classmethod
    def parse(cls, spec: Any) -> CoarseToFineSettings:
        values = as_mapping(spec or {}, "coarse_to_fine")
        unknown = sorted(set(values) - {"levels", "coarsest", "fine_levels_from"})
        if unknown:
            raise ValueError(f"coarse_to_fine has unknown key(s) {unknown}; its keys are levels, coarsest and "
                             "fine_levels_from")
        begin = values.get("fine_levels_from", "finest")
        if begin not in SHAPED_START_FROM:
            raise ValueError(f"coarse_to_fine.fine_levels_from={begin!r} must be one of {', '.join(SHAPED_START_FROM)} "
                             "(where a finer level's preconditioner schedule begins)")
        return cls(checked_whole(values.get("levels", 1), "coarse_to_fine.levels", 1, 6, example="2"),
                   checked_whole(values.get("coarsest", 32), "coarse_to_fine.coarsest", least=8, example="32"),
                   str(begin))

    def resolutions(self, m: int, n: int) -> list[tuple[int, int]]:
        """The coarse levels' (m, n), coarsest first; empty for a single level."""
        levels = []
        for k in range(1, self.levels):
            factor = 2 ** k
            if min(m, n) // factor < self.coarsest:
                break
            levels.append((m // factor, n // factor))
        return levels[::-1]


def resample_heights(d: torch.Tensor, m: int) -> torch.Tensor:
    """Heights (m0, m0) sampled at linspace(-W, W, m0), resampled bilinearly to (m, m) on the same
    span (align_corners: the end samples stay on the substrate's edges)."""
    if d.shape[-1] == m:
        return d
    out = F.interpolate(d[None, None].double(), size=(m, m), mode="bilinear", align_corners=True)[0, 0]
    return out.to(d.dtype)


def _coarse_mask(mask: torch.Tensor, m: int) -> torch.Tensor:
    """The printed mask (m0, m0) on (m, m): dilated by one sample, then resampled; a sample is
    printed where any of the dilated mask reaches it."""
    grown = F.max_pool2d(mask[None, None].double(), 3, stride=1, padding=1)[0, 0]
    return resample_heights(grown, m) > 0.0


def _coarse_data(data: ReconstructionData, m: int, n: int) -> ReconstructionData:
    def heights(d: torch.Tensor | None) -> torch.Tensor | None:
        return None if d is None else resample_heights(d, m)

    return replace(data, target=resample_image(data.target, n),
                   weights=None if data.weights is None else resample_image(data.weights, n).clamp(0.0, 1.0),
                   mask=_coarse_mask(data.mask, m), design=heights(data.design))


def coarser_problem(problem: Problem, m: int, n: int, photons: int, seed: int) -> Problem:
    """``problem`` on the height grid (m, m) and an n x n receiver, its operator tracing ``photons``
    with ``seed``'s pattern. Refused for a stack of photos (each shot has its own receiver)."""
    if problem.data.shots:
        raise ValueError("coarse_to_fine.levels > 1 reads one photo; a stack of shots runs on its own grid "
                         "(coarse_to_fine.levels=1)")
    operator = problem.operator.variant(photons, seed, n)
    grid = HeightGrid(m, problem.grid.half_width, problem.grid.base)
    return Problem(operator, _coarse_data(problem.data, m, n), grid, operator.scene)
