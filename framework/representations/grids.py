"""The free grids as representations: the heights themselves (the paper's M2) and their db3
wavelet coefficients (M3).

``pixels``: theta = d flattened, R the identity. ``wavelets``: theta = W d, the orthogonal
Daubechies transform of regularizers/wavelet.py, R = W^-1 and J^T g = W g (W orthogonal).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from framework.core.contracts.representation import Representation
from regularizers.wavelet import WaveletTransform

__all__ = ["PixelHeights", "WaveletHeights"]


def _grid(d0: Tensor) -> tuple[int, int]:
    if not isinstance(d0, Tensor) or d0.ndim != 2 or d0.shape[0] != d0.shape[1]:
        shape = tuple(d0.shape) if isinstance(d0, Tensor) else type(d0).__name__
        raise ValueError(f"a grid representation starts from square heights (m, m), got {shape}")
    return int(d0.shape[0]), int(d0.shape[1])


class PixelHeights(Representation):
    """theta = d (m * m,): every height sample free (``nonnegative``: bounded below by 0).

    Args:
        d0: The start (m, m), scene units.
        nonnegative: Heights >= 0 (printed glass adds material).
    """

    def __init__(self, d0: Tensor, nonnegative: bool = True) -> None:
        self.shape = _grid(d0)
        self.size = self.shape[0] * self.shape[1]
        self.dtype = d0.dtype
        self._d0 = d0.detach().clone()
        self.nonnegative = bool(nonnegative)

    @classmethod
    def from_config(cls, nonnegative: bool = True) -> Any:
        """A builder (problem, d0) -> PixelHeights (the ``representation`` group's keys)."""
        return lambda problem, d0: cls(d0, nonnegative)

    def initial(self) -> Tensor:
        return self._d0.reshape(-1).clone()

    def heights(self, theta: Tensor) -> Tensor:
        return theta.reshape(self.shape)

    def vjp(self, theta: Tensor, g: Tensor) -> Tensor:
        return g.reshape(-1).to(theta)

    def bounds(self) -> tuple[Tensor, Tensor]:
        lower, upper = super().bounds()
        return (torch.zeros_like(lower) if self.nonnegative else lower), upper

    def scale(self) -> Tensor:
        peak = float(self._d0.abs().max())
        return torch.full((self.size,), peak if peak > 0.0 else 1.0, dtype=self.dtype)


class WaveletHeights(Representation):
    """theta = W d (m * m,): the heights' orthogonal wavelet coefficients (unbounded).

    Args:
        d0: The start (m, m), scene units; m divisible by 2**levels.
        wavelet: An orthogonal PyWavelets wavelet (the paper's "db3").
        levels: Decomposition levels (the paper's 3).
    """

    def __init__(self, d0: Tensor, wavelet: str = "db3", levels: int = 3) -> None:
        self.shape = _grid(d0)
        self.size = self.shape[0] * self.shape[1]
        self.dtype = d0.dtype
        self.transform = WaveletTransform(self.shape, wavelet, levels)
        self._theta0 = self.transform.forward(d0.detach())

    @classmethod
    def from_config(cls, wavelet: str = "db3", levels: int = 3) -> Any:
        """A builder (problem, d0) -> WaveletHeights (the ``representation`` group's keys)."""
        return lambda problem, d0: cls(d0, wavelet, levels)

    def initial(self) -> Tensor:
        return self._theta0.clone()

    def heights(self, theta: Tensor) -> Tensor:
        return self.transform.inverse(theta)

    def vjp(self, theta: Tensor, g: Tensor) -> Tensor:
        return self.transform.forward(g.to(theta))

    def scale(self) -> Tensor:
        peak = float(self._theta0.abs().max())
        return torch.full((self.size,), peak if peak > 0.0 else 1.0, dtype=self.dtype)
