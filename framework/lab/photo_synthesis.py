"""Synthetic camera photos of a receiver image: the forward chain of the photo import
(framework/lab/photo_import.py), for tests and studies (docs/photo_import.md, "Synthetic photos").
"""

from __future__ import annotations

import numpy as np

from framework.lab.photo_geometry import bilinear_samples, homography, project_points
from framework.lab.photo_import import FULL_SCALE

__all__ = ["vignetting_field", "synthesize_photo"]


def vignetting_field(photo_shape: tuple[int, ...], vignetting: float) -> np.ndarray:
    """(H, W) factor 1 - vignetting * r^2, r = distance from the photo centre / half-diagonal."""
    height, width = photo_shape[0], photo_shape[1]
    row, col = np.mgrid[0:height, 0:width].astype(np.float64)
    r = np.hypot(col - 0.5 * (width - 1), row - 0.5 * (height - 1)) / (0.5 * np.hypot(width, height))
    return 1.0 - vignetting * r ** 2


def synthesize_photo(image: np.ndarray, corners: object, photo_shape: tuple[int, int], half_width: float, *,
                     gain: float = 1.0, vignetting: float = 0.0, gamma: float = 1.0, black_level_dn: float = 0.0,
                     bit_depth: int = 16, noise: float = 0.0, saturate_above: float = 1.0, seed: int = 0,
                     extend_edges: bool = False) -> np.ndarray:
    """Synthetic uint8/uint16 photo (H, W), row 0 = top, of a receiver image (1, n, n) or (n, n)
    (rows y-up) seen with the receiver's corners at ``corners`` (as for :func:`homography`).

    Each photo pixel is the mean of 2 x 2 bilinear samples of the image at its sub-points mapped
    back to the receiver (0 outside [-W, W]^2 unless ``extend_edges``: a screen larger than the
    receiver, as in a flat field), times ``gain`` (full scale per image unit) and
    :func:`vignetting_field`; then v ** (1 / gamma), Gaussian noise of sigma ``noise`` (fraction
    of full scale, seeded), + black level (DN); raw values >= ``saturate_above`` (fraction of full
    scale) read full scale; clipped to [0, full scale] and rounded.
    """
    image = np.asarray(image, dtype=np.float64)
    image = image[0] if image.ndim == 3 and image.shape[0] == 1 else image
    if image.ndim != 2 or image.shape[0] != image.shape[1]:
        raise ValueError(f"image has shape {image.shape}; expected (1, n, n) or (n, n)")
    if bit_depth not in FULL_SCALE:
        raise ValueError(f"bit_depth={bit_depth!r} must be 8 or 16")
    if not (gain > 0 and 0 <= vignetting < 1 and gamma > 0 and noise >= 0 and saturate_above > 0):
        raise ValueError(f"gain={gain}, gamma={gamma}, saturate_above={saturate_above} must be positive, "
                         f"vignetting={vignetting} in [0, 1) and noise={noise} >= 0")
    full = FULL_SCALE[bit_depth]
    height, width = photo_shape[0], photo_shape[1]
    n = image.shape[0]
    inverse = np.linalg.inv(homography(corners, half_width))
    sub_rows = (np.arange(2 * height) + 0.5) / 2.0 - 0.5
    sub_cols = (np.arange(2 * width) + 0.5) / 2.0 - 0.5
    col, row = np.meshgrid(sub_cols, sub_rows)
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = project_points(inverse, col, row)
    inside = (np.abs(x) <= half_width) & (np.abs(y) <= half_width)
    keep = inside | (extend_edges & np.isfinite(x) & np.isfinite(y))
    x, y = np.where(keep, x, 0.0), np.where(keep, y, 0.0)
    scale = n / (2.0 * half_width)
    samples = bilinear_samples(image[..., None], (x + half_width) * scale - 0.5, (y + half_width) * scale - 0.5)[..., 0]
    value = np.where(keep, samples, 0.0).reshape(height, 2, width, 2).mean(axis=(1, 3))
    value = np.maximum(value * gain * vignetting_field((height, width), vignetting), 0.0) ** (1.0 / gamma)
    if noise > 0:
        value = value + noise * np.random.default_rng(seed).standard_normal(value.shape)
    value = value + black_level_dn / full
    value = np.where(value >= saturate_above, 1.0, value)
    return np.round(np.clip(value, 0.0, 1.0) * full).astype(np.uint8 if bit_depth == 8 else np.uint16)
