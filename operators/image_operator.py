"""The operator contract: printed heights d (m, m) in, an image F(d) (c, n, n) out, with its adjoint.

:class:`ImageOperator` is the one contract of an operator plugin (kind ``operator``) and the base
it derives from: a subclass gives ``render(heights)``, ``vjp(heights, grad_image)``,
``output_shape``, its ``dtype``, ``photons`` and ``pixel_area`` (and ``variant`` when synthetic
data are rendered with it); the base turns render and vjp into the squared loss and its gradient
and autograd through ``operator(heights)`` (:class:`RenderFunction`), and declares every other
capability a caller may use, with the defaults of an operator of one image without elements,
gain or light path. Nothing is found by probing an operator: what it does not declare is the
default here. :class:`WrappingOperator` renders through another operator (a finer receiver, a
camera) and passes on its declarations. The photon operators derive from
operators/photon_operator.py's ``PhotonOperator``; the contract suite
(framework/core/contracts/checks.py) checks every registered one.

The registered class builds one with ``from_config(scene, photons, seed, **settings)`` or its
constructor (operators/plugin.py): ``scene`` is the :class:`operators.scene.Scene` of the config,
``photons`` and ``seed`` the run's, ``settings`` the rest of the ``operator`` group, which the
plugin checks (an unknown key is a ValueError naming the keys it takes).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import torch

from operators.plugin import Plugin

__all__ = ["ImageOperator", "NothingRunning", "RenderFunction", "WrappingOperator"]


class NothingRunning:
    """What ``warm_up()`` yields when no work goes on in the background."""

    running = False

    def wait(self) -> None:
        """Nothing to wait for."""


class ImageOperator(Plugin, ABC):
    """A differentiable forward operator F: R^{m x m} -> R_+^{c x n x n} given by ``render(heights)``
    and ``vjp(heights, grad_image)`` (module docstring).

    Attributes:
        dtype: The dtype of its images and gradients (set by the subclass).
        photons: Photons traced per evaluation (set by the subclass).
        pixel_area: Area of one receiver pixel, scene units^2 (set by the subclass).
        scene: The :class:`operators.scene.Scene` it renders (set by the subclass; an operator
            of no scene, such as a test's, leaves it None).
        conserves_energy: False unless a subclass knows that a print only moves light (the power
            is the same for every height field that sends all of it to the receiver).
        revision: 0: the setup never changes (an operator whose setup does counts it up, and the
            data term renders again instead of reusing an image).
        has_light_path: False unless a subclass offers ``arrivals`` and ``land_from_bottom``
            (operators/light_paths.py).
        elements: () unless a subclass traces optical elements beside the print (operators/mesh/).
        gain: 1.0 unless a subclass scales its images by a camera gain (operators/imaging.py).
        shots: () unless a subclass renders several shots' images (operators/stack.py).
        shot_count: 1: every pass traces ``photons`` once.
        deterministic: False unless a render has no sampling noise (two renders are equal).
        hit_key: None unless operators with equal keys may share where their photons meet the
            print (:meth:`share_hits`).
        has_jvp: False unless a subclass gives the Jacobian-vector product :meth:`jvp`.
    """

    dtype: torch.dtype
    photons: int
    pixel_area: float
    scene: Any = None
    conserves_energy: bool = False
    revision: int = 0
    has_light_path: bool = False
    elements: Sequence[Any] = ()
    gain: float = 1.0
    shots: Sequence[Any] = ()
    shot_count: int = 1
    deterministic: bool = False
    hit_key: Any = None
    has_jvp: bool = False

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

    def jvp(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """F'(d) v (c, n, n): the image's change along a direction v (m, m) of the heights, from an
        operator that declares ``has_jvp``; this one has none."""
        raise NotImplementedError(f"{type(self).__name__} has no Jacobian-vector product (has_jvp is False)")

    def variant(self, photons: int, seed: int, resolution: int) -> ImageOperator:
        """The same physics with another sampling (photons, seed, an n = resolution receiver):
        synthetic data and the photon budget need it; an operator of one fixed sampling has none."""
        raise NotImplementedError(f"{type(self).__name__} has no variant; synthetic data need an operator that can "
                                  "render with another photon count and receiver")

    def with_photons(self, photons: int, seed: int) -> ImageOperator:
        """This operator when it traces ``photons``, else its :meth:`variant` with ``photons`` and
        ``seed``'s pattern on the same receiver (a photon budget's stages, a cheap search)."""
        if photons == int(self.photons):
            return self
        return self.variant(photons, seed, int(self.output_shape[-1]))

    def exact_variant(self, photons: int, seed: int, resolution: int) -> Any:
        """A renderer (``render(heights)`` -> (c, resolution, resolution)) of the same physics for
        the references of synthetic data, free of this operator's own approximations where the
        operator knows an exact method; here, lacking one, its :meth:`variant`."""
        return self.variant(photons, seed, resolution)

    def warm_up(self) -> AbstractContextManager[Any]:
        """A context for a run that takes gradients, yielding the work started meanwhile (an object
        with ``running`` and ``wait()``, e.g. the gradient kernel compiling while the first images
        render); here nothing: :class:`NothingRunning`."""
        return nullcontext(NothingRunning())

    def arrivals(self, photons: int) -> Any:
        """The light path above the print (operators/light_paths.py) of an operator that declares
        ``has_light_path``; this one has none."""
        raise NotImplementedError(f"{type(self).__name__} has no light path (has_light_path is False)")

    def land_from_bottom(self, points: Any, directions: Any) -> Any:
        """The light path below the print (operators/light_paths.py) of an operator that declares
        ``has_light_path``; this one has none."""
        raise NotImplementedError(f"{type(self).__name__} has no light path (has_light_path is False)")

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
    cache, whether it has a Jacobian-vector product, and warm-up. Nothing else is passed on."""

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

    @property
    def has_jvp(self) -> bool:  # type: ignore[override]
        return bool(self.wrapped.has_jvp)

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
