"""Plugins defined only in the test suite, as a third-party package would write them.

- ``operator/shadow`` (:class:`ShadowOperator`): a linear stand-in for the caustic, each height
  sample lights a square of receiver pixels: F(d) = 1 + gain * U d, U the nearest-neighbour
  upsampling from the m x m heights to the n x n receiver (n a multiple of m).
- ``solver/exact_step`` (:class:`ExactStepSolver`): a non-iterative solver, one steepest-descent
  step with the exact step length of a quadratic data term. For ``shadow`` (U^T U = (n/m)^2 I) that
  one step is the least-squares solution.
- ``initial/mask_mean`` (:class:`MaskMeanStart`): a plate of the known volume over the printed
  area, at its mean height.
- ``stopping/small_change`` (:class:`SmallChangeStopping`): stop once an iteration moves no height
  sample by more than a tolerance.

They reach the framework only through the public plugin mechanism (entry points of the groups
``shape_from_caustics.<kind>``) and their config files (tests/plugins/conf, on Hydra's search
path); docs/plugins.md walks through them.
"""

from __future__ import annotations

import time
from typing import Any

import torch
import torch.nn.functional as F

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.core.contracts.stopping import StoppingRule
from framework.core.solver_loop import IterationRecord, IterativeSolver
from operators.photon_operator import ImageOperator


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


class ExactStepSolver(IterativeSolver):
    """d = d0 - t g, g = grad f(d0), t = <r, J g> / ||J g||^2 (r = F(d0) - b, J g = F(d0 + g) - F(d0))."""

    name = "exact_step"

    def __init__(self, problem: Any, d0: torch.Tensor) -> None:
        super().__init__(d0)
        self.problem = problem

    @classmethod
    def from_config(cls):
        return cls

    def step(self) -> IterationRecord:
        t0 = time.perf_counter()
        fidelity, render, d = self.problem.fidelity, self.problem.operator.render, self.state.d
        g = fidelity.evaluate(d, with_grad=True).grad
        residual = render(d) - fidelity.target
        direction = render(d + g) - render(d)
        step = float((residual * direction).sum() / (direction * direction).sum())
        self.state.d = d - step * g
        after = fidelity.evaluate(self.state.d, with_grad=False)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        record = IterationRecord(self.state.iteration, after.value, after.value, after.rel_discrepancy, step,
                                 self.state.elapsed_s)
        self.history.append(record)
        return record

    def finished(self) -> str | None:
        return "one exact step minimises the quadratic data term" if self.iteration >= 1 else None


class MaskMeanStart(Start):
    """d0 = V / (|N| a) on the printed area N (cell area a), 0 elsewhere: the known volume V spread
    evenly. Measured data without a volume are refused."""

    name = "mask_mean"

    def __init__(self, scale: float = 1.0) -> None:
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale >= 0:
            raise ValueError(f"initial.scale={scale!r} must be a number >= 0, e.g. 1.0")
        self.scale = float(scale)

    def __call__(self, request: StartRequest) -> StartResult:
        problem = request.problem
        if problem.data.volume is None:
            raise ValueError("initial=mask_mean needs the deposited volume; set data.volume")
        mask = problem.data.mask
        height = self.scale * problem.data.volume / (float(mask.sum()) * problem.grid.cell_area)
        d = torch.where(mask, height, 0.0).to(problem.operator.dtype)
        return StartResult(d, {"height": height}, self.name)


class SmallChangeStopping(StoppingRule):
    """Stop once an iteration moves no height sample by more than ``tolerance`` (scene units)."""

    def __init__(self, tolerance: float = 1e-6) -> None:
        if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not tolerance > 0:
            raise ValueError(f"stopping.small_change.tolerance={tolerance!r} must be a positive length, e.g. 1e-6")
        self.tolerance = float(tolerance)
        self.previous: torch.Tensor | None = None

    def on_start(self, solver: IterativeSolver) -> None:
        self.previous = solver.state.d.clone()

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> bool:
        change = float((solver.state.d - self.previous).abs().max())
        self.previous = solver.state.d.clone()
        if change <= self.tolerance:
            self.stop_reason = f"no height moved by more than {self.tolerance:g} in iteration {record.iteration}"
            return True
        return False
