"""Beyond the paper: the known volume held exactly, within a tolerance, after every step.

V1 (eq. (8)) keeps the height sum in a wide band (25%) by nudging it; a print whose volume is
known should come out with that volume unless the data contradict it. With too much glass this
post step moves every printed sample by one common amount lambda, the Euclidean projection onto

    {p1 <= d_j <= p2 on N^, d_j = 0 on N°, V (1 - eps) / a <= sum_{N^} d_j <= V (1 + eps) / a}

(the volume prox of regularizers/volume_prox.py without its L1 term): d_j <- clamp_[p1,p2](d_j -
lambda) on N^, lambda = 0 when the sum already lies in the band. With too little it does the same on
the samples above p1 only: lifting the bare plate would put a step where the printed area ends, and
flat glass (a start that must grow the print) stays flat. Measured on every built-in scene in
docs/results.md ("The volume held").
"""

from __future__ import annotations

import torch

from operators.values import checked_height_field

from ._checks import checked_bounds, checked_relative_tolerance
from .base import PostStepUpdate, RegularizerContext
from .shrinkage import clamp_on_mask
from .volume_heuristic import VolumeBand
from .volume_prox import slab_multiplier


class VolumeHold(VolumeBand, PostStepUpdate):
    """Bring d onto the bounds, the mask and the volume band of relative width ``tolerance`` (module
    docstring: lowering is the Euclidean projection, raising moves the samples above p1 only).

    Args:
        tolerance: Relative volume tolerance eps in [0, 1) (0.02: within 2% of the known volume).
        p1: Lower height bound (scene units), that of the pixel regulariser (l1_bounds).
        p2: Upper height bound (scene units), likewise.
    """

    length_keys = ("p1", "p2")  # may be given with a unit, e.g. '0.4 mm' (framework/core/plugin_config.py)

    needs_volume = (
        True  # the run's checks refuse measured data without data.volume (framework/reconstruction/run_checks.py)
    )

    holds_volume = True  # a stack's calibrated distance moves without a factor on the heights (calibration.py)

    def __init__(self, tolerance: float = 0.02, p1: float = 0.0, p2: float = 0.3) -> None:
        self.tolerance = checked_relative_tolerance(tolerance, "tolerance")
        self.p1, self.p2 = checked_bounds(p1, p2)

    def setup(self, ctx: RegularizerContext) -> None:
        """Store the context and the band [q1, q2] (a sum of heights); refuse a band the bounds cannot
        reach on the mask."""
        super().setup(ctx)
        self.set_band(ctx, self.tolerance, "volume_hold", (self.p1, self.p2))

    def __call__(self, d: torch.Tensor) -> torch.Tensor:
        """d (m, m) held in bounds, mask and band; a new tensor of d's dtype and device."""
        checked_height_field(d)
        printed = self._mask_for(d)
        moving = printed
        if float(torch.clamp(d[printed], self.p1, self.p2).sum()) < self.band[0]:  # raise only the glass there is
            moving = printed & (d > self.p1)
            if not bool(moving.any()):
                return d.clone()
        shift = slab_multiplier(d.detach().to(torch.float64)[moving], 0.0, self.p1, self.p2, self.band)
        held = torch.clamp(d - shift, self.p1, self.p2)
        return torch.where(moving, held, clamp_on_mask(d, printed, self.p1, self.p2))
