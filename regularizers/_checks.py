"""The regularizers' own checks, on the value checks of operators/values.py: a pair of height
bounds and a relative volume tolerance."""

from __future__ import annotations

from typing import Any

from operators.values import checked_number


def checked_bounds(p1: Any, p2: Any) -> tuple[float, float]:
    """``(p1, p2)`` as floats if they are finite with ``p1 <= p2``, else a ValueError."""
    lo, hi = checked_number(p1, "p1", unit="scene units"), checked_number(p2, "p2", unit="scene units")
    if lo > hi:
        raise ValueError(f"p1={p1!r} exceeds p2={p2!r}; pass height bounds p1 <= p2 (e.g. p1=0.0, p2=0.3)")
    return lo, hi


def checked_relative_tolerance(value: Any, key: str = "v_eps") -> float:
    """A relative volume uncertainty in [0, 1), else a ValueError naming ``key``."""
    return checked_number(value, key, least=0.0, below=1.0, unit="relative volume uncertainty",
                          example="0.25 (the paper's V1 band) or 0.02")
