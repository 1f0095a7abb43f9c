"""Small float64 scenes shared by the operator tests."""

from __future__ import annotations

import numpy as np
import torch

from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Light, Receiver, Scene, Substrate


def bump(m: int, centre: tuple[float, float] = (0.0, 0.0), sigma: float = 0.3, height: float = 0.05) -> torch.Tensor:
    """Smooth Gaussian bump (m, m), [row, col] = [y, x], samples on linspace(-1, 1, m)."""
    axis = np.linspace(-1.0, 1.0, m)
    y, x = np.meshgrid(axis, axis, indexing="ij")
    d = height * np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * sigma ** 2))
    return torch.from_numpy(d)


def make_operator(photons: int = 40_000, resolution: int = 32, half_width: float = 1.0,
                  wavelengths: tuple[float, ...] = (0.633,), chunk_size: int = 1 << 18, walls: str = "clear",
                  **settings) -> CausticOperator:
    scene = Scene(light=Light(), substrate=Substrate(walls=walls),
                  receiver=Receiver(z=-0.05, resolution=resolution, half_width=half_width),
                  wavelengths=wavelengths)
    settings.setdefault("dtype", "float64")
    # A 3-pixel footprint with a 1-pixel filter: the smooth renders at few photons that the tests of
    # the machinery around the operator (gradients, stacks, calibration, starts) are built on; the
    # default model's own tests are in tests/operators/test_irradiance_model.py.
    settings.setdefault("footprint_px", 3.0)
    settings.setdefault("min_footprint_px", 1.0)
    return CausticOperator(scene, OperatorSettings(photons=photons, chunk_size=chunk_size, **settings))

