"""How well a caustic matches a target image: relative L2 after energy normalisation, and SSIM.

Both compare images of one receiver, (c, n, n) or (n, n), rows along +y. The caustic is first
scaled to the target's total (a refractive design only moves light, so its brightness is the
light's, not the target's); the relative L2 is then ||x - t|| / ||t||. SSIM is the structural
similarity of Wang et al. 2004 ("Image quality assessment: from error visibility to structural
similarity"): Gaussian window of standard deviation 1.5 pixels, K1 = 0.01, K2 = 0.03, dynamic
range L = the target's maximum, averaged over the pixels and the channels. :func:`ssim_tensor` is
the same measure on torch tensors, differentiable in the image (a design's data term can hold it:
framework/design/design_refinement.py); :func:`ssim` evaluates it on arrays.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = ["energy_normalised", "relative_l2", "ssim", "ssim_tensor"]

SSIM_SIGMA_PX = 1.5
SSIM_TRUNCATE = 3.5  # the window's half width in standard deviations (5 pixels)
SSIM_K1, SSIM_K2 = 0.01, 0.03


def _as_channels(image: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(image, dtype=np.float64)
    array = array[None] if array.ndim == 2 else array
    if array.ndim != 3 or not np.isfinite(array).all():
        raise ValueError(f"{name} must be a finite (n, n) or (c, n, n) image, got shape {np.shape(image)}")
    return array


def energy_normalised(image: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``image`` (c, n, n) scaled so that its total equals the target's (unchanged if it is dark)."""
    x, t = _as_channels(image, "image"), _as_channels(target, "target")
    total = float(x.sum())
    return x * (float(t.sum()) / total) if total > 0.0 else x


def relative_l2(image: np.ndarray, target: np.ndarray) -> float:
    """||x - t|| / ||t|| with x = ``image`` scaled to the target's total (dimensionless)."""
    x, t = energy_normalised(image, target), _as_channels(target, "target")
    if x.shape != t.shape:
        raise ValueError(f"image {x.shape} and target {t.shape} differ in shape")
    return float(np.linalg.norm(x - t) / np.linalg.norm(t))


def _blur(v: Tensor) -> Tensor:
    """``v`` (c, n, n) filtered by the normalised Gaussian window of :data:`SSIM_SIGMA_PX` along both
    axes, the image mirrored about its edges (a b c | c b a), as scipy.ndimage's ``reflect``."""
    radius = int(SSIM_TRUNCATE * SSIM_SIGMA_PX + 0.5)
    offsets = torch.arange(-radius, radius + 1, dtype=v.dtype, device=v.device)
    window = torch.exp(-0.5 * (offsets / SSIM_SIGMA_PX) ** 2)
    window = window / window.sum()
    for dim in (1, 2):
        n = v.shape[dim]
        index = torch.arange(-radius, n + radius, device=v.device) % (2 * n)
        index = torch.where(index >= n, 2 * n - 1 - index, index)
        padded = v.index_select(dim, index)
        v = sum((window[k] * padded.narrow(dim, k, n) for k in range(2 * radius + 1)), torch.zeros_like(v))
    return v


def ssim_tensor(image: Tensor, target: Tensor) -> Tensor:
    """Mean structural similarity (0-d tensor) of ``image`` (c, n, n), scaled to the target's total,
    and ``target`` (c, n, n); differentiable in ``image``."""
    if image.ndim != 3 or image.shape != target.shape:
        raise ValueError(f"image {tuple(image.shape)} and target {tuple(target.shape)} must be (c, n, n) alike")
    total = image.sum()
    x = image * (target.sum() / total) if float(total.detach()) > 0.0 else image
    t = target.to(x.dtype)
    peak = t.amax(dim=(1, 2), keepdim=True)
    dynamic_range = torch.where(peak > 0, peak, torch.ones_like(peak))
    c1, c2 = (SSIM_K1 * dynamic_range) ** 2, (SSIM_K2 * dynamic_range) ** 2
    mu_x, mu_t = _blur(x), _blur(t)
    var_x, var_t = _blur(x * x) - mu_x ** 2, _blur(t * t) - mu_t ** 2
    cov = _blur(x * t) - mu_x * mu_t
    index = (2 * mu_x * mu_t + c1) * (2 * cov + c2) / ((mu_x ** 2 + mu_t ** 2 + c1) * (var_x + var_t + c2))
    return index.mean(dim=(1, 2)).mean()


def ssim(image: np.ndarray, target: np.ndarray) -> float:
    """Mean structural similarity (in [-1, 1], 1 for equal images) of the energy-normalised image
    and the target (:func:`ssim_tensor` in float64)."""
    x, t = _as_channels(image, "image"), _as_channels(target, "target")
    if x.shape != t.shape:
        raise ValueError(f"image {x.shape} and target {t.shape} differ in shape")
    return float(ssim_tensor(torch.tensor(x), torch.tensor(t)))  # copies: the arrays may be read-only
