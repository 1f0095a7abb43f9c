"""Dispersion curves n(lambda) of transparent materials; wavelengths in micrometres."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol
from collections.abc import Sequence

from operators.values import is_number

# The coefficients each material kind takes (``kind`` and ``name`` aside).
MATERIAL_KEYS: dict[str, tuple[str, ...]] = {
    "fused_silica": (),
    "sellmeier": ("b", "c"),
    "cauchy": ("a", "b", "c"),
    "constant": ("n",),
}


class DispersionCurve(Protocol):
    """Refractive index as a function of the vacuum wavelength (micrometres)."""

    def index(self, wavelength_um: float) -> float: ...


@dataclass(frozen=True)
class Sellmeier:
    """n^2 = 1 + sum_i B_i L^2 / (L^2 - C_i^2), L in micrometres, C_i resonance wavelengths (um)."""

    b: tuple[float, ...]
    c: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.b) != len(self.c) or not self.b:
            raise ValueError(f"Sellmeier needs as many B as C coefficients (got {len(self.b)} B, "
                             f"{len(self.c)} C); give e.g. b=[0.696,0.408,0.897] c=[0.068,0.116,9.896]")

    def index(self, wavelength_um: float) -> float:
        l2 = wavelength_um ** 2
        n2 = 1.0 + sum(b * l2 / (l2 - c * c) for b, c in zip(self.b, self.c))
        if n2 <= 0.0:
            raise ValueError(f"Sellmeier curve gives n^2={n2:.4g} at {wavelength_um} um (a resonance); "
                             "use a wavelength inside the fit's range")
        return math.sqrt(n2)


@dataclass(frozen=True)
class Cauchy:
    """n = A + B / L^2 + C / L^4 (L in micrometres)."""

    a: float
    b: float = 0.0
    c: float = 0.0

    def index(self, wavelength_um: float) -> float:
        return self.a + self.b / wavelength_um ** 2 + self.c / wavelength_um ** 4


@dataclass(frozen=True)
class ConstantIndex:
    """The same refractive index at every wavelength."""

    n: float

    def index(self, wavelength_um: float) -> float:
        return self.n


# Malitson (1965) fit for fused silica, valid 0.21 um - 6.7 um (docs/method.md, "Setup and units").
FUSED_SILICA = Sellmeier(b=(0.6961663, 0.4079426, 0.8974794), c=(0.0684043, 0.1162414, 9.896161))


def make_material(spec: dict[str, Any]) -> DispersionCurve:
    """Build a dispersion curve from a config mapping.

    ``{"kind": "fused_silica"}``, ``{"kind": "sellmeier", "b": [...], "c": [...]}``,
    ``{"kind": "cauchy", "a": 1.45, "b": 0.0036}`` or ``{"kind": "constant", "n": 1.5}``.
    """
    kind = spec.get("kind", "fused_silica")
    params = {k: v for k, v in spec.items() if k not in ("kind", "name")}
    if kind == "fused_silica":
        return FUSED_SILICA
    if kind == "sellmeier":
        return Sellmeier(b=tuple(params["b"]), c=tuple(params["c"]))
    if kind == "cauchy":
        return Cauchy(**params)
    if kind == "constant":
        return ConstantIndex(n=float(params["n"]))
    raise ValueError(f"unknown material kind {kind!r}; use fused_silica, sellmeier, cauchy or constant")


def _coefficient(value: Any, where: str, listed: bool) -> None:
    """Refuse a coefficient that is not a number (``listed``: a non-empty list of numbers)."""
    values = value if listed and isinstance(value, (list, tuple)) and value else [value]
    if (listed and not isinstance(value, (list, tuple))) or not all(is_number(v) for v in values):
        raise ValueError(f"{where}={value!r} must be {'a list of numbers' if listed else 'a number'}, "
                         f"e.g. {where}={'[0.696, 0.408, 0.897]' if listed else '1.5'}")


def material_from_config(spec: Any, where: str = "material") -> DispersionCurve:
    """The dispersion curve of config ``spec`` (:func:`make_material`; None: fused silica), its
    kind, keys and coefficients checked first; errors name the keys under ``where``."""
    if spec is None:
        return FUSED_SILICA
    if not isinstance(spec, Mapping):
        raise ValueError(f"{where}={spec!r} must be a mapping, e.g. {{kind: fused_silica}}")
    kind = spec.get("kind", "fused_silica")
    if not isinstance(kind, str) or kind not in MATERIAL_KEYS:
        raise ValueError(f"unknown {where}.kind {kind!r}; use {', '.join(MATERIAL_KEYS)}")
    allowed = ("kind", "name") + MATERIAL_KEYS[kind]
    for key in spec:
        if key not in allowed:
            raise ValueError(f"unknown key {where}.{key}; allowed keys of {where}: {', '.join(allowed)}")
    missing = [k for k in MATERIAL_KEYS[kind] if k not in spec and not (kind == "cauchy" and k != "a")]
    if missing:
        raise ValueError(f"material kind {kind!r} needs {where}.{missing[0]}; give e.g. {where}.{missing[0]}=...")
    for key in MATERIAL_KEYS[kind]:
        if key in spec:
            _coefficient(spec[key], f"{where}.{key}", listed=kind == "sellmeier")
    return make_material(dict(spec))


def refractive_indices(material: DispersionCurve, wavelengths_um: Sequence[float]) -> list[float]:
    """Index per wavelength, validated: every wavelength > 0 and every index >= 1."""
    indices = []
    for lam in wavelengths_um:
        if not lam > 0.0:
            raise ValueError(f"wavelength {lam} um is not positive; give wavelengths in micrometres, e.g. [0.633]")
        n = material.index(lam)
        if not n >= 1.0:
            raise ValueError(f"refractive index {n:.4g} at {lam} um is below 1; check the material coefficients")
        indices.append(n)
    return indices
