"""Input validation shared by the regularizers: one clear line per error, naming value and fix."""

from __future__ import annotations

import math

import torch


def check_height_field(d: torch.Tensor, name: str = "d") -> None:
    """Raise ``ValueError`` unless ``d`` is a finite, floating-point 2-D tensor.

    Args:
        d: Height field, shape (m, m), scene units.
        name: How the argument is called in the error message.
    """
    if not isinstance(d, torch.Tensor):
        kind = type(d).__name__
        raise ValueError(f"{name} must be a torch.Tensor, got {kind}; wrap it with torch.as_tensor")
    if d.ndim != 2:
        raise ValueError(f"{name} must be a 2-D height field (m, m), got shape {tuple(d.shape)}; pass one channel")
    if not d.is_floating_point():
        raise ValueError(f"{name} has dtype {d.dtype}; pass a floating-point tensor (float32 or float64)")
    if not bool(torch.isfinite(d).all()):
        bad = int((~torch.isfinite(d)).sum())
        raise ValueError(f"{name} contains {bad} NaN/inf value(s); check the step size or the gradient behind it")


def check_positive(value: float, name: str, fix: str) -> float:
    """Return ``float(value)`` if it is finite and > 0, else raise ``ValueError`` with ``fix``."""
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}; {fix}")
    return v


def check_nonnegative(value: float, name: str, fix: str) -> float:
    """Return ``float(value)`` if it is finite and >= 0, else raise ``ValueError`` with ``fix``."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ValueError(f"{name} must be a non-negative finite number, got {value!r}; {fix}")
    return v


def check_bounds(p1: float, p2: float) -> tuple[float, float]:
    """Return ``(p1, p2)`` as floats if they are finite with ``p1 <= p2``, else raise ``ValueError``."""
    lo, hi = float(p1), float(p2)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"height bounds must be finite, got p1={p1!r}, p2={p2!r}; pass finite scene-unit heights")
    if lo > hi:
        raise ValueError(
            f"lower height bound p1={p1!r} exceeds upper bound p2={p2!r}; pass p1 <= p2 (e.g. p1=0.0, p2=0.3)"
        )
    return lo, hi


def check_relative_tolerance(v_eps: float, name: str = "v_eps") -> float:
    """Return ``v_eps`` as float if it lies in [0, 1), else raise ``ValueError`` naming ``name``."""
    v = float(v_eps)
    if not (0.0 <= v < 1.0):
        raise ValueError(f"relative volume uncertainty {name}={v_eps!r} must lie in [0, 1), e.g. 0.25 (the paper's "
                         "V1 band) or 0.02")
    return v
