"""Images scaled by one number: the camera's gain, and photon flux per pixel turned into irradiance."""

from __future__ import annotations

import math

import torch

from operators.linear.linear_map import LinearMap

__all__ = ["Gain", "PerPixelArea"]


class Gain(LinearMap):
    """x -> gain x: the exposure gain of a camera (image units per W per scene unit^2); self-adjoint."""

    def __init__(self, gain: float) -> None:
        if not (math.isfinite(gain) and gain > 0.0):
            raise ValueError(f"gain={gain!r} must be a positive finite number")
        self.gain = float(gain)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return self.gain * x

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.gain * y

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(1.7), (2, 5, 5)


class PerPixelArea(LinearMap):
    """Flux per pixel (W) -> irradiance (W per scene unit^2): x / area, area a receiver pixel's in
    scene units^2; self-adjoint."""

    def __init__(self, area: float) -> None:
        if not (math.isfinite(area) and area > 0.0):
            raise ValueError(f"pixel area {area!r} must be a positive finite number")
        self.area = float(area)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return x / self.area

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return y / self.area

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(0.01), (1, 6, 6)
