"""A photon operator rendered on a finer receiver and area-averaged: pixels that integrate exactly.

A camera pixel (or a screen pixel of a rectified photo) records the mean irradiance over its
square. The splat approximates that mean by widening every footprint by the pixel box's second
moment (operators/photon_operator.py, PIXEL_BOX_R2), which rounds the box: on print_lines at
n = 128 the render then differs from the exact pixel means by 1.7% (relative L2) however many
photons it traces (docs/method.md, "The irradiance model"). :class:`SupersampledOperator`
renders on a receiver ``factor`` times finer over the same square and averages each
factor x factor block: the box is then exact at the output pixels and the approximation only acts
at the fine ones.

    F(d) = A F_fine(d),   F'(d)^* g = F_fine'(d)^* (A^T g),

A the block mean (c, f n, f n) -> (c, n, n) (operators/linear/block_mean.py).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import torch

from operators.linear.block_mean import BlockMean
from operators.image_operator import WrappingOperator
from operators.photon_operator import PIXEL_SETTINGS
from operators.scene import Scene
from operators.values import checked_whole, is_number

__all__ = ["SupersampledOperator", "build_supersampled", "finer_scene"]


def build_supersampled(make: Callable[[Scene, dict[str, Any]], Any], scene: Scene, settings: dict[str, Any],
                       defaults: Any) -> Any:
    """The operator ``make(scene, settings)`` of an operator plugin's config, rendered ``supersample``
    (a key of ``settings``, default 1) times finer and block-averaged. The footprints in
    ``settings`` (or, where absent, in ``defaults``, the settings dataclass) are in output pixels
    and are scaled to the fine receiver's."""
    settings = dict(settings)
    factor = checked_whole(settings.pop("supersample", 1), "operator.supersample", 1, 16, must="must be an integer "
                           "in 1 .. 16 (receiver pixels rendered per output pixel side; 1: none)")
    for key in PIXEL_SETTINGS:
        value = settings.get(key, getattr(defaults, key))
        if is_number(value):
            settings[key] = value * factor
    fine = make(finer_scene(scene, factor), settings)
    return fine if factor == 1 else SupersampledOperator(fine, scene, factor)


def finer_scene(scene: Scene, factor: int) -> Scene:
    """``scene`` with a receiver of ``factor`` times its resolution over the same square."""
    receiver = dataclasses.replace(scene.receiver, resolution=scene.receiver.resolution * factor)
    return dataclasses.replace(scene, receiver=receiver)


class SupersampledOperator(WrappingOperator):
    """``fine``, an operator on a receiver ``factor`` times finer than ``scene``'s, seen through the
    block mean (module docstring): images (c, n, n) on ``scene``'s receiver.

    Its light path, elements, hit cache, camera gain and warm-up are ``fine``'s
    (:class:`operators.photon_operator.WrappingOperator`); ``scene`` is the configured one, which
    code outside the operator reads.
    """

    def __init__(self, fine: Any, scene: Scene, factor: int) -> None:
        self.mean = BlockMean(factor)
        if fine.output_shape[-1] != scene.receiver.resolution * self.mean.factor:
            raise ValueError(f"the fine operator renders {fine.output_shape[-1]} pixels, not "
                             f"{self.mean.factor} x {scene.receiver.resolution}")
        self.fine, self.scene, self.factor = fine, scene, self.mean.factor

    @property
    def wrapped(self) -> Any:
        """The fine operator."""
        return self.fine

    @property
    def conserves_energy(self) -> bool:
        return bool(self.fine.conserves_energy)

    @property
    def pixel_area(self) -> float:
        """Area of one output pixel, scene units^2."""
        return self.scene.receiver.pixel_size ** 2

    @property
    def output_shape(self) -> tuple[int, int, int]:
        n = self.scene.receiver.resolution
        return (self.scene.channels, n, n)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """The block mean of the fine render (c, n, n), W per scene unit^2."""
        return self.mean.apply(self.fine.render(heights, progress=progress))

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F_fine'(d)^* (A^T grad_image) (m, m)."""
        if tuple(grad_image.shape) != self.output_shape:
            raise ValueError(f"grad_image has shape {tuple(grad_image.shape)}, expected {self.output_shape}")
        return self.fine.vjp(heights, self.mean.adjoint(grad_image))

    def jvp(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """A F_fine'(d) v (c, n, n)."""
        return self.mean.apply(self.fine.jvp(heights, direction))

    def variant(self, photons: int, seed: int, resolution: int) -> SupersampledOperator:
        """The same supersampling of the fine operator's variant for an n = ``resolution`` output."""
        coarse = dataclasses.replace(
            self.scene, receiver=dataclasses.replace(self.scene.receiver, resolution=resolution)
        )
        return SupersampledOperator(self.fine.variant(photons, seed, resolution * self.factor), coarse, self.factor)

    def exact_variant(self, photons: int, seed: int, resolution: int) -> Any:
        """The fine operator's exact references (:meth:`ImageOperator.exact_variant`) at ``resolution``."""
        return self.fine.exact_variant(photons, seed, resolution)

    def describe(self) -> dict[str, float]:
        """The fine operator's sampling figures and the supersampling factor."""
        return {**self.fine.describe(), "supersample": float(self.factor)}

    @property
    def gain(self) -> float:  # type: ignore[override]
        return self.fine.gain
