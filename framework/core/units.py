"""Physical units: the length of one scene unit in millimetres, and lengths or volumes given in mm.

The optics are scale free, so the scene is set up in scene units; ``units.mm_per_unit`` says how
long one scene unit is (the paper's sample: 1 unit = 2.5 cm, so 25 mm per unit). Every length
of the scene config (light position, substrate, receiver, screen blur, the optical elements'
placements and sizes), the plugins' length parameters (their ``length_keys``: height bounds,
preconditioner lengths, the mask threshold) and the deposited volume may be given either as a number in scene units or
as a string with a unit, e.g. ``substrate.thickness="2.5 mm"`` or ``data.volume="1.7 mm3"``
(parsed by operators/lengths.py); outputs in millimetres (framework/files/mm_outputs.py) are converted back
with the same factor.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from operators.lengths import DEFAULT_MM_PER_UNIT, scene_length, scene_volume
from operators.values import checked_number

__all__ = ["DEFAULT_MM_PER_UNIT", "mm_per_unit", "scene_length", "scene_volume"]


def mm_per_unit(cfg: Mapping[str, Any]) -> float:
    """Millimetres per scene unit from ``units.mm_per_unit`` (default 25: the paper's 2.5 cm)."""
    units = cfg.get("units") or {}
    if not isinstance(units, Mapping):
        raise ValueError(f"units={units!r} must be a mapping, e.g. {{mm_per_unit: 25.0}}")
    unknown = [k for k in units if k != "mm_per_unit"]
    if unknown:
        raise ValueError(f"unknown key units.{unknown[0]}; units takes mm_per_unit")
    value = units.get("mm_per_unit", DEFAULT_MM_PER_UNIT)
    return checked_number(value, "units.mm_per_unit", above=0.0, must="must be a length > 0 in mm per scene unit",
                          example="25 (the paper: 1 scene unit = 2.5 cm)")
