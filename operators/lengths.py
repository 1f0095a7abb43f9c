"""Lengths and volumes given as a number in scene units or as a string with a unit ('2.5 mm').

The parser behind framework/core/units.py (which reads ``units.mm_per_unit`` from the config), here so
that the operators (e.g. the optical elements' lengths) read their lengths the same way.
"""

from __future__ import annotations

import re
from typing import Any

from operators.values import is_number

__all__ = ["DEFAULT_MM_PER_UNIT", "scene_length", "scene_volume"]

DEFAULT_MM_PER_UNIT = 25.0

_LENGTH_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "µm": 1e-3}
_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ]+)(\^?3)?\s*$")


def _quantity(value: Any, where: str, cubic: bool) -> tuple[float, float | None]:
    """(number, mm per given unit, or None for a bare number in scene units)."""
    if is_number(value):
        return float(value), None
    example = "'1.7 mm3'" if cubic else "'2.5 mm'"
    match = _QUANTITY.match(value) if isinstance(value, str) else None
    if match is None or match.group(2) not in _LENGTH_MM or bool(match.group(3)) != cubic:
        raise ValueError(f"{where}={value!r} must be a number (scene units) or a string such as {example} "
                         f"(units: {', '.join(u + ('3' if cubic else '') for u in _LENGTH_MM)})")
    return float(match.group(1)), _LENGTH_MM[match.group(2)]


def scene_length(value: Any, mm_per_scene_unit: float, where: str) -> float:
    """A length in scene units from a number (scene units) or a string with a unit ('2.5 mm')."""
    number, mm = _quantity(value, where, cubic=False)
    return number if mm is None else number * mm / mm_per_scene_unit


def scene_volume(value: Any, mm_per_scene_unit: float, where: str) -> float:
    """A volume in scene units^3 from a number (scene units^3) or a string ('1.7 mm3')."""
    number, mm = _quantity(value, where, cubic=True)
    return number if mm is None else number * mm ** 3 / mm_per_scene_unit ** 3
