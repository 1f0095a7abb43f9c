"""The contract of a forward-operator plugin (kind ``operator``): printed heights d (m, m) in,
irradiance image F(d) (c, n, n) out, with its adjoint.

Operators live in operators/, which knows nothing of the framework, so the contract is a Protocol
that an operator keeps by its members; operators/photon_operator.py (``ImageOperator``) is the base
that gives the squared loss, autograd and the defaults below from ``render`` and ``vjp``.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import Any, Protocol, runtime_checkable

import torch

__all__ = ["BackgroundWork", "MEMBERS", "Operator", "missing_members"]


@runtime_checkable
class BackgroundWork(Protocol):
    """What an operator's ``warm_up()`` yields: work going on meanwhile (e.g. a kernel compiling)."""

    @property
    def running(self) -> bool:
        """True while the work is not done."""
        ...

    def wait(self) -> None:
        """Block until the work is done."""
        ...


@runtime_checkable
class Operator(Protocol):
    """A differentiable forward operator F: R^{m x m} -> R_+^{c x n x n}.

    The registered object builds one with ``from_config(scene, photons, seed, **settings)``:
    ``scene`` is the :class:`operators.scene.Scene` of the config (light, substrate, receiver,
    material, wavelengths), ``photons`` and ``seed`` the run's, ``settings`` the rest of the
    ``operator`` group, which the plugin checks (an unknown key is a ValueError naming the keys it
    takes). ``example_settings() -> dict`` gives the settings the contract checks build it with
    when it has required ones.

    Attributes:
        dtype: The dtype of its images and gradients.
        photons: Photons traced per evaluation.
        pixel_area: Area of one receiver pixel, scene units^2.
        conserves_energy: True when a print only moves light on the receiver (the power is the
            same for every height field that sends all of it there); False with Fresnel losses,
            a camera gain or light that misses the receiver.
        revision: Changes whenever the operator's setup changes (joint calibration): the data
            term renders again instead of reusing an image.
        has_light_path: True when the operator also offers the two fixed halves of its light
            path around the print, ``arrivals(photons)`` and ``land_from_bottom(points,
            directions)`` (operators/light_paths.py), which the transport start inverts.
        elements: The optical elements it traces besides the print and the substrate (lenses,
            operators/mesh/); () for none.
        gain: The camera gain its images carry (operators/imaging.py); 1.0 for none.
        shots: The operators of a stack's shots (operators/stack.py), whose images it renders one
            after the other; () for an operator of one image.
        shot_count: How many times a pass traces ``photons`` (a stack's shots; 1 otherwise).

    :class:`operators.photon_operator.ImageOperator` declares all of these with the defaults of an
    operator of one image, without elements or gain; nothing is found by probing an operator for them.
    """

    dtype: torch.dtype
    photons: int
    pixel_area: float
    conserves_energy: bool
    revision: int
    has_light_path: bool
    elements: Sequence[Any]
    gain: float
    shots: Sequence[Any]
    shot_count: int

    @property
    def output_shape(self) -> tuple[int, int, int]:
        """(c, n, n) of the images it renders."""
        ...

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """F(d) (c, n, n), W per scene unit^2, of heights d (m, m), without a graph; heights of
        the wrong shape or with NaN raise a ValueError."""
        ...

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* grad_image (m, m): the adjoint of the linearisation at d."""
        ...

    def loss_and_grad(self, heights: torch.Tensor, target: torch.Tensor, image: torch.Tensor | None = None
                      ) -> tuple[float, torch.Tensor, torch.Tensor]:
        """(1/2 ||F(d) - target||_F^2, its gradient (m, m), F(d) (c, n, n)) with memory bounded by
        the photon chunk; ``image`` = F(d) rendered before for these heights may be reused."""
        ...

    def __call__(self, heights: torch.Tensor) -> torch.Tensor:
        """F(d) with autograd (forward by ``render``, backward by ``vjp``)."""
        ...

    def variant(self, photons: int, seed: int, resolution: int) -> Operator:
        """The same physics with another sampling (photons, seed, an n = resolution receiver):
        the independent reference renders of synthetic data."""
        ...

    def warm_up(self) -> AbstractContextManager[BackgroundWork]:
        """A context for a run that takes gradients, yielding the work started meanwhile (e.g. the
        gradient kernel compiling while the first images render); nothing for most operators."""
        ...



MEMBERS = ("dtype", "photons", "pixel_area", "conserves_energy", "revision", "has_light_path", "elements", "gain",
           "shots", "shot_count", "output_shape",
           "render", "vjp",
           "loss_and_grad", "__call__", "variant", "warm_up")


def missing_members(operator: object) -> list[str]:
    """The members of :class:`Operator` that ``operator`` lacks (none for an operator that keeps it)."""
    return [name for name in MEMBERS if not hasattr(operator, name)]
