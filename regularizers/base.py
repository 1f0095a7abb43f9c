"""Common shape of regularizers (value + prox) and post-step updates (heuristics).

A :class:`Regularizer` is a convex functional R(d) of the height field d (shape (m, m), scene
units) with ``value(d) = R(d)`` and ``prox(d, step) = argmin_x step * R(x) + 1/2 ||x - d||^2``
(a projection for an indicator function). A :class:`PostStepUpdate` is a rule applied after a
solver iteration that is *not* a proximal map (the paper's volume heuristic, eq. (8)).
Both are configured once per reconstruction through :meth:`setup` with a
:class:`RegularizerContext` (mask N^, deposited volume V, pixel area a).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from operators.plugin import Plugin
from operators.values import checked_number


@dataclass(frozen=True)
class RegularizerContext:
    """What a regularizer may know about the reconstruction problem.

    Attributes:
        mask: Bool tensor (m, m); True on the printed area N^ (where material may be
            deposited), False on the unprinted area N° (height forced to 0).
        volume: Deposited volume V in scene units^3, or None if unknown.
        pixel_area: Area a of one height-field sample in scene units^2
            (e.g. (2/m)^2 for an m x m grid on [-1, 1]^2).
        design: The print's design (m, m), scene units, when one is given (a prior toward it:
            regularizers/l1_design.py), else None.
    """

    mask: torch.Tensor
    volume: float | None = None
    pixel_area: float = 1.0
    design: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.mask, torch.Tensor) or self.mask.ndim != 2:
            shape = tuple(self.mask.shape) if isinstance(self.mask, torch.Tensor) else type(self.mask).__name__
            raise ValueError(f"mask must be a 2-D torch.Tensor (m, m), got {shape}; pass one mask image")
        if self.mask.dtype != torch.bool:
            raise ValueError(f"mask has dtype {self.mask.dtype}, expected torch.bool; pass mask > 0.5 or mask.bool()")
        checked_number(
            self.pixel_area, "pixel_area", above=0.0, unit="the area of one height-field sample", example="(2/m)**2"
        )
        if self.design is not None and (not isinstance(self.design, torch.Tensor)
                                        or tuple(self.design.shape) != tuple(self.mask.shape)):
            shape = tuple(self.design.shape) if isinstance(self.design, torch.Tensor) else type(self.design).__name__
            raise ValueError(f"design has shape {shape}, the mask {tuple(self.mask.shape)}; give the design on the "
                             "height grid")
        if self.volume is not None:
            v = float(self.volume)
            if not math.isfinite(v) or v <= 0.0:
                raise ValueError(
                    f"deposited volume must be a positive finite number, got volume={self.volume!r}; "
                    "pass V in scene units^3 or None"
                )

    @classmethod
    def full(cls, m: int, volume: float | None = None, pixel_area: float = 1.0) -> RegularizerContext:
        """Context whose mask is True everywhere on an m x m grid (no area constraint)."""
        return cls(mask=torch.ones(m, m, dtype=torch.bool), volume=volume, pixel_area=pixel_area)


class _UsesContext(Plugin):
    """Mixin: stores the :class:`RegularizerContext` and hands out the mask on the right device."""

    _ctx: RegularizerContext | None = None

    def setup(self, ctx: RegularizerContext) -> None:
        """Store the problem context; call once before use (again if mask or volume change)."""
        if not isinstance(ctx, RegularizerContext):
            raise ValueError(f"setup expects a RegularizerContext, got {type(ctx).__name__}; build one from the mask")
        self._ctx = ctx

    @property
    def ctx(self) -> RegularizerContext:
        """The context given to :meth:`setup`; raises if setup was not called."""
        if self._ctx is None:
            raise RuntimeError(f"{type(self).__name__} is not set up; call setup(RegularizerContext(mask=...)) first")
        return self._ctx

    def _mask_for(self, d: torch.Tensor) -> torch.Tensor:
        """The mask N^ as a bool tensor on ``d.device``, checked against ``d.shape``."""
        mask = self.ctx.mask
        if mask.shape != d.shape:
            raise ValueError(
                f"mask shape {tuple(mask.shape)} does not match height field shape {tuple(d.shape)}; "
                "build the mask on the same grid as d"
            )
        return mask.to(d.device)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({params})"


class Regularizer(_UsesContext, ABC):
    """A convex functional R(d) of the height field with (optionally) a proximal map.

    Subclasses set the class flags and implement :meth:`value` and, if ``has_prox``, :meth:`prox`.

    Attributes:
        has_prox: True if :meth:`prox` is implemented exactly (closed form or 1-D root find).
        smooth: True if R is differentiable (a gradient step may be used instead of a prox).
        band: The band (q1, q2) of the height sum the term enforces (a known volume), else None.
        needs_volume: True if it needs the deposited volume (the run's checks refuse measured
            data without data.volume, framework/reconstruction/run_checks.py).
    """

    has_prox: ClassVar[bool] = False
    smooth: ClassVar[bool] = False
    needs_volume: ClassVar[bool] = False
    band: tuple[float, float] | None = None

    @abstractmethod
    def value(self, d: torch.Tensor) -> float:
        """R(d) for a height field d of shape (m, m); ``inf`` outside the domain of an indicator."""

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """prox_{step R}(d) = argmin_x step * R(x) + 1/2 ||x - d||_2^2, shape (m, m).

        Args:
            d: Point to evaluate the proximal map at, shape (m, m).
            step: Step size tau > 0 multiplying R (ignored by pure indicators).
        """
        raise NotImplementedError(
            f"{type(self).__name__} has no proximal map (has_prox=False); use a solver that takes its gradient"
        )

    def project(self, d: torch.Tensor) -> torch.Tensor:
        """The nearest point of the set where :meth:`value` is finite, shape (m, m): identity for a
        functional that is finite everywhere; indicator terms (bounds, mask) override it. A solver
        uses it to bring a post-step update that left the set back into it."""
        return d

    @staticmethod
    def _check_step(step: float) -> float:
        return checked_number(step, "step", above=0.0, unit="the solver step size tau")


class PostStepUpdate(_UsesContext, ABC):
    """A heuristic applied to d after each solver iteration; not a proximal map of any functional.

    Attributes:
        band: The band (q1, q2) of the height sum it enforces (a known volume), else None.
        needs_volume: True if it needs the deposited volume (as a regulariser's).
        holds_volume: True if it keeps the height sum at the known volume after every step (a
            stack's calibrated distance then moves without a factor on the heights,
            framework/lab/calibration.py).
    """

    band: tuple[float, float] | None = None
    needs_volume: ClassVar[bool] = False
    holds_volume: ClassVar[bool] = False

    @abstractmethod
    def __call__(self, d: torch.Tensor) -> torch.Tensor:
        """Return the updated height field (same shape, dtype and device as d); d is not modified."""



class CoefficientTransform(ABC):
    """An invertible linear transform of the height field, w = W d: (m, m) -> (m * m,) flat
    coefficients, with the adjoint of its inverse (a pixel gradient to a coefficient gradient)."""

    @abstractmethod
    def forward(self, d: torch.Tensor) -> torch.Tensor:
        """W d (m * m,) of heights d (m, m)."""

    @abstractmethod
    def inverse(self, w: torch.Tensor) -> torch.Tensor:
        """W^-1 w (m, m) of flat coefficients w."""

    @abstractmethod
    def inverse_adjoint(self, g: torch.Tensor) -> torch.Tensor:
        """(W^-1)^* g (m * m,) of a pixel gradient g (m, m)."""

    def subbands(self) -> list[tuple[torch.Tensor, int]]:
        """One (mask (m * m,) bool, flat index of a coefficient inside it) per group of coefficients
        that a metric may scale alike; none here (a transform without subbands)."""
        return []


class CoefficientRegularizer(Regularizer):
    """A regulariser of the coefficients w = W d of a :class:`CoefficientTransform`, with the
    proximal map on the coefficients that a transform-domain solver steps with."""

    @abstractmethod
    def transform_for(self, shape: tuple[int, int]) -> CoefficientTransform:
        """The transform W on a height grid of ``shape``."""

    @abstractmethod
    def prox_coefficients(self, w: torch.Tensor, step: float, metric: torch.Tensor | None = None) -> torch.Tensor:
        """prox of ``step`` x the regulariser on flat coefficients w, in the metric diag(1 / metric)
        when ``metric`` (flat, positive) is given."""
