"""What the photon operators share: the base of the operator contract around ``render`` and ``vjp``.

:class:`ImageOperator` keeps the operator contract (framework/core/contracts/operator.py) for a
subclass that gives ``render(heights)``, ``vjp(heights, grad_image)``, ``output_shape``,
``variant`` and its dtype, photons and pixel area: it turns render and vjp into the squared loss
and its gradient and autograd through ``operator(heights)`` (:class:`RenderFunction`), and
declares the defaults (no energy conservation claimed, a fixed setup, nothing to warm up).
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
from abc import ABC, abstractmethod
from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import torch

from operators.linear import GaussianBlur, LinearMap
from operators.scene import Scene
from operators.splat.splat import footprint_metric, splat_photons_vjp

__all__ = [
    "PIXEL_SETTINGS",
    "PIXEL_BOX_R2",
    "ImageOperator",
    "NothingRunning",
    "PhotonOperator",
    "RenderFunction",
    "WrappingOperator",
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


class NothingRunning:
    """What ``warm_up()`` yields when no work goes on in the background."""

    running = False

    def wait(self) -> None:
        """Nothing to wait for."""


class ImageOperator(ABC):
    """An operator given by ``render(heights)`` and ``vjp(heights, grad_image)``: the squared loss
    and its gradient in two passes, and autograd through ``operator(heights)``.

    Attributes:
        dtype: The dtype of its images and gradients (set by the subclass).
        conserves_energy: False unless a subclass knows that a print only moves light.
        revision: 0: the setup never changes (an operator whose setup does counts it up).
        has_light_path: False unless a subclass offers ``arrivals`` and ``land_from_bottom``
            (operators/light_paths.py).
        elements: () unless a subclass traces optical elements beside the print (operators/mesh/).
        gain: 1.0 unless a subclass scales its images by a camera gain (operators/imaging.py).
        shots: () unless a subclass renders several shots' images (operators/stack.py).
        shot_count: 1: every pass traces ``photons`` once.
        deterministic: False unless a render has no sampling noise (two renders are equal).
        hit_key: None unless operators with equal keys may share where their photons meet the
            print (:meth:`share_hits`).
    """

    dtype: torch.dtype
    conserves_energy: bool = False
    revision: int = 0
    has_light_path: bool = False
    elements: Sequence[Any] = ()
    gain: float = 1.0
    shots: Sequence[Any] = ()
    shot_count: int = 1
    deterministic: bool = False
    hit_key: Any = None

    def share_hits(self, other: Any) -> None:
        """Use ``other``'s hit cache (operators/stack.py); only an operator with a ``hit_key`` has one."""
        raise ValueError(f"{type(self).__name__} has no hit cache to share (hit_key is None)")

    @abstractmethod
    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """The image F(d) (c, n, n) of heights d (m, m), without a graph."""

    @abstractmethod
    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* grad_image (m, m)."""

    @property
    @abstractmethod
    def output_shape(self) -> tuple[int, int, int]:
        """(c, n, n) of the images it renders."""

    def variant(self, photons: int, seed: int, resolution: int) -> ImageOperator:
        """The same physics with another sampling (photons, seed, an n = resolution receiver):
        synthetic data and the photon budget need it; an operator of one fixed sampling has none."""
        raise NotImplementedError(f"{type(self).__name__} has no variant; synthetic data need an operator that can "
                                  "render with another photon count and receiver")

    def exact_variant(self, photons: int, seed: int, resolution: int) -> Any:
        """A renderer (``render(heights)`` -> (c, resolution, resolution)) of the same physics for
        the references of synthetic data, free of this operator's own approximations where the
        operator knows an exact method; here, lacking one, its :meth:`variant`."""
        return self.variant(photons, seed, resolution)

    def warm_up(self) -> AbstractContextManager[Any]:
        """Nothing to start in the background: yields :class:`NothingRunning`."""
        return nullcontext(NothingRunning())

    def loss_and_grad(self, heights: torch.Tensor, target: torch.Tensor, image: torch.Tensor | None = None
                      ) -> tuple[float, torch.Tensor, torch.Tensor]:
        """(1/2 ||F(d) - target||^2, its gradient (m, m), F(d)) in two passes of bounded memory;
        ``image`` = F(d) from an earlier :meth:`render` of these heights skips the first pass."""
        if image is None:
            image = self.render(heights)
        elif image.shape != self.output_shape:
            raise ValueError(f"image has shape {tuple(image.shape)}, the operator renders {self.output_shape}")
        if target.shape != image.shape:
            raise ValueError(f"target has shape {tuple(target.shape)}, the operator renders {tuple(image.shape)}")
        residual = image - target.to(image)
        return 0.5 * float((residual.double() ** 2).sum()), self.vjp(heights, residual), image

    def __call__(self, heights: torch.Tensor) -> torch.Tensor:
        return RenderFunction.apply(heights, self)


class WrappingOperator(ImageOperator):
    """An operator that renders through another one, :attr:`wrapped` (a finer receiver, a camera),
    and passes on what that one declares: dtype, photons, its light path, elements, shots, hit
    cache and warm-up. Nothing else is passed on."""

    @property
    def wrapped(self) -> Any:
        """The operator rendered through."""
        raise NotImplementedError

    @property
    def dtype(self) -> torch.dtype:  # type: ignore[override]
        return self.wrapped.dtype

    @property
    def photons(self) -> int:
        return self.wrapped.photons

    @property
    def has_light_path(self) -> bool:  # type: ignore[override]
        return bool(self.wrapped.has_light_path)

    @property
    def elements(self) -> Sequence[Any]:  # type: ignore[override]
        return self.wrapped.elements

    @property
    def shot_count(self) -> int:  # type: ignore[override]
        return self.wrapped.shot_count

    @property
    def deterministic(self) -> bool:  # type: ignore[override]
        return self.wrapped.deterministic

    @property
    def hit_key(self) -> Any:  # type: ignore[override]
        return self.wrapped.hit_key

    def share_hits(self, other: Any) -> None:
        """Share the wrapped operators' hit cache (operators/stack.py)."""
        self.wrapped.share_hits(other.wrapped if isinstance(other, WrappingOperator) else other)

    def arrivals(self, photons: int) -> Any:
        """The wrapped operator's light path above the print (operators/light_paths.py)."""
        return self.wrapped.arrivals(photons)

    def land_from_bottom(self, points: Any, directions: Any) -> Any:
        """The wrapped operator's light path below the print (operators/light_paths.py)."""
        return self.wrapped.land_from_bottom(points, directions)

    def warm_up(self) -> AbstractContextManager[Any]:
        """The wrapped operator's warm-up."""
        return self.wrapped.warm_up()


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


class RenderFunction(torch.autograd.Function):
    """F(d) forward by ``operator.render``, backward by ``operator.vjp``."""

    @staticmethod
    def forward(ctx, heights: torch.Tensor, operator: Any) -> torch.Tensor:
        ctx.operator = operator
        ctx.save_for_backward(heights)
        return operator.render(heights)

    @staticmethod
    def backward(ctx, grad_image: torch.Tensor):
        (heights,) = ctx.saved_tensors
        return ctx.operator.vjp(heights, grad_image), None


def backward_through_splat(pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor, channel: torch.Tensor,
                           grad_image: torch.Tensor) -> None:
    """Accumulate into the graph's leaves the gradient of <splat(photons), grad_image>: pixel
    positions (2, N), footprint metrics (3, N), flux (N,), channel (N,); grad_image (c, n, n)
    already divided by the pixel area."""
    grads = splat_photons_vjp(pos, metric, flux, channel, grad_image)
    pairs = [(t, g) for t, g in zip((pos, metric, flux), grads) if t.requires_grad]
    if pairs:
        torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
