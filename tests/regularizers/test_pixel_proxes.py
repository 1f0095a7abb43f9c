"""Soft shrinkage, L1, bounds and the eq. (7) composite: hand values, brute force, Moreau identity."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from regularizers import HeightBounds, PixelL1, PixelL1Bounds, RegularizerContext, soft_shrink

from .conftest import brute_force_prox_1d


def masked_ctx(m: int = 4) -> RegularizerContext:
    mask = torch.ones(m, m, dtype=torch.bool)
    mask[0, :] = False  # first row unprinted
    mask[:, -1] = False  # last column unprinted
    return RegularizerContext(mask=mask)


def test_soft_shrink_hand_values(device: torch.device) -> None:
    w = torch.tensor([-3.0, -1.0, -0.25, 0.0, 0.25, 1.0, 3.0], dtype=torch.float64, device=device)
    expected = torch.tensor([-2.5, -0.5, 0.0, 0.0, 0.0, 0.5, 2.5], dtype=torch.float64, device=device)
    torch.testing.assert_close(soft_shrink(w, 0.5), expected, rtol=0, atol=0)


def test_pixel_l1_value_and_prox_hand_values() -> None:
    reg = PixelL1(alpha=0.5)
    d = torch.tensor([[1.0, -2.0], [0.1, 0.0]], dtype=torch.float64)
    assert reg.value(d) == pytest.approx(0.5 * 3.1)
    # step 0.4 -> threshold 0.2
    expected = torch.tensor([[0.8, -1.8], [0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(reg.prox(d, 0.4), expected)


def test_pixel_l1_prox_matches_brute_force(rng: np.random.Generator) -> None:
    alpha, step = 0.7, 0.3
    w = rng.uniform(-1.0, 1.0, size=(3, 3))
    got = PixelL1(alpha).prox(torch.from_numpy(w), step).numpy()
    want = brute_force_prox_1d(lambda x, _: step * alpha * abs(x), w, -3.0, 3.0)
    np.testing.assert_allclose(got, want, atol=1e-7)


def test_pixel_l1_moreau_identity(rng: np.random.Generator) -> None:
    """w = prox_{t f}(w) + t prox_{f*/t}(w/t), f* = indicator of the inf-ball of radius alpha."""
    alpha, step = 0.2, 0.5
    w = torch.from_numpy(rng.normal(size=(5, 5)))
    conj_part = step * torch.clamp(w / step, -alpha, alpha)
    torch.testing.assert_close(PixelL1(alpha).prox(w, step) + conj_part, w, rtol=0, atol=1e-15)


def test_bounds_prox_hand_values() -> None:
    reg = HeightBounds(p1=0.0, p2=0.3)
    reg.setup(RegularizerContext(mask=torch.tensor([[True, True], [True, False]])))
    d = torch.tensor([[-0.1, 0.2], [0.5, 0.7]], dtype=torch.float64)
    expected = torch.tensor([[0.0, 0.2], [0.3, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(reg.prox(d, 1.0), expected, rtol=0, atol=0)
    assert reg.value(expected) == 0.0
    assert reg.value(d) == math.inf


def test_bounds_prox_fenchel_young(rng: np.random.Generator) -> None:
    """Moreau: y = (w - P w)/t lies in the normal cone, i.e. <P w, y> = sigma_C(y) (support function)."""
    p1, p2, step = -0.1, 0.3, 0.7
    reg = HeightBounds(p1, p2)
    ctx = masked_ctx()
    reg.setup(ctx)
    w = torch.from_numpy(rng.uniform(-1, 1, size=(4, 4)))
    p = reg.prox(w, step)
    y = (w - p) / step
    support = torch.where(ctx.mask, torch.maximum(p1 * y, p2 * y), torch.zeros_like(y)).sum()
    assert float((p * y).sum()) == pytest.approx(float(support), abs=1e-14)


def test_l1_bounds_prox_hand_values() -> None:
    """Eq. (7) with alpha*step = 0.1: shrink, clamp to [0, 0.3] on the mask, zero off it."""
    reg = PixelL1Bounds(alpha=0.5, p1=0.0, p2=0.3)
    reg.setup(RegularizerContext(mask=torch.tensor([[True, True, True], [True, True, False]])))
    d = torch.tensor([[0.25, 0.05, 0.6], [-0.4, 0.15, 0.2]], dtype=torch.float64)
    expected = torch.tensor([[0.15, 0.0, 0.3], [0.0, 0.05, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(reg.prox(d, 0.2), expected)


@pytest.mark.parametrize("p1, p2", [(0.0, 0.3), (-0.2, 0.1), (0.1, 0.4), (-0.5, -0.2)])
def test_l1_bounds_prox_matches_brute_force(rng: np.random.Generator, p1: float, p2: float) -> None:
    """Clamp after shrink is the exact prox of alpha|.| + box, for any interval (0 inside or not)."""
    alpha, step = 0.8, 0.25
    reg = PixelL1Bounds(alpha, p1, p2)
    ctx = masked_ctx()
    reg.setup(ctx)
    w = rng.uniform(-0.8, 0.8, size=(4, 4))
    got = reg.prox(torch.from_numpy(w), step).numpy()
    want = brute_force_prox_1d(lambda x, _: step * alpha * abs(x), w, p1, p2)
    want[~ctx.mask.numpy()] = 0.0
    np.testing.assert_allclose(got, want, atol=1e-7)


def test_l1_bounds_prox_fenchel_young(rng: np.random.Generator) -> None:
    """f(p) + f*(y) = <p, y> for y = (w - p)/t, with f_j*(y) = max over {p1, p2, 0 in box} of x y - alpha|x|."""
    alpha, p1, p2, step = 0.4, -0.1, 0.3, 0.5
    reg = PixelL1Bounds(alpha, p1, p2)
    ctx = masked_ctx()
    reg.setup(ctx)
    w = torch.from_numpy(rng.uniform(-1, 1, size=(4, 4)))
    p = reg.prox(w, step)
    y = (w - p) / step
    cands = torch.stack([p1 * y - alpha * abs(p1), p2 * y - alpha * abs(p2), torch.zeros_like(y)])
    conj = torch.where(ctx.mask, cands.max(dim=0).values, torch.zeros_like(y)).sum()
    assert reg.value(p) + float(conj) == pytest.approx(float((p * y).sum()), abs=1e-13)
