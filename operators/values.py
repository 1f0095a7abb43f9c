"""Checked values from configs and arguments: the one family of value checks every package uses.

operators/ is the lowest package (regularizers/ and framework/ import it, it imports neither), so
the checks live here. Every error is one line in one format, ``<key>=<value> must be ...``,
naming the config key (or argument) and, where the caller gives one, an example of a good value.
A bool is never a number (``True`` is refused where a count or a length is asked), and a number
is finite unless the caller allows infinity.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
import torch

__all__ = ["checked_flag", "checked_height_field", "checked_number", "checked_print_heights", "checked_seed",
           "checked_whole", "described", "is_number"]


def described(value: object) -> str:
    """A tensor's shape and dtype, or another value's type, for an error message."""
    if isinstance(value, torch.Tensor):
        return f"shape {tuple(value.shape)}, {value.dtype}"
    return type(value).__name__


def is_number(value: object) -> bool:
    """Whether ``value`` is a real number: an int or a float, NumPy's too (a bool is not a number here)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _number_phrase(least: float, most: float, above: float | None, below: float | None) -> str:
    """'must be a positive number', 'must be a number in [0, 1)', ... for the bounds given."""
    low = None if above is None and least == -math.inf else ("(" if above is not None else "[",
                                                               above if above is not None else least)
    high = None if below is None and most == math.inf else (")" if below is not None else "]",
                                                            below if below is not None else most)
    if low and high:
        return f"must be a number in {low[0]}{low[1]:g}, {high[1]:g}{high[0]}"
    if low:
        if low == ("(", 0):
            return "must be a positive number"
        return f"must be a number {'>' if low[0] == '(' else '>='} {low[1]:g}"
    if high:
        return f"must be a number {'<' if high[0] == ')' else '<='} {high[1]:g}"
    return "must be a finite number"


def checked_number(value: Any, key: str, least: float = -math.inf, most: float = math.inf, *,
                   above: float | None = None, below: float | None = None, must: str | None = None,
                   unit: str | None = None, example: str | None = None) -> float:
    """``value`` as a float: a finite number (not a bool) with ``least <= value <= most`` and, where
    given, ``value > above`` and ``value < below``; else a ValueError ``<key>=<value> must be ...``
    (``must`` replaces the generated phrase; ``unit`` is appended in parentheses, ``example`` as
    ``, e.g. <example>``)."""
    ok = is_number(value) and math.isfinite(value) and least <= value <= most
    ok = ok and (above is None or value > above) and (below is None or value < below)
    if not ok:
        phrase = must or _number_phrase(least, most, above, below)
        raise ValueError(f"{key}={value!r} {phrase}" + (f" ({unit})" if unit else "")
                         + (f", e.g. {example}" if example else ""))
    return float(value)


def checked_whole(value: Any, key: str, least: int | None = None, most: int | None = None, *,
                  must: str | None = None, example: str | None = None) -> int:
    """``value`` as an int: a whole number (8 or 8.0, as YAML's 1e6 reads; not True) in [least, most]
    where given; else a ValueError ``<key>=<value> must be an integer >= <least>`` (or ``must``, and
    ``example``)."""
    ok = is_number(value) and math.isfinite(value) and int(value) == value
    ok = ok and (least is None or value >= least) and (most is None or value <= most)
    if not ok:
        bounds = " and ".join(
            b for b in ("" if least is None else f">= {least}", "" if most is None else f"<= {most}") if b
        )
        phrase = must or ("must be an integer" + (f" {bounds}" if bounds else ""))
        raise ValueError(f"{key}={value!r} {phrase}" + (f", e.g. {example}" if example else ""))
    return int(value)


def checked_seed(value: Any, key: str = "seed") -> int:
    """``value`` as a seed of torch's and numpy's generators: an integer in [0, 2^63)."""
    return checked_whole(value, key, 0, 2 ** 63 - 1, must="must be an integer in [0, 2^63)")


def checked_flag(value: Any, key: str) -> bool:
    """``value`` if it is a bool, else a ValueError ``<key>=<value> must be true or false``."""
    if not isinstance(value, bool):
        raise ValueError(f"{key}={value!r} must be true or false")
    return value


def checked_height_field(d: Any, key: str = "d") -> torch.Tensor:
    """``d`` if it is a finite floating-point tensor (m, m), else a ValueError naming ``key`` and the fix."""
    if not isinstance(d, torch.Tensor):
        raise ValueError(f"{key} must be a torch.Tensor, got {type(d).__name__}; wrap it with torch.as_tensor")
    if d.ndim != 2:
        raise ValueError(f"{key} must be a 2-D height field (m, m), got shape {tuple(d.shape)}; pass one channel")
    if not d.is_floating_point():
        raise ValueError(f"{key} has dtype {d.dtype}; pass a floating-point tensor (float32 or float64)")
    if not bool(torch.isfinite(d).all()):
        bad = int((~torch.isfinite(d)).sum())
        raise ValueError(f"{key} contains {bad} NaN/inf value(s); check the step size or the gradient behind it")
    return d


def checked_print_heights(heights: torch.Tensor, thickness: float) -> torch.Tensor:
    """``heights`` when they are a finite, square (m, m) height field (m >= 4) whose glass top
    stays above the substrate bottom (d > -thickness; iterates of M1 may dip below d = 0): what an
    operator renders; anything else is refused in one line."""
    if not isinstance(heights, torch.Tensor):
        raise TypeError(f"heights must be a torch.Tensor, got {type(heights).__name__}")
    if heights.dim() != 2 or heights.shape[0] != heights.shape[1]:
        raise ValueError(f"heights must be a square (m, m) array, got shape {tuple(heights.shape)}")
    if heights.shape[0] < 4:
        raise ValueError(f"heights resolution {heights.shape[0]} is too small; use m >= 4")
    if not bool(torch.isfinite(heights).all()):
        raise ValueError("heights contain NaN or infinite values; clean the height field first")
    if float(heights.min()) <= -thickness:
        raise ValueError(f"heights reach {float(heights.min()):.4g}, below the substrate bottom "
                         f"(d must exceed -thickness = {-thickness}); printed heights are >= 0")
    return heights
