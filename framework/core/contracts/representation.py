"""The contract of a representation plugin (kind ``representation``, framework/representations/,
framework/tracks/): the heights as a function of the parameters a solver fits.

d = R(theta): theta (p,) -> heights (m, m), scene units, with its exact vector-Jacobian product
vjp(theta, g) = J_R(theta)^T g, so that the data term, the regularisers of the heights and the
stopping rules stay as they are and only the parameters change (docs/method.md, "Representations").
A representation also says which parameters may move (``bounds``), their natural sizes (``scale``,
the metric a solver's first step uses), its own prior on theta (``prior``) and, for solvers that fit
in stages, which parameters each stage frees (``stages``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

import torch
from torch import Tensor

from operators.plugin import Plugin

__all__ = ["Representation", "SearchContext"]


@dataclass(frozen=True)
class SearchContext:
    """What a representation's global search sees of the fit.

    Attributes:
        objective: theta -> the solver's objective (one render).
        pixel_misfit: theta -> (n * n,) each receiver pixel's share of the objective's data term (one render).
        penalty: theta -> the objective's other terms (the priors, the volume; no caustic render).
        noise_variance: Each receiver pixel's expected share of the data term at the noise level.
        receiver_half_width: The receiver's half width (scene units); receiver_pixels: n.
        earlier: The searches this fit made before this one (0: the first, from the start).
    """

    objective: Callable[[Tensor], float]
    pixel_misfit: Callable[[Tensor], np.ndarray]
    penalty: Callable[[Tensor], float]
    noise_variance: float
    receiver_half_width: float
    receiver_pixels: int
    earlier: int = 0


class Representation(Plugin, ABC):
    """d = R(theta) on one height grid.

    Attributes:
        shape: (m, m), the heights' grid.
        size: p, the number of parameters.
        dtype: The parameters' and heights' dtype.
        describes_beads: True where the parameters are beads along tracks (their count is then
            the fit's, not a question for the run's stages; framework/core/contracts/stage.py).
    """

    shape: tuple[int, int]
    size: int
    dtype: torch.dtype = torch.float64
    describes_beads: ClassVar[bool] = False

    @abstractmethod
    def initial(self) -> Tensor:
        """theta_0 (p,): where a fit starts (the design's nominal values, or the start's heights)."""

    @abstractmethod
    def heights(self, theta: Tensor) -> Tensor:
        """d = R(theta), shape (m, m), scene units."""

    @abstractmethod
    def vjp(self, theta: Tensor, g: Tensor) -> Tensor:
        """J_R(theta)^T g (p,) for a heights cotangent g (m, m): the gradient in theta of <g, R(theta)>."""

    def bounds(self) -> tuple[Tensor, Tensor]:
        """(lower, upper), each (p,) (+-inf where free): the box theta stays in."""
        inf = torch.full((self.size,), float("inf"), dtype=self.dtype)
        return -inf, inf

    def scale(self) -> Tensor:
        """(p,) > 0: each parameter's natural size (a solver's first step moves theta by about this)."""
        return torch.ones(self.size, dtype=self.dtype)

    def prior(self, theta: Tensor) -> tuple[float, Tensor]:
        """(value, gradient (p,)) of the representation's own prior on theta; none by default."""
        return 0.0, torch.zeros_like(theta)

    def stages(self) -> list[Tensor]:
        """The parameters each stage of a staged fit frees, (p,) bool each; one stage: all."""
        return [torch.ones(self.size, dtype=torch.bool)]

    def search(self, theta: Tensor, context: SearchContext) -> tuple[Tensor, list[str]]:
        """A global search beyond the gradient's reach (alternative basins of parts of the print):
        the new theta and what changed, in words; none by default."""
        return theta, []

    def clipped(self, theta: Tensor) -> Tensor:
        """theta projected onto :meth:`bounds`."""
        lower, upper = self.bounds()
        return torch.maximum(torch.minimum(theta, upper.to(theta)), lower.to(theta))

    def summary(self, theta: Tensor) -> dict[str, Any]:
        """What the run's metrics.json reports of this representation at theta."""
        return {"representation": type(self).__name__, "parameters": self.size}
