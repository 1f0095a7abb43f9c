"""A bound on the light that meets the printed top a second time (docs/method.md, "Steep flanks").

The height-field operator refracts a photon into the glass at its first hit on the top and does
not test the refracted ray against the top again. Below the hit the gap g(t) = z(t) - S(x(t), y(t))
between the ray and the surface starts at 0 and changes at the rate
w_z - grad S . w_xy <= w_z + b_x |w_x| + b_y |w_y|, with b_x, b_y the grid's bounds on the slopes
(:meth:`operators.heightfield.surface.HeightFieldGrid.slope_bounds`). Where that rate is negative
the ray stays below the surface all the way down: it cannot meet the top again. The light of the
other photons is an upper bound on what the operator misses at steep flanks.
"""

from __future__ import annotations

import torch

from operators.heightfield.surface import HeightFieldGrid, intersect_height_field
from operators.optics.reference import height_field_normal, refract
from operators.photon_operator import PhotonOperator


def remeet_bound(operator: PhotonOperator, heights: torch.Tensor) -> float:
    """Fraction (0 .. 1) of the light entering the top of ``heights`` (m, m) whose refracted ray
    may meet the top again (module docstring), over the photons of a height-field ``operator``
    (:class:`operators.heightfield.operator.CausticOperator`), traced chunk by chunk in float64."""
    scene = operator.scene
    d = heights.detach().to(device="cpu", dtype=torch.float64)
    grid = HeightFieldGrid(scene.substrate.thickness, scene.substrate.half_width, d.shape[0])
    slope_x, slope_y = grid.slope_bounds(d.numpy())
    glass = torch.tensor(scene.indices, dtype=torch.float64)
    flagged = total = 0.0
    for start, stop in operator.chunks():
        batch = operator.emitter.batch(start, stop)
        origin, direction = batch.origin.double(), batch.direction.double()
        _, jet = intersect_height_field(d, grid, origin, direction)
        normal = height_field_normal(jet)
        inside, _, _, _, _ = refract(direction, batch.direction_diff.double(), normal, None,
                                     1.0 / glass[batch.channel])
        rate = inside[2] + slope_x * inside[0].abs() + slope_y * inside[1].abs()
        flux = batch.flux.double()
        flagged += float(flux[rate >= 0.0].sum())
        total += float(flux.sum())
    return flagged / total
