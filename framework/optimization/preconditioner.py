"""Gradient preconditioners: the metric in which the solvers take their gradient step.

The paper steps along the plain (pixel, L2) gradient. For small heights the caustic obeys the
transport-of-intensity linearisation F'(d) u ~ -c B Laplace(u) (B the footprint blur), so the
Hessian of the data term behaves like Laplace B^2 Laplace: broad components of d (|k| small) have
eigenvalues ~ |k|^4 and converge very slowly, while components finer than the footprint are not
seen by the data and collect the photon noise of the gradient. Taking the gradient in the Sobolev
metric <u, (I - l^2 Laplace)^p u> instead, i.e. stepping along

    P grad f,   P = (I - l^2 Laplace)^(-p),

damps what is finer than l and so admits a much larger step for everything broader than l
(variable-metric proximal gradient; the proxes keep their usual, pixel-wise form). P is symmetric
positive definite and leaves a constant field unchanged.

Coarse to fine: with a schedule of lengths l_1 > l_2 > ..., the solver starts with l_1 and, when
the fit stalls (:class:`framework.reconstruction.stopping.StagnationStopping`) or its line search finds no
decrease, calls :meth:`refine` and goes on with the next length, so detail finer than l_1 is
fitted once the broad shape is in place.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any
from collections.abc import Sequence

import numpy as np
import scipy.fft
import torch
from torch import Tensor

from operators.plugin import Plugin
from operators.values import checked_number, checked_whole

__all__ = ["GradientPreconditioner", "SobolevPreconditioner", "check_stage_index", "neumann_laplacian_eigenvalues"]


class GradientPreconditioner(Plugin, ABC):
    """Maps the gradient (m, m) to the step direction (m, m), symmetric positive definite.

    The defaults are those of a single fixed metric; a coarse-to-fine schedule overrides them.

    Attributes:
        stage: The schedule's current stage (0 for a single metric).
        length: The current smoothing length, scene units, or None for a metric without one.
    """

    stage: int = 0
    length: float | None = None

    @abstractmethod
    def __call__(self, grad: Tensor) -> Tensor:
        """P grad (m, m)."""

    def refine(self) -> bool:
        """Switch to the next, finer metric; False (and no change) without one."""
        return False

    def setup(self, context: Any) -> None:
        """Take what the metric needs of the problem (e.g. the grid spacing); nothing here."""

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps (nothing for a fixed metric)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`."""


def check_stage_index(stage: Any, key: str, null_means: str) -> int | None:
    """A setting ``key`` that names a preconditioner stage (``solver.two_metric_from``,
    ``solver.momentum_from``) as an index >= 0, or None (``null_means`` says what null does)."""
    if stage is None:
        return None
    return checked_whole(stage, key, 0, must="must be a preconditioner stage index >= 0 "
                                             f"(0: from the first length) or null ({null_means})")


def neumann_laplacian_eigenvalues(m: int) -> np.ndarray:
    """Eigenvalues (m,) of the 1-D negative Laplacian with reflecting ends, in 1 / cells^2, for the
    orthonormal DCT-II modes cos(pi k (i + 1/2) / m): 2 - 2 cos(pi k / m)."""
    return 2.0 - 2.0 * np.cos(np.pi * np.arange(m) / m)


class SobolevPreconditioner(GradientPreconditioner):
    """P = (I - l^2 Laplace)^(-p) on the height grid, reflecting borders, applied by a 2-D DCT.

    Args:
        length: Smoothing length l in scene units (converted to grid cells with the grid spacing
            from ``setup``); finer detail than l is damped, broader detail passes unchanged. A
            decreasing list of lengths is a coarse-to-fine schedule (see :meth:`refine`).
        order: Exponent p > 0 (2 matches the |k|^4 growth of the data term's Hessian).
        grid: The height grid (samples a side) the lengths are meant for: on a finer grid of m
            samples each length shrinks by grid / m, so that the schedule spans the same cells
            (the data of a finer grid resolve finer detail, and a length of many cells holds it
            back); on a grid no finer the lengths hold in scene units. None: scene units on
            every grid.
    """

    length_keys = ("length",)  # may be given with a unit, e.g. '3 mm' (framework/core/plugin_config.py)

    def __init__(self, length: float | Sequence[float] = 0.125, order: float = 2.0, grid: int | None = None) -> None:
        lengths = [length] if isinstance(length, (int, float)) else list(length)
        if not lengths or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0 for v in lengths):
            raise ValueError(f"preconditioner length={length!r} must be a positive length in scene units "
                             "(e.g. 0.125) or a list of them (e.g. [0.125, 0.0625])")
        if any(b >= a for a, b in zip(lengths, lengths[1:])):
            raise ValueError(f"preconditioner length={length!r}: a schedule must decrease (coarse to fine), "
                             "e.g. [0.125, 0.0625]")
        checked_number(order, "preconditioner order", above=0.0, example="2")
        self.lengths = [float(v) for v in lengths]
        self.grid = None if grid is None else checked_whole(grid, "preconditioner grid", least=2, example="128")
        self._scale = 1.0  # grid / m on a finer grid (setup)
        self.stage = 0
        self.order = float(order)
        self._spacing: float | None = None
        self._filters: dict[int, np.ndarray] = {}

    @property
    def length(self) -> float:  # type: ignore[override]
        """The smoothing length of the current stage on the grid of ``setup`` (scene units)."""
        return self.lengths[self.stage] * self._scale

    def refine(self) -> bool:
        """Go to the next, finer length of the schedule; False (and no change) at the last one."""
        if self.stage + 1 >= len(self.lengths):
            return False
        self.stage += 1
        self._filters.clear()
        return True

    def state_dict(self) -> dict[str, Any]:
        """The schedule position, for checkpoints."""
        return {"stage": self.stage}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (a checkpoint of the same schedule)."""
        stage = int(state.get("stage", 0))
        if not 0 <= stage < len(self.lengths):
            raise ValueError(f"checkpoint preconditioner stage {stage} does not exist in the schedule {self.lengths}")
        self.stage = stage
        self._filters.clear()

    def setup(self, context: Any) -> None:
        """Take the grid spacing sqrt(a) (scene units) from a context with ``pixel_area`` a, and the
        grid's samples a side from its ``mask`` (m, m) where the lengths are meant for a ``grid``."""
        self._spacing = math.sqrt(float(context.pixel_area))
        m = None if self.grid is None else int(context.mask.shape[-1])
        self._scale = 1.0 if m is None or m <= self.grid else self.grid / m
        self._filters.clear()

    def _filter(self, m: int) -> np.ndarray:
        if self._spacing is None:
            raise RuntimeError(
                "SobolevPreconditioner.setup(context) must be called before use (it needs the grid spacing)"
            )
        if m not in self._filters:
            cells = self.length / self._spacing
            lam = neumann_laplacian_eigenvalues(m)
            self._filters[m] = (1.0 + cells ** 2 * (lam[:, None] + lam[None, :])) ** (-self.order)
        return self._filters[m]

    def __call__(self, grad: Tensor) -> Tensor:
        """P grad for a square gradient (m, m); same dtype and device."""
        if grad.ndim != 2 or grad.shape[0] != grad.shape[1]:
            raise ValueError(f"the preconditioner needs a square (m, m) gradient, got shape {tuple(grad.shape)}")
        g = grad.detach().cpu().double().numpy()
        out = scipy.fft.idctn(scipy.fft.dctn(g, norm="ortho") * self._filter(g.shape[0]), norm="ortho")
        return torch.from_numpy(out).to(dtype=grad.dtype, device=grad.device)
