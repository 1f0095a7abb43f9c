"""volume_hold: the Euclidean projection onto bounds, mask and a volume band, against a QP solver."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from regularizers import RegularizerContext, VolumeHold

P1, P2, TOLERANCE = 0.0, 0.3, 0.02


def mask5() -> torch.Tensor:
    mask = torch.ones(5, 5, dtype=torch.bool)
    mask[0, :2] = mask[4, 3] = False
    return mask


def hold(volume: float) -> VolumeHold:
    step = VolumeHold(tolerance=TOLERANCE, p1=P1, p2=P2)
    step.setup(RegularizerContext(mask=mask5(), volume=volume, pixel_area=1.0))
    return step


def qp_projection(w: np.ndarray, mask: np.ndarray, q1: float, q2: float) -> np.ndarray:
    """argmin 1/2 ||x - w||^2 over the bounds and the band, x = 0 off the mask, by SLSQP."""
    wm = w[mask]
    ones = np.ones(wm.size)
    cons = [{"type": "ineq", "fun": lambda x: ones @ x - q1, "jac": lambda x: ones[None]},
            {"type": "ineq", "fun": lambda x: q2 - ones @ x, "jac": lambda x: -ones[None]}]
    res = minimize(lambda x: 0.5 * np.sum((x - wm) ** 2), np.clip(wm, P1, P2), jac=lambda x: x - wm,
                   bounds=[(P1, P2)] * wm.size, constraints=cons, method="SLSQP",
                   options={"ftol": 1e-15, "maxiter": 1000})
    assert res.success, res.message
    out = np.zeros_like(w)
    out[mask] = res.x
    return out


@pytest.mark.parametrize("volume", [1.0, 2.5, 4.0])
def test_projection_matches_qp_and_lands_in_the_band(volume: float, rng: np.random.Generator) -> None:
    """Too much glass: the projection onto bounds, mask and band. Too little (4.0 > the sum of
    about 3.3): the same on the samples above p1 only, the others clamped to the bounds."""
    w = rng.uniform(-0.1, 0.4, size=(5, 5))
    step = hold(volume)
    out = step(torch.from_numpy(w))
    q1, q2 = step.band
    assert (q1, q2) == pytest.approx((volume * (1 - TOLERANCE), volume * (1 + TOLERANCE)))
    raising = float(np.clip(w, P1, P2)[mask5().numpy()].sum()) < q1
    assert raising == (volume == 4.0)
    support = mask5().numpy() & (w > P1) if raising else mask5().numpy()
    expected = qp_projection(w, support, q1, q2)
    np.testing.assert_allclose(out.numpy(), expected, atol=1e-7)
    assert q1 - 1e-9 <= float(out.sum()) <= q2 + 1e-9
    assert float(out.min()) >= P1 and float(out.max()) <= P2
    assert float(out[~mask5()].abs().max()) == 0.0


def test_flat_glass_stays_flat_and_only_raised_glass_is_raised() -> None:
    flat = torch.zeros(5, 5, dtype=torch.float64)
    assert torch.equal(hold(2.0)(flat), flat)
    w = torch.zeros(5, 5, dtype=torch.float64)
    w[2, 1:4] = 0.1
    out = hold(0.6)(w)
    assert float(out.sum()) == pytest.approx(0.6 * (1 - TOLERANCE), rel=1e-12)
    assert torch.equal(out[w == 0], w[w == 0]) and torch.allclose(out[2, 1:4], torch.full((3,), 0.196, dtype=w.dtype))


def test_heights_inside_the_band_and_bounds_are_untouched(rng: np.random.Generator) -> None:
    w = torch.from_numpy(rng.uniform(0.0, 0.3, size=(5, 5))) * mask5()
    assert torch.equal(hold(float(w.sum()) * 1.01)(w), w)


def test_a_sum_above_the_band_ends_on_its_upper_edge() -> None:
    w = torch.full((5, 5), 0.2, dtype=torch.float64) * mask5()
    out = hold(2.0)(w)
    assert float(out.sum()) == pytest.approx(2.0 * (1 + TOLERANCE), rel=1e-12)
    printed = out[mask5()]
    assert float(printed.max() - printed.min()) < 1e-12  # one common shift of every printed sample


def test_an_unreachable_volume_is_refused() -> None:
    with pytest.raises(ValueError, match=r"volume_hold: the volume band .* unreachable .* check data.volume"):
        hold(22 * P2 * 1.5)
    with pytest.raises(ValueError, match=r"tolerance=1.5 must be a number in \[0, 1\)"):
        VolumeHold(tolerance=1.5)
