"""An operator plugin in one file: ``operator/shadow``, a linear stand-in for the caustic. Each
height sample lights a square of receiver pixels: F(d) = 1 + gain * U d, U the nearest-neighbour
upsampling from the m x m heights to the n x n receiver (n a multiple of m).

    [project.entry-points."shape_from_caustics.operator"]
    shadow = "examples.plugins.shadow_operator:ShadowOperator"

Config ``examples/plugins/conf/operator/shadow.yaml``; chosen with ``operator=shadow``
(docs/plugins.md, "A newcomer's path").
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F

from operators.image_operator import ImageOperator


class ShadowOperator(ImageOperator):
    """F(d) = 1 + gain * U d on the scene's receiver; float64. The base
    (operators/photon_operator.py) gives the loss, its gradient and autograd from render and vjp."""

    dtype = torch.float64

    def __init__(self, channels: int, resolution: int, half_width: float, photons: int, gain: float) -> None:
        self.channels, self.resolution, self.half_width = channels, resolution, half_width
        self.photons, self.gain = photons, gain
        self.pixel_area = (2.0 * half_width / resolution) ** 2

    @classmethod
    def from_config(cls, scene: Any, photons: int, seed: int, gain: float = 1.0) -> ShadowOperator:
        if not gain > 0:
            raise ValueError(f"operator.gain={gain!r} must be positive")
        return cls(scene.channels, scene.receiver.resolution, scene.receiver.half_width, photons, float(gain))

    @property
    def output_shape(self) -> tuple[int, int, int]:
        return (self.channels, self.resolution, self.resolution)

    def variant(self, photons: int, seed: int, resolution: int) -> ShadowOperator:
        return ShadowOperator(self.channels, resolution, self.half_width, photons, self.gain)

    def _factor(self, heights: torch.Tensor) -> int:
        """Receiver pixels per height sample along each axis."""
        if heights.ndim != 2 or heights.shape[0] != heights.shape[1] or self.resolution % heights.shape[0]:
            raise ValueError(f"heights of shape {tuple(heights.shape)}: the shadow operator takes (m, m) with m "
                             f"dividing the receiver's {self.resolution} pixels")
        if not bool(torch.isfinite(heights).all()):
            raise ValueError("heights contain NaN or infinite values")
        return self.resolution // heights.shape[-1]

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        factor = self._factor(heights)
        lit = F.interpolate(heights.detach().to(self.dtype)[None, None], scale_factor=factor, mode="nearest")[0]
        return (1.0 + self.gain * lit).expand(self.output_shape).clone()

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """gain U^T summed over channels: each sample collects its block of pixels."""
        factor = self._factor(heights)
        blocks = F.avg_pool2d(grad_image.to(self.dtype).sum(0)[None, None], factor)[0, 0]
        return self.gain * factor ** 2 * blocks
