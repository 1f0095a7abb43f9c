"""V2: exact prox of alpha||d||_1 + bounds on the mask + volume slab, against a QP solver and KKT."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from regularizers import PixelL1Bounds, RegularizerContext, VolumeSlabL1Bounds, soft_shrink

ALPHA, STEP, P1, P2, V_EPS = 0.5, 0.1, -0.05, 0.3, 0.1


def mask4() -> torch.Tensor:
    mask = torch.ones(4, 4, dtype=torch.bool)
    mask[0, 0] = mask[3, 1] = mask[1, 3] = mask[2, 2] = False
    return mask


def build(volume: float) -> VolumeSlabL1Bounds:
    reg = VolumeSlabL1Bounds(alpha=ALPHA, p1=P1, p2=P2, v_eps=V_EPS)
    reg.setup(RegularizerContext(mask=mask4(), volume=volume, pixel_area=1.0))
    return reg


def qp_prox(w: np.ndarray, mask: np.ndarray, q1: float, q2: float) -> np.ndarray:
    """Brute force: split x = u - v (u, v >= 0) on the mask; a smooth QP solved by SLSQP."""
    wm = w[mask]
    n, k = wm.size, STEP * ALPHA

    def objective(z: np.ndarray) -> float:
        x = z[:n] - z[n:]
        return k * z.sum() + 0.5 * np.sum((x - wm) ** 2)

    def gradient(z: np.ndarray) -> np.ndarray:
        r = z[:n] - z[n:] - wm
        return np.concatenate([k + r, k - r])

    ones = np.concatenate([np.ones(n), -np.ones(n)])
    diff = np.hstack([np.eye(n), -np.eye(n)])
    cons = [
        {"type": "ineq", "fun": lambda z: diff @ z - P1, "jac": lambda z: diff},
        {"type": "ineq", "fun": lambda z: P2 - diff @ z, "jac": lambda z: -diff},
        {"type": "ineq", "fun": lambda z: ones @ z - q1, "jac": lambda z: ones[None]},
        {"type": "ineq", "fun": lambda z: q2 - ones @ z, "jac": lambda z: -ones[None]},
    ]
    z0 = np.concatenate([np.clip(wm, 0, None), np.clip(-wm, 0, None)])
    res = minimize(objective, z0, jac=gradient, constraints=cons, bounds=[(0, None)] * (2 * n), method="SLSQP",
                   options={"ftol": 1e-15, "maxiter": 1000})
    assert res.success, res.message
    out = np.zeros_like(w)
    out[mask] = res.x[:n] - res.x[n:]
    return out


@pytest.mark.parametrize("case", ["above", "below", "inside"])
def test_prox_matches_qp_and_kkt(case: str, rng: np.random.Generator) -> None:
    mask = mask4()
    w = rng.uniform(-0.1, 0.45, size=(4, 4))
    pixel = PixelL1Bounds(ALPHA, P1, P2)
    pixel.setup(RegularizerContext(mask=mask))
    s0 = float(pixel.prox(torch.from_numpy(w), STEP).sum())  # unshifted eq. (7) sum
    volume = {"above": 0.6 * s0, "below": 1.6 * s0, "inside": s0}[case]
    reg = build(volume)
    q1, q2 = reg.band
    got = reg.prox(torch.from_numpy(w), STEP)
    lam = reg.shift(torch.from_numpy(w), STEP)
    total = float(got.sum())
    # KKT: closed form with the multiplier, sign of lambda matches the active constraint.
    expected = torch.where(mask, torch.clamp(soft_shrink(torch.from_numpy(w) - lam, STEP * ALPHA), P1, P2), 0.0)
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-15)
    if case == "above":
        assert lam > 0 and total == pytest.approx(q2, abs=1e-12)
    elif case == "below":
        assert lam < 0 and total == pytest.approx(q1, abs=1e-12)
    else:
        assert lam == 0.0 and torch.equal(got, pixel.prox(torch.from_numpy(w), STEP))
    assert reg.value(got) < float("inf")
    np.testing.assert_allclose(got.numpy(), qp_prox(w, mask.numpy(), q1, q2), atol=1e-6)


def test_prox_is_never_worse_than_feasible_competitors(rng: np.random.Generator) -> None:
    """Objective at the prox <= objective at random feasible points (via their own projection)."""
    w = torch.from_numpy(rng.uniform(-0.1, 0.45, size=(4, 4)))
    reg = build(0.8)
    p = reg.prox(w, STEP)

    def objective(x: torch.Tensor) -> float:
        return STEP * reg.value(x) + 0.5 * float(((x - w) ** 2).sum())

    best = objective(p)
    for _ in range(50):
        candidate = reg.prox(w + torch.from_numpy(rng.normal(scale=0.05, size=(4, 4))), STEP)
        assert objective(candidate) >= best - 1e-12


def test_target_at_the_limit_of_the_box_is_reached() -> None:
    """q1 = n p2 exactly: the prox must fill every printed sample to p2."""
    mask = mask4()
    n = int(mask.sum())
    reg = VolumeSlabL1Bounds(alpha=ALPHA, p1=P1, p2=P2, v_eps=0.0)
    reg.setup(RegularizerContext(mask=mask, volume=n * P2, pixel_area=1.0))
    out = reg.prox(torch.zeros(4, 4, dtype=torch.float64), STEP)
    torch.testing.assert_close(out[mask], torch.full((n,), P2, dtype=torch.float64), rtol=0, atol=1e-9)


def test_float32_128_grid_is_fast_and_in_band(rng: np.random.Generator) -> None:
    m = 128
    reg = VolumeSlabL1Bounds()
    reg.setup(RegularizerContext.full(m, volume=0.0669, pixel_area=(2 / m) ** 2))
    q1, q2 = reg.band
    d = torch.from_numpy(rng.uniform(0.0, 0.3, size=(m, m))).float()
    out = reg.prox(d, 0.1)
    assert out.dtype == torch.float32
    assert q1 * (1 - 1e-5) <= float(out.double().sum()) <= q2 * (1 + 1e-5)
