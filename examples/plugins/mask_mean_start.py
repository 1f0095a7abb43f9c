"""A start plugin in one file: ``initial/mask_mean``, a plate of the known volume over the printed
area, at its mean height.

    [project.entry-points."shape_from_caustics.initial"]
    mask_mean = "examples.plugins.mask_mean_start:MaskMeanStart"

Config ``examples/plugins/conf/initial/mask_mean.yaml``; chosen with ``initial=mask_mean``.
"""

from __future__ import annotations

import torch

from framework.core.contracts.start import Start, StartRequest, StartResult
from operators.values import checked_number


class MaskMeanStart(Start):
    """d0 = V / (|N| a) on the printed area N (cell area a), 0 elsewhere: the known volume V spread
    evenly. Measured data without a volume are refused."""

    name = "mask_mean"

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = checked_number(scale, "initial.scale", least=0.0, example="1.0")

    def __call__(self, request: StartRequest) -> StartResult:
        problem = request.problem
        if problem.data.volume is None:
            raise ValueError("initial=mask_mean needs the deposited volume; set data.volume")
        mask = problem.data.mask
        height = self.scale * problem.data.volume / (float(mask.sum()) * problem.grid.cell_area)
        d = torch.where(mask, height, 0.0).to(problem.operator.dtype)
        return StartResult(d, {"height": height}, self.name)
