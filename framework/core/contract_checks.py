"""The contract every plugin of a kind keeps, as checks a test runs on each registered plugin.

tests/test_plugin_contracts.py runs them on every installed plugin of the kinds below (third-party
ones included, found through their entry points); a plugin package may call them from its own
tests. A plugin with required settings declares an example of them in a classmethod
``example_settings() -> dict`` (e.g. the mesh scene's elements); optional physics is declared, not
discovered: an operator that conserves energy says so with ``conserves_energy = True``.

- operator (:func:`check_operator`): the declared output shape and dtype, finite non-negative
  images, determinism under a seed, the gradient of ``loss_and_grad`` against central finite
  differences (the adjoint of the operator's linearisation: <J^T w, v> = <w, J v>), the power on
  the receiver unchanged by a small print when energy is conserved, and bad heights refused
  (wrong shape, NaN) with a ValueError;
- regularizer (:func:`check_regularizer`): ``prox`` is the minimiser of step R(x) + 1/2 ||x - d||^2
  (no nearby point does better), its result lies where R is finite, and ``value`` is finite there;
- post_step (:func:`check_post_step`): same shape and dtype, finite, the input untouched,
  deterministic.

A failed check raises :class:`ContractViolation` naming the plugin and the check.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import torch

from regularizers import PostStepUpdate, Regularizer, RegularizerContext

__all__ = ["ContractViolation", "example_settings", "check_operator", "check_regularizer", "check_post_step",
           "smooth_bump"]


class ContractViolation(AssertionError):
    """A plugin breaks its kind's contract."""


def _require(condition: bool, who: str, what: str) -> None:
    if not condition:
        raise ContractViolation(f"{who}: {what}")


def example_settings(plugin: Any) -> dict[str, Any]:
    """The settings a plugin declares for the contract checks (its ``example_settings()``), else {}."""
    example = getattr(plugin, "example_settings", None)
    return dict(example()) if callable(example) else {}


def smooth_bump(m: int, height: float = 0.02, width: float = 0.3) -> torch.Tensor:
    """A Gaussian bump (m, m), float64, scene units, on the grid linspace(-1, 1, m)."""
    axis = torch.linspace(-1.0, 1.0, m, dtype=torch.float64)
    y, x = torch.meshgrid(axis, axis, indexing="ij")
    return height * torch.exp(-(x ** 2 + y ** 2) / (2.0 * width ** 2))


def check_operator(make: Callable[[int], Any], m: int = 16, who: str = "operator") -> None:
    """Check an operator plugin built by ``make(seed)`` on heights of an m x m grid."""
    operator = make(0)
    dtype = operator.dtype
    flat = torch.zeros(m, m, dtype=dtype)
    bump = smooth_bump(m).to(dtype) + 1e-3
    image = operator.render(bump)
    _require(tuple(image.shape) == tuple(operator.output_shape), who,
             f"render gives shape {tuple(image.shape)}, output_shape says {tuple(operator.output_shape)}")
    _require(image.dtype == dtype, who, f"render gives dtype {image.dtype}, the operator's dtype is {dtype}")
    _require(bool(torch.isfinite(image).all()) and float(image.min()) >= 0.0, who,
             "render gives a negative or non-finite irradiance")
    _require(torch.equal(make(0).render(bump), image), who, "two operators of one seed render differently")
    _check_gradient(operator, bump, who)
    if getattr(operator, "conserves_energy", False):
        power = [float(operator.render(d).double().sum()) * operator.pixel_area for d in (flat, bump)]
        _require(power[0] > 0 and abs(power[1] - power[0]) <= 0.02 * power[0], who,
                 f"the power on the receiver changes from {power[0]:.6g} to {power[1]:.6g} under a small print "
                 "(declared conserves_energy)")
    for bad, what in ((torch.zeros(m, m + 1, dtype=dtype), "non-square heights"),
                      (torch.full((m, m), math.nan, dtype=dtype), "NaN heights")):
        try:
            operator.render(bad)
        except ValueError:
            continue
        raise ContractViolation(f"{who}: render accepts {what} instead of raising a ValueError")


def _check_gradient(operator: Any, heights: torch.Tensor, who: str) -> None:
    """<grad L(d), v> against (L(d + e v) - L(d - e v)) / 2e for L = 1/2 ||F(d) - target||^2."""
    generator = torch.Generator().manual_seed(1)
    target = operator.render(torch.zeros_like(heights)) * 0.9
    direction = (torch.randn(heights.shape, generator=generator, dtype=torch.float64) * smooth_bump(
        heights.shape[0], 1.0, 0.5)).to(heights.dtype)
    double = heights.dtype == torch.float64
    eps, tolerance = (1e-6, 1e-4) if double else (1e-3, 5e-2)
    _, grad, _ = operator.loss_and_grad(heights, target)
    _require(tuple(grad.shape) == tuple(heights.shape), who,
             f"loss_and_grad gives a gradient of shape {tuple(grad.shape)} for heights {tuple(heights.shape)}")
    loss = lambda d: 0.5 * float(((operator.render(d).double() - target.double()) ** 2).sum())  # noqa: E731
    numeric = (loss(heights + eps * direction) - loss(heights - eps * direction)) / (2.0 * eps)
    analytic = float((grad.double() * direction.double()).sum())
    _require(abs(numeric - analytic) <= tolerance * max(abs(numeric), abs(analytic), 1e-30), who,
             f"the gradient's directional derivative {analytic:.8g} differs from finite differences {numeric:.8g} "
             f"(relative tolerance {tolerance:g})")


def _context(m: int) -> RegularizerContext:
    mask = torch.zeros(m, m, dtype=torch.bool)
    mask[m // 4: 3 * m // 4, m // 4: 3 * m // 4] = True
    area = (2.0 / m) ** 2
    return RegularizerContext(mask=mask, volume=0.05 * float(mask.sum()) * area, pixel_area=area)


def check_regularizer(regularizer: Regularizer, m: int = 16, who: str = "regularizer", trials: int = 30) -> None:
    """Check a regularizer: with ``has_prox``, prox(d, step) minimises step R(x) + 1/2 ||x - d||^2
    (no random nearby point, nor its projection, does better) and R is finite at it."""
    _require(isinstance(regularizer, Regularizer), who, f"is a {type(regularizer).__name__}, not a Regularizer")
    regularizer.setup(_context(m))
    generator = torch.Generator().manual_seed(0)
    d = 0.2 * torch.rand(m, m, generator=generator, dtype=torch.float64) - 0.05
    _require(math.isfinite(regularizer.value(regularizer.project(d))), who, "value is not finite at project(d)")
    if not regularizer.has_prox:
        return
    for step in (1e-3, 1e-1, 10.0):
        x = regularizer.prox(d, step)
        best = step * regularizer.value(x) + 0.5 * float(((x - d) ** 2).sum())
        _require(math.isfinite(best), who, f"value is not finite at prox(d, {step:g})")
        for trial in range(trials):
            scale = 10.0 ** (-1 - trial % 4)
            y = x + scale * torch.randn(m, m, generator=generator, dtype=torch.float64)
            for candidate in (y, regularizer.project(y)):
                other = step * regularizer.value(candidate) + 0.5 * float(((candidate - d) ** 2).sum())
                _require(other >= best - 1e-9 * (1.0 + abs(best)), who,
                         f"prox(d, {step:g}) is not the minimiser: a point {scale:g} away does better "
                         f"({other:.10g} < {best:.10g})")


def check_post_step(post_step: PostStepUpdate, m: int = 16, who: str = "post_step") -> None:
    """Check a post-step update: same shape and dtype, finite, the input untouched, deterministic."""
    _require(isinstance(post_step, PostStepUpdate), who, f"is a {type(post_step).__name__}, not a PostStepUpdate")
    post_step.setup(_context(m))
    d = smooth_bump(m, 0.05)
    before = d.clone()
    out = post_step(d)
    _require(out.shape == d.shape and out.dtype == d.dtype, who,
             f"gives {tuple(out.shape)} {out.dtype} for {tuple(d.shape)} {d.dtype}")
    _require(bool(torch.isfinite(out).all()), who, "gives non-finite heights")
    _require(torch.equal(d, before), who, "modifies its input")
    _require(torch.equal(post_step(d), out), who, "is not deterministic")
