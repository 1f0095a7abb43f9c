"""Checked numbers from configs and arguments: one rule and one message per kind of value."""

from __future__ import annotations

import math
from typing import Any

import torch

__all__ = ["described", "non_negative_number", "positive_int", "positive_number"]


def described(value: object) -> str:
    """A tensor's shape and dtype, or another value's type, for an error message."""
    if isinstance(value, torch.Tensor):
        return f"shape {tuple(value.shape)}, {value.dtype}"
    return type(value).__name__


def positive_number(value: Any, where: str, what: str = "number") -> float:
    """``value`` as a finite float > 0 (not a bool), else a ValueError: '<where>=<value> must be a
    finite <what> > 0'."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{where}={value!r} must be a finite {what} > 0")
    return float(value)


def non_negative_number(value: Any, where: str, what: str = "number") -> float:
    """``value`` as a finite float >= 0 (not a bool), else a ValueError: '<where>=<value> must be a
    finite <what> >= 0'."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{where}={value!r} must be a finite {what} >= 0")
    return float(value)


def positive_int(value: Any, where: str) -> int:
    """``value`` as an integer >= 1 (not a bool), else a ValueError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{where}={value!r} must be an integer >= 1")
    return value
