"""Shared fixtures and brute-force helpers for the regularizer tests (float64, tiny grids)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=DEVICES)
def device(request: pytest.FixtureRequest) -> torch.device:
    """Each device test runs on the CPU and, when present, on CUDA."""
    return torch.device(request.param)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240607)


def brute_force_prox_1d(
    phi: Callable[[float, float], float], w: np.ndarray, lo: float, hi: float
) -> np.ndarray:
    """argmin_x phi(x, w_j) + 1/2 (x - w_j)^2 over [lo, hi], per coordinate (bounded Brent).

    Valid for separable convex proxes: the 1-D objective is unimodal.
    """
    out = np.empty_like(w)
    for idx, wj in np.ndenumerate(w):
        res = minimize_scalar(
            lambda x: phi(x, wj) + 0.5 * (x - wj) ** 2, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12}
        )
        out[idx] = res.x
    return out
