"""Separable filtering of image stacks with zero padding, steady for any kernel and image size.

``torch.nn.functional.conv2d`` with a (k, 1) or (1, k) kernel is quick for a short kernel over one
small image but drops to slow paths on the CPU for longer kernels, several channels or large
images: on one core of an AMD EPYC family 25 model 17 a 69-tap filter over a 256 x 256 float32
image took 29 ms, over a 1024 x 1024 float64 image 3.3 s (docs/performance.md, "Screen blur").
The filter is applied here as a banded matrix product instead: the axis is cut into tiles of
``TILE`` samples, each tile with the ``k - 1`` samples around it is one row of a strided view, and
one batched product with the TILE x (TILE + k - 1) band of taps filters all of them, n (TILE + k
- 1) multiply-adds per line in BLAS (13.5 ms and 0.15 s for the two examples). conv2d is kept
where it measured faster: kernels of at most ``CONV_MAX_TAPS`` taps on one channel of at most
``CONV_MAX_SIDE`` pixels a side. The two give the same sums up to rounding.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["correlate_axis", "separable_correlate", "TILE"]

TILE = 64  # samples of one tile of the banded product
CONV_MAX_TAPS = 15  # conv2d for kernels up to this many taps ...
CONV_MAX_SIDE = 512  # ... on one channel of at most this many pixels a side


def _band(taps: torch.Tensor) -> torch.Tensor:
    """The TILE x (TILE + k - 1) matrix B with B[i, i + t] = taps[t]: one tile's filter."""
    k = taps.numel()
    i = torch.arange(TILE).unsqueeze(1)
    t = torch.arange(TILE + k - 1).unsqueeze(0) - i
    inside = (t >= 0) & (t < k)
    return torch.where(inside, taps[t.clamp(0, k - 1)], torch.zeros((), dtype=taps.dtype))


def _banded_last_axis(x: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """y[..., i] = sum_t taps[t] x[..., i + t - r] along the last axis of ``x`` (..., n), zero
    outside, by the banded product; ``taps`` (k,) in ``x``'s dtype, k = 2 r + 1."""
    k = taps.numel()
    r = (k - 1) // 2
    n = x.shape[-1]
    tiles = -(-n // TILE)
    padded = F.pad(x.reshape(-1, n), (r, r + tiles * TILE - n))
    windows = padded.unfold(-1, TILE + k - 1, TILE)  # (lines, tiles, TILE + k - 1), a strided view
    out = torch.matmul(windows, _band(taps).T)  # (lines, tiles, TILE)
    return out.reshape(-1, tiles * TILE)[:, :n].reshape(x.shape)


def correlate_axis(image: torch.Tensor, taps: torch.Tensor, axis: int) -> torch.Tensor:
    """The image stack (c, n, n) filtered along ``axis`` (1: down the columns, 2: along the rows):
    y_i = sum_t taps[t] x_(i + t - r), zero outside; ``taps`` (k,), k = 2 r + 1 odd, centred."""
    k = taps.numel()
    if k % 2 != 1:
        raise ValueError(f"a centred kernel has an odd number of taps, got {k}")
    taps = taps.to(image)
    r = (k - 1) // 2
    if k <= CONV_MAX_TAPS and image.shape[0] == 1 and max(image.shape[1:]) <= CONV_MAX_SIDE:
        shape, padding = ((-1, 1), (r, 0)) if axis == 1 else ((1, -1), (0, r))
        return F.conv2d(image.unsqueeze(1), taps.view(1, 1, *shape), padding=padding).squeeze(1)
    if axis == 2:
        return _banded_last_axis(image, taps)
    return _banded_last_axis(image.transpose(1, 2), taps).transpose(1, 2)


def separable_correlate(image: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """The image stack (c, n, n) filtered with ``rows`` down its columns (axis 1) and ``cols`` along
    its rows (axis 2), both odd-length and centred, zero padding."""
    return correlate_axis(correlate_axis(image, rows, 1).contiguous(), cols, 2).contiguous()
