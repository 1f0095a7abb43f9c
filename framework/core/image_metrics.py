"""How well a caustic matches a target image: relative L2 after energy normalisation, and SSIM.

Both compare images of one receiver, (c, n, n) or (n, n), rows along +y. The caustic is first
scaled to the target's total (a refractive design only moves light, so its brightness is the
light's, not the target's); the relative L2 is then ||x - t|| / ||t||. SSIM is the structural
similarity of Wang et al. 2004 ("Image quality assessment: from error visibility to structural
similarity"): Gaussian window of standard deviation 1.5 pixels, K1 = 0.01, K2 = 0.03, dynamic
range L = the target's maximum, averaged over the pixels and the channels.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = ["energy_normalised", "relative_l2", "ssim"]

SSIM_SIGMA_PX = 1.5
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


def ssim(image: np.ndarray, target: np.ndarray) -> float:
    """Mean structural similarity (in [-1, 1], 1 for equal images) of the energy-normalised image
    and the target."""
    x, t = energy_normalised(image, target), _as_channels(target, "target")
    if x.shape != t.shape:
        raise ValueError(f"image {x.shape} and target {t.shape} differ in shape")
    values = []
    for a, b in zip(x, t):
        dynamic_range = float(b.max()) if b.max() > 0 else 1.0
        c1, c2 = (SSIM_K1 * dynamic_range) ** 2, (SSIM_K2 * dynamic_range) ** 2

        def blur(v: np.ndarray) -> np.ndarray:
            return gaussian_filter(v, SSIM_SIGMA_PX, truncate=3.5, mode="reflect")

        mu_a, mu_b = blur(a), blur(b)
        var_a, var_b = blur(a * a) - mu_a ** 2, blur(b * b) - mu_b ** 2
        cov = blur(a * b) - mu_a * mu_b
        index = (2 * mu_a * mu_b + c1) * (2 * cov + c2) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
        values.append(float(index.mean()))
    return float(np.mean(values))
