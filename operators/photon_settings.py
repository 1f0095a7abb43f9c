"""The numerical settings every photon operator shares, checked in one place.

:class:`PhotonSettings` holds what the height-field and the mesh-scene operators both read (the
photon count and pattern, the footprints in receiver pixels, the chunk that bounds memory, Fresnel
weights, the dtype and the CPU kernels); each operator's settings add their own fields and checks
(operators/heightfield/operator.py, operators/mesh/settings.py), all with the value checks of
operators/values.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from operators.emission import CELL_FOOTPRINT, check_footprint
from operators.values import checked_flag, checked_number, checked_whole

__all__ = ["DTYPES", "KERNELS", "PhotonSettings"]

DTYPES = {"float32": torch.float32, "float64": torch.float64}
KERNELS = ("c", "numba")  # which CPU photon kernels trace: the compiled extension's, or numba's


@dataclass(frozen=True)
class PhotonSettings:
    """What every photon operator's settings hold.

    photons: total photons per evaluation (split evenly over the wavelengths; the run's ``photons``).
    seed: seeds the emission pattern; the same seed gives the same photons (common random numbers).
    footprint_px: ``"cell"``: every footprint is the photon's own emission cell carried through
        the optics (no blur of the model's own); a number: the footprint radius on the receiver
        in pixels for light that went straight through (the paper's smoothing; operators/emission.py).
    min_footprint_px: pixel-filter radius added in quadrature to every footprint (pixels).
    pixel_integration: every pixel averages the irradiance over its area (a camera pixel, or an
        image area-averaged from a finer render), modelled by widening every footprint by the
        pixel box's second moment (operators/photon_operator.py, PIXEL_BOX_R2); False evaluates
        the irradiance at the pixel centres.
    max_pixel_radius: cut-off for the footprint's major semi-axis, in pixels (paper: 20).
    chunk_size: photons traced at once; sets the peak memory.
    fresnel: weight by Fresnel transmittance (the paper ignores Fresnel losses).
    dtype: of the images and gradients, ``float32`` or ``float64``.
    kernels: which CPU photon kernels trace (same results to rounding): ``c``, those of the
        compiled extension (operators/kernels/, compiled at install: a run traces at once);
        ``numba``, the numba kernels (compiled into numba's cache on first use, 1-2 minutes;
        docs/performance.md compares the two). Without the extension: numba.
    """

    photons: int = 1 << 22
    seed: int = 0
    footprint_px: float | str = CELL_FOOTPRINT
    min_footprint_px: float = 0.3
    pixel_integration: bool = True
    max_pixel_radius: float = 20.0
    chunk_size: int = 1 << 18
    fresnel: bool = False
    dtype: str = "float32"
    kernels: str = "c"

    def __post_init__(self) -> None:
        self._set("photons", checked_whole(self.photons, "photons", 1))
        self._set("seed", checked_whole(self.seed, "seed"))
        self._set("chunk_size", checked_whole(self.chunk_size, "operator.chunk_size", 1))
        self._set("footprint_px", check_footprint(self.footprint_px))
        for key in ("min_footprint_px", "max_pixel_radius"):
            self._set(key, checked_number(getattr(self, key), f"operator.{key}", above=0.0, unit="pixels"))
        if not self.min_footprint_px < self.max_pixel_radius:
            raise ValueError(f"need operator.min_footprint_px ({self.min_footprint_px}) < operator.max_pixel_radius "
                             f"({self.max_pixel_radius})")
        for key in ("pixel_integration", "fresnel"):
            checked_flag(getattr(self, key), f"operator.{key}")
        if not isinstance(self.dtype, str) or self.dtype not in DTYPES:
            raise ValueError(f"operator.dtype={self.dtype!r} is not supported; use float32 or float64")
        if self.kernels not in KERNELS:
            raise ValueError(f"operator.kernels={self.kernels!r} must be one of {', '.join(KERNELS)}")

    def _set(self, key: str, value: object) -> None:
        """Store a checked value on the frozen settings."""
        object.__setattr__(self, key, value)
