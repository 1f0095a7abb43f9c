"""The photons under way in the mesh-scene operator's torch tracer (operators/mesh/operator.py):
their state, the printed top they may meet, the substrate's walls and bottom, and mirror
reflection with differentials."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from operators.heightfield.surface import HeightFieldGrid

__all__ = ["AIR", "Rays", "Surface", "box_planes", "reflect"]

AIR = -1  # the medium of a photon in air (else an element's index, or the element count: the substrate)


def reflect(direction: torch.Tensor, d_direction: torch.Tensor, normal: torch.Tensor,
            d_normal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror reflection r = w - 2 (w . n) n with its differentials (Igehy 1999)."""
    cos = (direction * normal).sum(0)
    d_cos = (d_direction * normal).sum(1) + (direction * d_normal).sum(1)  # (2, N)
    reflected = direction - 2 * cos * normal
    d_reflected = d_direction - 2 * (d_cos.unsqueeze(1) * normal + cos * d_normal)
    return reflected, d_reflected


@dataclass
class Rays:
    """Photons under way: position, direction (3, N), their differentials (2, 3, N), flux (N,),
    medium (N,): AIR, an element's index, or the substrate's (the element count)."""

    position: torch.Tensor
    d_position: torch.Tensor
    direction: torch.Tensor
    d_direction: torch.Tensor
    flux: torch.Tensor
    medium: torch.Tensor

    def take(self, index: torch.Tensor) -> Rays:
        """The photons at ``index``."""
        return Rays(self.position[:, index], self.d_position[:, :, index], self.direction[:, index],
                     self.d_direction[:, :, index], self.flux[index], self.medium[index])

    def put(self, index: torch.Tensor, part: Rays) -> Rays:
        """These photons with those at ``index`` replaced by ``part`` (differentiable)."""
        return Rays(self.position.index_copy(1, index, part.position),
                     self.d_position.index_copy(2, index, part.d_position),
                     self.direction.index_copy(1, index, part.direction),
                     self.d_direction.index_copy(2, index, part.d_direction),
                     self.flux.index_copy(0, index, part.flux), self.medium.index_copy(0, index, part.medium))


@dataclass(frozen=True)
class Surface:
    """The printed top: its grid, heights (m, m) and a plane above its highest point."""

    grid: HeightFieldGrid
    heights: torch.Tensor
    top_max: float


def box_planes(position: torch.Tensor, direction: torch.Tensor, half: float, height: float,
                in_air: torch.Tensor, in_sub: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Distance (N,) to the first of the substrate's walls (x, y = +-half, 0 <= z <= height) and
    bottom (z = 0, |x|, |y| <= half) that a ray meets: leaving for rays inside, entering for rays in
    air; and that plane's outward normal (3, N)."""
    n = direction.shape[1]
    best = torch.full((n,), math.inf, dtype=direction.dtype)
    normal = torch.zeros(3, n, dtype=direction.dtype)
    for axis, value, outward in ((0, half, 1.0), (0, -half, -1.0), (1, half, 1.0), (1, -half, -1.0), (2, 0.0, -1.0)):
        w = direction[axis]
        safe = torch.where(w.abs() > 1e-12, w, torch.ones_like(w))
        t = (value - position[axis]) / safe
        point = position + t * direction
        others = [k for k in range(3) if k != axis]
        inside_face = torch.ones(n, dtype=torch.bool)
        for k in others:
            inside_face &= (point[k] >= 0.0) & (point[k] <= height) if k == 2 else point[k].abs() <= half
        leaving = in_sub & (w * outward > 0)
        entering = in_air & (w * outward < 0)
        ok = (leaving | entering) & (w.abs() > 1e-12) & (t > 1e-9) & inside_face & (t < best)
        best = torch.where(ok, t, best)
        unit = torch.zeros(3, 1, dtype=direction.dtype)
        unit[axis] = outward
        normal = torch.where(ok, unit.expand(3, n), normal)
    return best, normal
