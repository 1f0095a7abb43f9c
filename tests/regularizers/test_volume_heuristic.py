"""V1, eq. (8): direction of the volume correction, the band, the mask, one exact pixel value."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from regularizers import RegularizerContext, VolumeHeuristic


def setup_v1(mask: torch.Tensor, volume: float, pixel_area: float = 1.0, **params) -> VolumeHeuristic:
    update = VolumeHeuristic(**params)
    update.setup(RegularizerContext(mask=mask, volume=volume, pixel_area=pixel_area))
    return update


def random_field(rng: np.random.Generator, mask: torch.Tensor) -> torch.Tensor:
    d = torch.from_numpy(rng.uniform(0.0, 0.3, size=tuple(mask.shape)))
    return torch.where(mask, d, torch.zeros_like(d))


@pytest.fixture
def mask() -> torch.Tensor:
    m = torch.zeros(16, 16, dtype=torch.bool)
    m[3:13, 4:12] = True
    return m


def test_band_uses_volume_pixel_area_and_eps(mask: torch.Tensor) -> None:
    update = setup_v1(mask, volume=0.5, pixel_area=0.25, v_eps=0.2)
    assert update.band == pytest.approx((1.6, 2.4))


def test_grows_volume_below_band(mask: torch.Tensor, rng: np.random.Generator) -> None:
    d = random_field(rng, mask)
    v = float(d.sum())
    update = setup_v1(mask, volume=v / 0.5)  # q1 = 0.75 * 2 v > v
    out = update(d)
    assert float(out.sum()) > v
    torch.testing.assert_close(out[~mask], d[~mask], rtol=0, atol=0)


def test_shrinks_volume_above_band(mask: torch.Tensor, rng: np.random.Generator) -> None:
    d = random_field(rng, mask)
    v = float(d.sum())
    update = setup_v1(mask, volume=v / 1.5)  # q2 = 1.25 v / 1.5 < v < 2 q2
    out = update(d)
    assert float(out.sum()) < v
    torch.testing.assert_close(out[~mask], d[~mask], rtol=0, atol=0)


def test_leaves_d_unchanged_inside_band(mask: torch.Tensor, rng: np.random.Generator) -> None:
    d = random_field(rng, mask)
    out = setup_v1(mask, volume=float(d.sum()))(d)
    assert torch.equal(out, d) and out is not d


def test_never_changes_off_mask_entries(mask: torch.Tensor, rng: np.random.Generator) -> None:
    d = torch.from_numpy(rng.uniform(0.0, 0.3, size=(16, 16)))  # nonzero off the mask as well
    for volume in (float(d.sum()) * 3.0, float(d.sum()) * 0.6):
        out = setup_v1(mask, volume=volume)(d)
        assert not torch.equal(out[mask], d[mask])
        assert torch.equal(out[~mask], d[~mask])


def test_exact_pixel_values_on_tiny_grid() -> None:
    """5x5 of 0.1 (v = 2.5), r_V = 1, gamma = 0.1, V_eps = 0, a = 1.

    Below (V = 5, q1 = 5): factor gamma sin(pi/2) = 0.1; corner window holds 4 samples -> dbar 0.4/9.
    Above (V = 2, q2 = 2): factor -gamma sin(pi (1.25 - 1)) = -0.1 sqrt(2)/2; centre dbar = 0.1.
    """
    mask = torch.ones(5, 5, dtype=torch.bool)
    mask[4, 4] = False
    d = torch.full((5, 5), 0.1, dtype=torch.float64)
    out = setup_v1(mask, volume=5.0, r_v=1, v_eps=0.0)(d)
    assert float(out[0, 0]) == pytest.approx(0.1 + 0.1 * 0.4 / 9, abs=1e-15)
    assert float(out[2, 2]) == pytest.approx(0.1 + 0.1 * 0.1, abs=1e-15)
    assert float(out[0, 2]) == pytest.approx(0.1 + 0.1 * 0.6 / 9, abs=1e-15)
    assert float(out[4, 4]) == 0.1
    out = setup_v1(mask, volume=2.0, r_v=1, v_eps=0.0)(d)
    assert float(out[2, 2]) == pytest.approx(0.1 - 0.1 * 0.1 * math.sqrt(2) / 2, abs=1e-15)


def test_dtype_and_device_preserved(device: torch.device) -> None:
    mask = torch.ones(8, 8, dtype=torch.bool)
    d = torch.full((8, 8), 0.1, dtype=torch.float32, device=device)
    out = setup_v1(mask, volume=20.0)(d)
    assert out.dtype == torch.float32 and out.device == d.device
