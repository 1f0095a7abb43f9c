"""operators/linear/band_filter.py: the separable filter against numpy's direct convolution, on both of its
paths (conv2d and the banded product), tile edges, several channels and both precisions."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from operators.linear.band_filter import CONV_MAX_TAPS, TILE, correlate_axis, separable_correlate


def _direct(image: np.ndarray, taps: np.ndarray, axis: int) -> np.ndarray:
    """y_i = sum_t taps[t] x_(i + t - r), zero outside, by numpy's full convolution of each line."""
    r = (len(taps) - 1) // 2
    lines = np.moveaxis(image, axis, -1)
    out = np.stack([np.convolve(line, taps[::-1], mode="full")[r:r + line.shape[-1]]
                    for line in lines.reshape(-1, lines.shape[-1])])
    return np.moveaxis(out.reshape(lines.shape), -1, axis)


@pytest.mark.parametrize("channels, side, taps", [
    (1, 40, 7),                   # conv2d
    (1, 40, CONV_MAX_TAPS + 2),   # banded, kernel longer than the image's half
    (3, 2 * TILE + 5, 9),         # banded (several channels), a ragged last tile
    (1, 3 * TILE, 2 * TILE + 1),  # banded, kernel wider than a tile
    (2, 17, 41),                  # banded, kernel wider than the image
])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_each_axis_equals_numpys_direct_convolution(channels, side, taps, dtype) -> None:
    rng = np.random.default_rng(channels * 1000 + side + taps)
    image = rng.random((channels, side, side))
    kernel = rng.random(taps)  # asymmetric: the direction of the correlation is checked too
    tol = 1e-12 if dtype == torch.float64 else 2e-6
    for axis in (1, 2):
        got = correlate_axis(torch.from_numpy(image).to(dtype), torch.from_numpy(kernel), axis)
        assert got.dtype == dtype and got.shape == image.shape
        truth = _direct(image, kernel, axis)
        assert np.abs(got.double().numpy() - truth).max() <= tol * np.abs(truth).max()


def test_separable_filter_is_rows_then_columns_and_its_adjoint_is_the_flipped_kernels() -> None:
    rng = np.random.default_rng(7)
    x, y = rng.random((2, 3, 150, 150))
    rows, cols = rng.random(31), rng.random(5)
    got = separable_correlate(torch.from_numpy(x), torch.from_numpy(rows), torch.from_numpy(cols)).numpy()
    truth = _direct(_direct(x, rows, 1), cols, 2)
    assert np.abs(got - truth).max() <= 1e-12 * np.abs(truth).max()
    back = separable_correlate(torch.from_numpy(y), torch.from_numpy(rows[::-1].copy()),
                               torch.from_numpy(cols[::-1].copy())).numpy()
    assert float((got * y).sum()) == pytest.approx(float((x * back).sum()), rel=1e-13)


def test_an_even_kernel_is_refused() -> None:
    with pytest.raises(ValueError, match="odd number of taps, got 4"):
        correlate_axis(torch.zeros(1, 8, 8), torch.ones(4), 1)
