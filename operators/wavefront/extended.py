"""Exact caustic of an extended light: the mean of wavefront renders from points over the source.

Each point of a disc or square source (operators/scene.py, ``light.shape``) casts the caustic of a
point light there; the extended light's is their mean. :class:`ExtendedLightReference` renders
it from K points of Vogel's spiral (operators/light_source.py, ``spiral_points``), independent of
the photon operators' R2 emission points, each by the blur-free wavefront renderer
(operators/wavefront/renderer.py) with the power split evenly. K is chosen per render so that
neighbouring points' caustics lie at most a quarter pixel apart on the receiver: the caustic moves
by ``receiver_spread`` per unit the light moves, taken for the thickest glass of the heights
(where it moves most), so K >= area(source) (4 spread / pixel)^2, at least ``MIN_POINTS``.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from operators.light_source import receiver_spread, spiral_points
from operators.scene import Scene
from operators.wavefront.renderer import WavefrontRenderer

__all__ = ["ExtendedLightReference", "MIN_POINTS", "MAX_POINTS"]

MIN_POINTS = 16
MAX_POINTS = 4096
POINT_SPACING_PX = 0.25  # neighbouring source points' caustics at most this many pixels apart


class ExtendedLightReference:
    """Wavefront renders of the point lights over an extended source, averaged (module docstring).

    Args:
        scene: The scene with an extended light.
        vertices: Aim points per side of every wavefront render (WavefrontRenderer).
        fresnel: Fresnel weights at the interfaces.
    """

    deterministic = True  # no sampling noise (framework/data/sources.py)

    def __init__(self, scene: Scene, vertices: int | None = None, fresnel: bool = False) -> None:
        if not scene.light.extended:
            raise ValueError("ExtendedLightReference needs light.shape=disc or square; a point light renders "
                             "by WavefrontRenderer")
        self.scene, self.vertices, self.fresnel = scene, vertices, fresnel
        self.last_points = 0  # source points of the last render

    @property
    def output_shape(self) -> tuple[int, int, int]:
        n = self.scene.receiver.resolution
        return self.scene.channels, n, n

    def points_for(self, max_height: float) -> int:
        """Source points K for heights reaching ``max_height`` above the substrate (module docstring)."""
        light, scene = self.scene.light, self.scene
        index = min(scene.indices)
        spread = receiver_spread(light, scene.substrate.thickness + max(max_height, 0.0), index, -scene.receiver.z)
        area = light.size ** 2 * (math.pi / 4.0 if light.shape == "disc" else 1.0)
        spacing = POINT_SPACING_PX * scene.receiver.pixel_size / spread
        return min(MAX_POINTS, max(MIN_POINTS, math.ceil(area / spacing ** 2)))

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """Irradiance (c, n, n) float64 of the extended light through heights (m, m)."""
        count = self.points_for(float(heights.max()))
        offsets = spiral_points(self.scene.light, count)
        share = self.scene.light.power / len(offsets)
        image = None
        for dx, dy in offsets:
            scene = dataclasses.replace(self.scene, light=self.scene.light.at((float(dx), float(dy)), share))
            part = WavefrontRenderer(scene, vertices=self.vertices, fresnel=self.fresnel).render(heights)
            image = part if image is None else image + part
        self.last_points = len(offsets)
        return image
