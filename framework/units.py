"""Physical units: the length of one scene unit in millimetres, and lengths or volumes given in mm.

The optics are scale free, so the scene is set up in scene units; ``units.mm_per_unit`` says how
long one scene unit is (the paper's sample: 1 unit = 2.5 cm, so 25 mm per unit). Every length
of the scene config (light position, substrate, receiver, screen blur) and the deposited volume
may be given either as a number in scene units or as a string with a unit, e.g.
``substrate.thickness="2.5 mm"`` or ``data.volume="1.7 mm3"``; outputs in millimetres
(framework/export.py) are converted back with the same factor.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

__all__ = ["DEFAULT_MM_PER_UNIT", "mm_per_unit", "scene_length", "scene_volume"]

DEFAULT_MM_PER_UNIT = 25.0

_LENGTH_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "µm": 1e-3}
_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ]+)(\^?3)?\s*$")


def mm_per_unit(cfg: Mapping[str, Any]) -> float:
    """Millimetres per scene unit from ``units.mm_per_unit`` (default 25: the paper's 2.5 cm)."""
    units = cfg.get("units") or {}
    if not isinstance(units, Mapping):
        raise ValueError(f"units={units!r} must be a mapping, e.g. {{mm_per_unit: 25.0}}")
    unknown = [k for k in units if k != "mm_per_unit"]
    if unknown:
        raise ValueError(f"unknown key units.{unknown[0]}; units takes mm_per_unit")
    value = units.get("mm_per_unit", DEFAULT_MM_PER_UNIT)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"units.mm_per_unit={value!r} must be a length > 0 in mm per scene unit, "
                         "e.g. 25 (the paper: 1 scene unit = 2.5 cm)")
    return float(value)


def _quantity(value: Any, where: str, cubic: bool) -> tuple[float, float | None]:
    """(number, mm per given unit, or None for a bare number in scene units)."""
    if isinstance(value, bool):
        raise ValueError(f"{where}={value!r} must be a number (scene units) or a string such as '2.5 mm'")
    if isinstance(value, (int, float)):
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
