"""A linear stage of your own in the camera's chain: a lens's vignetting, the light that reaches
a pixel falling off as cos^4 of its angle from the axis.

    V x = v * x,   v[i, j] = cos^4(theta_ij) = (1 + r_ij^2 / f^2)^-2,

r_ij the pixel's distance from the screen's centre and f the camera's distance to the screen
(scene units). V is diagonal, hence self-adjoint. It joins the chain of
:class:`operators.imaging.ImagingOperator` through ``stages=[Vignetting(...)]``, which renders
gain V A K F(d) and takes its gradient through the chain's adjoint; the shared contract
(framework/core/contracts/linear_checks.py, run on every linear piece by
tests/test_plugin_contracts.py) dot-tests it through :meth:`Vignetting.example`.
"""

from __future__ import annotations

import torch

from operators.linear import LinearMap

__all__ = ["Vignetting"]


class Vignetting(LinearMap):
    """V: each pixel of (c, n, n) images scaled by cos^4 of its angle from the camera's axis.

    Args:
        resolution: n, the image's pixels per side.
        half_width: Half the screen's side, scene units.
        distance: The camera's distance to the screen, scene units.
    """

    def __init__(self, resolution: int, half_width: float, distance: float) -> None:
        if not distance > 0.0:
            raise ValueError(f"distance={distance!r} must be > 0 (the camera's distance to the screen)")
        centres = (torch.arange(resolution, dtype=torch.float64) + 0.5) / resolution * 2.0 * half_width - half_width
        r2 = centres[None, :] ** 2 + centres[:, None] ** 2
        self.falloff = (1.0 + r2 / distance ** 2) ** -2  # (n, n)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.falloff.to(x)

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.apply(y)

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(8, 1.0, 3.0), (2, 8, 8)
