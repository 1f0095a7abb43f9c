"""The operator contract's checks (operators/image_operator.py), run by
tests/test_plugin_contracts.py on every registered operator: derived from the contract, the declared
output shape and dtype, finite non-negative images, determinism under a seed, the adjoint identity
of the linearisation <vjp(d, w), v> = <w, F'(d) v> and the gradient of ``loss_and_grad`` against
central finite differences (on a bump, and on a bump over a ramp raised along an edge, whose light
crosses the rim and meets the side walls), the power on the receiver unchanged by a small print
when ``conserves_energy``, and bad heights refused (wrong shape, NaN) with a ValueError."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

from framework.core.contracts.violation import ContractViolation, require
from operators.image_operator import ImageOperator

__all__ = ["check_operator", "raised_edge", "smooth_bump"]


def smooth_bump(m: int, height: float = 0.02, width: float = 0.3) -> torch.Tensor:
    """A Gaussian bump (m, m), float64, scene units, on the grid linspace(-1, 1, m)."""
    axis = torch.linspace(-1.0, 1.0, m, dtype=torch.float64)
    y, x = torch.meshgrid(axis, axis, indexing="ij")
    return height * torch.exp(-(x ** 2 + y ** 2) / (2.0 * width ** 2))


def raised_edge(m: int, rise: float = 0.02) -> torch.Tensor:
    """A ramp (m, m), float64, scene units, from 0 at x = -1 to ``rise`` at x = 1: a top that
    stands raised along the +x edge of the square."""
    axis = torch.linspace(-1.0, 1.0, m, dtype=torch.float64)
    return (0.5 * rise * (axis + 1.0)).expand(m, m).clone()


def check_operator(make: Callable[[int], Any], m: int = 16, who: str = "operator") -> None:
    """Check an operator plugin built by ``make(seed)`` on heights of an m x m grid."""
    operator = make(0)
    require(isinstance(operator, ImageOperator), who, "does not derive from operators.image_operator.ImageOperator")
    dtype = operator.dtype
    flat = torch.zeros(m, m, dtype=dtype)
    bump = smooth_bump(m).to(dtype) + 1e-3
    image = operator.render(bump)
    require(tuple(image.shape) == tuple(operator.output_shape), who,
             f"render gives shape {tuple(image.shape)}, output_shape says {tuple(operator.output_shape)}")
    require(image.dtype == dtype, who, f"render gives dtype {image.dtype}, the operator's dtype is {dtype}")
    require(bool(torch.isfinite(image).all()) and float(image.min()) >= 0.0, who,
             "render gives a negative or non-finite irradiance")
    require(torch.equal(make(0).render(bump), image), who, "two operators of one seed render differently")
    probe = _Probe(operator, bump)
    _check_adjoint(operator, bump, probe, who)
    _check_gradient(operator, bump, probe, who)
    edge = bump + raised_edge(m).to(dtype)  # light through a raised rim and off the side walls
    edge_probe = _Probe(operator, edge)
    _check_adjoint(operator, edge, edge_probe, f"{who} (a top raised at the +x edge)")
    _check_gradient(operator, edge, edge_probe, f"{who} (a top raised at the +x edge)")
    if operator.has_jvp:
        _check_jvp(operator, bump, probe, who)
        _check_jvp(operator, edge, edge_probe, f"{who} (a top raised at the +x edge)")
    if operator.conserves_energy:
        power = [float(operator.render(d).double().sum()) * operator.pixel_area for d in (flat, bump)]
        require(power[0] > 0 and abs(power[1] - power[0]) <= 0.02 * power[0], who,
                 f"the power on the receiver changes from {power[0]:.6g} to {power[1]:.6g} under a small print "
                 "(declared conserves_energy)")
    for bad, what in ((torch.zeros(m, m + 1, dtype=dtype), "non-square heights"),
                      (torch.full((m, m), math.nan, dtype=dtype), "NaN heights")):
        try:
            operator.render(bad)
        except ValueError:
            continue
        raise ContractViolation(f"{who}: render accepts {what} instead of raising a ValueError")


def _tolerances(dtype: torch.dtype) -> tuple[float, float]:
    """(finite-difference step, relative tolerance) for an operator of this dtype."""
    return (1e-6, 1e-4) if dtype == torch.float64 else (1e-3, 5e-2)


def _direction(heights: torch.Tensor) -> torch.Tensor:
    """A smooth random perturbation of heights (m, m), fixed seed."""
    generator = torch.Generator().manual_seed(1)
    return (torch.randn(heights.shape, generator=generator, dtype=torch.float64) * smooth_bump(
        heights.shape[0], 1.0, 0.5)).to(heights.dtype)


class _Probe:
    """The images F(d + e v) and F(d - e v), float64, along a smooth direction v: the central
    differences both the adjoint and the gradient check compare with."""

    def __init__(self, operator: Any, heights: torch.Tensor) -> None:
        self.eps, self.tolerance = _tolerances(heights.dtype)
        self.direction = _direction(heights)
        self.plus = operator.render(heights + self.eps * self.direction).double()
        self.minus = operator.render(heights - self.eps * self.direction).double()

    def along(self, grad: torch.Tensor) -> float:
        """<grad, v>."""
        return float((grad.double() * self.direction.double()).sum())

    def close(self, a: float, b: float) -> bool:
        """Whether a and b agree within the relative tolerance."""
        return abs(a - b) <= self.tolerance * max(abs(a), abs(b), 1e-30)


def _check_adjoint(operator: Any, heights: torch.Tensor, probe: _Probe, who: str) -> None:
    """<vjp(d, w), v> against <w, (F(d + e v) - F(d - e v)) / 2e> for a random image w."""
    w = torch.rand(operator.output_shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    pulled = operator.vjp(heights, w.to(operator.dtype))
    require(tuple(pulled.shape) == tuple(heights.shape), who,
             f"vjp gives shape {tuple(pulled.shape)} for heights {tuple(heights.shape)}")
    left, right = probe.along(pulled), float((w * (probe.plus - probe.minus)).sum()) / (2.0 * probe.eps)
    require(probe.close(left, right), who,
             f"the adjoint identity fails: <vjp(d, w), v> = {left:.8g} but <w, F'(d) v> = {right:.8g} "
             f"(relative tolerance {probe.tolerance:g})")


def _check_jvp(operator: Any, heights: torch.Tensor, probe: _Probe, who: str) -> None:
    """jvp(d, v) against (F(d + e v) - F(d - e v)) / 2e, and <jvp(d, v), w> against <v, vjp(d, w)>
    (the same derivatives forward and backward: a tolerance of the arithmetic's, not the difference's)."""
    pushed = operator.jvp(heights, probe.direction)
    require(tuple(pushed.shape) == tuple(operator.output_shape) and pushed.dtype == operator.dtype, who,
            f"jvp gives shape {tuple(pushed.shape)} and dtype {pushed.dtype}, the images are "
            f"{tuple(operator.output_shape)} {operator.dtype}")
    numeric = (probe.plus - probe.minus) / (2.0 * probe.eps)
    error = float(torch.linalg.vector_norm(pushed.double() - numeric)) / max(
        float(torch.linalg.vector_norm(numeric)), 1e-30)
    require(error <= probe.tolerance, who, f"jvp differs from finite differences by {error:.3g} relative "
            f"(tolerance {probe.tolerance:g})")
    w = torch.rand(operator.output_shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    left = float((pushed.double() * w).sum())
    right = probe.along(operator.vjp(heights, w.to(operator.dtype)))
    exact = 1e-10 if operator.dtype == torch.float64 else 1e-4
    require(abs(left - right) <= exact * max(abs(left), abs(right), 1e-30), who,
            f"jvp and vjp disagree: <jvp(d, v), w> = {left:.12g} but <v, vjp(d, w)> = {right:.12g}")


def _check_gradient(operator: Any, heights: torch.Tensor, probe: _Probe, who: str) -> None:
    """<grad L(d), v> against (L(d + e v) - L(d - e v)) / 2e for L = 1/2 ||F(d) - target||^2."""
    target = operator.render(torch.zeros_like(heights)) * 0.9
    _, grad, _ = operator.loss_and_grad(heights, target)
    require(tuple(grad.shape) == tuple(heights.shape), who,
             f"loss_and_grad gives a gradient of shape {tuple(grad.shape)} for heights {tuple(heights.shape)}")
    def loss(image: torch.Tensor) -> float:
        return 0.5 * float(((image - target.double()) ** 2).sum())

    numeric = (loss(probe.plus) - loss(probe.minus)) / (2.0 * probe.eps)
    analytic = probe.along(grad)
    require(probe.close(numeric, analytic), who,
             f"the gradient's directional derivative {analytic:.8g} differs from finite differences {numeric:.8g} "
             f"(relative tolerance {probe.tolerance:g})")
