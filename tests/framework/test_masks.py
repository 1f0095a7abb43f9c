"""The official simulated-data mask: |d_true| >= 1e-3 dilated by 5% of the grid width."""

from __future__ import annotations

import doctest

import pytest
import torch

from framework.core.masks import mask_from_height_field


def test_single_spike_dilates_by_six_pixels_at_m128() -> None:
    d = torch.zeros(128, 128, dtype=torch.float64)
    d[64, 64] = 0.1
    mask = mask_from_height_field(d)
    assert mask.dtype == torch.bool and mask.shape == (128, 128)
    expected = torch.zeros(128, 128, dtype=torch.bool)
    expected[58:71, 58:71] = True  # 64 - 6 .. 64 + 6
    assert torch.equal(mask, expected)


def test_spike_at_corner_is_clipped_not_wrapped() -> None:
    d = torch.zeros(128, 128, dtype=torch.float64)
    d[0, 0] = -0.01  # |d| counts
    mask = mask_from_height_field(d)
    assert int(mask.sum()) == 49 and bool(mask[:7, :7].all())


def test_disk_footprint_counts_lattice_points_within_radius() -> None:
    d = torch.zeros(128, 128, dtype=torch.float64)
    d[64, 64] = 0.1
    mask = mask_from_height_field(d, footprint="disk")
    assert int(mask.sum()) == 113  # #{(i, j): i^2 + j^2 <= 36}
    assert bool(mask[64, 70]) and not bool(mask[70, 70])


def test_threshold_and_zero_dilation() -> None:
    d = torch.zeros(16, 16, dtype=torch.float64)
    d[3, 4] = 5e-4
    d[8, 9] = 2e-3
    mask = mask_from_height_field(d, dilation_fraction=0.0)
    assert mask.nonzero().tolist() == [[8, 9]]


def test_footprint_must_be_square_or_disk() -> None:
    with pytest.raises(ValueError, match="'diamond'"):
        mask_from_height_field(torch.zeros(8, 8), footprint="diamond")  # type: ignore[arg-type]


def test_docstring_example() -> None:
    import framework.core.masks

    result = doctest.testmod(framework.core.masks, extraglobs={"torch": torch})
    assert result.failed == 0 and result.attempted > 0
