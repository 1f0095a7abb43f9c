"""What the photon operators share, on the operator contract (operators/image_operator.py).

:class:`PhotonOperator` adds, for a subclass with ``scene``, ``settings`` (photons, seed,
chunk_size and the footprints in pixels) and ``emitter``: photon count, image shape, chunks,
resampled variants, and ``render``/``vjp`` as the splatted irradiance E(d) of the subclass
(``render_irradiance``/``vjp_irradiance``) seen through its :attr:`PhotonOperator.image_chain`,
F(d) = C E(d) and F'(d)^* g = E'(d)^* C^T g, C an extended light's patch blur (operators/linear/).
:func:`backward_through_splat` sends an image gradient back through the
splat's adjoint (a gather per photon, no image needed) into whatever a chunk of photons depends on.
"""

from __future__ import annotations

import dataclasses
from abc import abstractmethod
from typing import Any

import torch

from operators.image_operator import ImageOperator
from operators.linear import GaussianBlur, LinearMap
from operators.scene import Scene
from operators.splat.splat import footprint_metric, splat_photons_vjp

__all__ = [
    "PIXEL_SETTINGS",
    "PIXEL_BOX_R2",
    "PhotonOperator",
    "backward_through_splat",
    "check_setting_keys",
    "filter_radius_px",
]

# Settings given in receiver pixels: a render at another receiver resolution scales them.
PIXEL_SETTINGS = ("footprint_px", "min_footprint_px", "max_pixel_radius")

# A pixel that averages the irradiance over its area blurs by a unit box: per axis a variance of
# 1/12 pixel^2. Silverman's kernel of radius R has a per-axis variance of R^2 / 8, so the box is
# matched in its second moment by widening every footprint by 8/12 pixel^2 in quadrature
# (docs/method.md, "Pixel integration").
PIXEL_BOX_R2 = 2.0 / 3.0


def filter_radius_px(min_footprint_px: float, pixel_integration: bool) -> float:
    """Radius (pixels) added in quadrature to every footprint: the pixel filter ``min_footprint_px``
    and, with ``pixel_integration``, the pixel's own area (:data:`PIXEL_BOX_R2`)."""
    return (min_footprint_px ** 2 + (PIXEL_BOX_R2 if pixel_integration else 0.0)) ** 0.5


def check_setting_keys(
    settings: dict[str, Any], settings_class: type, plugin: str, extra: tuple[str, ...] = ()
) -> None:
    """Refuse a key of the ``operator`` group that is not a field of ``settings_class`` (photons and
    seed come from the run) or one of ``extra``, naming the keys the plugin takes."""
    fields = {f.name for f in dataclasses.fields(settings_class)} - {"photons", "seed"}
    for key in settings:
        if key not in fields and key not in extra:
            raise ValueError(f"unknown key operator.{key}; operator/{plugin} takes: "
                             f"{', '.join([*extra, *sorted(fields)])}")


class PhotonOperator(ImageOperator):
    """Base of the photon operators (see the module docstring)."""

    scene: Scene
    settings: Any
    emitter: Any

    @property
    def photons(self) -> int:
        """Photons actually traced per evaluation (a multiple of the channel count)."""
        return self.emitter.total

    @property
    def output_shape(self) -> tuple[int, int, int]:
        n = self.scene.receiver.resolution
        return (self.scene.channels, n, n)

    @property
    def pixel_area(self) -> float:
        """Area of one receiver pixel, scene units^2."""
        return self.scene.receiver.pixel_size ** 2

    @property
    def image_chain(self) -> LinearMap:
        """C, the linear map from the splatted irradiance to the image: the blur of an extended
        light's patches on this receiver (operators/emission.py; a delta for a point light)."""
        return GaussianBlur(self.emitter.source_blur_sigma, self.scene.receiver.pixel_size)

    @abstractmethod
    def render_irradiance(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """E(d) (c, n, n), W per scene unit^2: the photons splatted onto the receiver, no graph."""

    @abstractmethod
    def vjp_irradiance(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """E'(d)^* grad_image (m, m) for a gradient (c, n, n) of the splatted irradiance."""

    def jvp_irradiance(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """E'(d) v (c, n, n), for a subclass that declares ``has_jvp``."""
        raise NotImplementedError(f"{type(self).__name__} has no Jacobian-vector product (has_jvp is False)")

    def jvp(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """F'(d) v = C E'(d) v (c, n, n) in the operator's dtype, on the device of ``heights``."""
        if tuple(direction.shape) != tuple(heights.shape):
            raise ValueError(f"the direction has shape {tuple(direction.shape)}, the heights {tuple(heights.shape)}")
        image = self.image_chain.apply(self.jvp_irradiance(heights, direction))
        return image.to(dtype=self.dtype, device=heights.device)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """F(d) = C E(d) (c, n, n) in the operator's dtype, on the device of ``heights``."""
        image = self.image_chain.apply(self.render_irradiance(heights, progress))
        return image.to(dtype=self.dtype, device=heights.device)

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* grad_image = E'(d)^* (C^T grad_image) (m, m)."""
        if tuple(grad_image.shape) != self.output_shape:
            raise ValueError(f"grad_image has shape {tuple(grad_image.shape)}, expected {self.output_shape}")
        return self.vjp_irradiance(heights, self.image_chain.adjoint(grad_image))

    @property
    def _to_pixels(self) -> float:
        """Receiver pixels per scene unit."""
        return self.scene.receiver.resolution / (2.0 * self.scene.receiver.half_width)

    def receiver_pixels(self, position: torch.Tensor, footprint: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Splat inputs from photons on the receiver: positions (2, N) and footprints (2, 2, N)
        in scene units -> pixel positions (2, N) and footprint metrics (3, N)."""
        pos = (position + self.scene.receiver.half_width) * self._to_pixels - 0.5
        metric = footprint_metric(footprint * self._to_pixels,
                                  filter_radius_px(self.settings.min_footprint_px, self.settings.pixel_integration),
                                  self.settings.max_pixel_radius)
        return pos, metric

    def chunks(self) -> list[tuple[int, int]]:
        """Photon index ranges of at most ``settings.chunk_size``, each from one emission point
        (the emitter's segments split)."""
        size = self.settings.chunk_size
        return [(a, min(a + size, stop)) for start, stop in self.emitter.segments() for a in range(start, stop, size)]

    def resampled(self, photons: int, seed: int, resolution: int) -> tuple[Scene, Any]:
        """Scene and settings of the same physics with another sampling (photons, seed, an
        n = resolution receiver), footprints in pixels scaled so that it blurs like this one."""
        zoom = resolution / self.scene.receiver.resolution
        scaled = {key: getattr(self.settings, key) * zoom for key in PIXEL_SETTINGS
                  if not isinstance(getattr(self.settings, key), str)}  # "cell" footprints scale themselves
        receiver = dataclasses.replace(self.scene.receiver, resolution=resolution)
        return (dataclasses.replace(self.scene, receiver=receiver),
                dataclasses.replace(self.settings, photons=photons, seed=seed, **scaled))


def backward_through_splat(pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor, channel: torch.Tensor,
                           grad_image: torch.Tensor) -> None:
    """Accumulate into the graph's leaves the gradient of <splat(photons), grad_image>: pixel
    positions (2, N), footprint metrics (3, N), flux (N,), channel (N,); grad_image (c, n, n)
    already divided by the pixel area."""
    grads = splat_photons_vjp(pos, metric, flux, channel, grad_image)
    pairs = [(t, g) for t, g in zip((pos, metric, flux), grads) if t.requires_grad]
    if pairs:
        torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
