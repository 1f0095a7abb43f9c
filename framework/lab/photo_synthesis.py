"""Synthetic camera photos of a receiver image: the forward chain of the photo import
(framework/lab/photo_import.py), for tests and studies (docs/photo_import.md, "Synthetic photos").
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from framework.lab.photo_geometry import bilinear_samples, homography, project_points
from framework.lab.photo_import import FULL_SCALE

__all__ = ["camera_view", "synthesize_photo", "vignetting_field", "write_dng"]


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


# Adobe DNG 1.4 tags of a Bayer mosaic (the DNG specification, chapter 4), as tifffile's extratags.
_DNG_VERSION, _CFA_REPEAT, _CFA_PATTERN, _BLACK_REPEAT, _BLACK, _WHITE = 50706, 33421, 33422, 50713, 50714, 50717
_CFA_COLOUR = {"R": 0, "G": 1, "B": 2}


def write_dng(path: str | Path, rgb: np.ndarray, black: tuple[int, int, int] = (512, 512, 512), white: int = 16383,
              pattern: str = "RGGB", orientation: int = 1) -> Path:
    """A RAW photo as a DNG: (H, W, 3) linear values in [0, 1] (H, W even) sampled on a Bayer
    ``pattern`` mosaic, each photosite black + value (white - black) counts (uint16, rounded), with
    the black level of each colour, the white level and the TIFF ``orientation`` (1: as stored; 3:
    turned 180 degrees; 6: view turned a quarter clockwise; 8: counter-clockwise) in the file. For
    tests and synthetic benches of the RAW import (framework/lab/raw_photo.py)."""
    import tifffile

    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] % 2 or rgb.shape[1] % 2:
        raise ValueError(f"write_dng needs (H, W, 3) values with H and W even, got {rgb.shape}")
    if sorted(pattern) != ["B", "G", "G", "R"]:
        raise ValueError(f"pattern={pattern!r} must be a 2 x 2 Bayer pattern such as RGGB, BGGR, GRBG or GBRG")
    counts = np.empty(rgb.shape[:2], dtype=np.uint16)
    blacks = []
    for k, colour in enumerate(pattern):
        i, j = divmod(k, 2)
        c = _CFA_COLOUR[colour]
        blacks.append(int(black[c]))
        value = np.clip(rgb[i::2, j::2, c], 0.0, 1.0)
        counts[i::2, j::2] = np.round(black[c] + value * (white - black[c])).astype(np.uint16)
    tags = [(_DNG_VERSION, "B", 4, (1, 4, 0, 0), True), (_CFA_REPEAT, "H", 2, (2, 2), True),
            (_CFA_PATTERN, "B", 4, tuple(_CFA_COLOUR[c] for c in pattern), True),
            (_BLACK_REPEAT, "H", 2, (2, 2), True), (_BLACK, "H", 4, tuple(blacks), True),
            (_WHITE, "H", 1, (int(white),), True), (50708, "s", 0, "shape-from-caustics synthetic bench", True),
            (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),  # ColorMatrix1: identity
            (50778, "H", 1, (21,), True), (274, "H", 1, (int(orientation),), True)]  # D65; Orientation
    tifffile.imwrite(str(path), counts, photometric=32803, compression=None, subfiletype=0, metadata=None,
                     extratags=tags)
    return Path(path)


def camera_view(page: np.ndarray, mm_per_px: float, camera_matrix: np.ndarray, distortion: Sequence[float],
                rotation: Sequence[float], translation_mm: Sequence[float], size: tuple[int, int],
                outside: float = 0.0, supersample: int = 2) -> np.ndarray:
    """A photo (H, W) float64 of a flat ``page`` (P_rows, P_cols; row 0 = its top, +y), ``mm_per_px``
    a page pixel, lying at z = 0 with its centre at the origin, seen by a camera with
    ``camera_matrix`` and OpenCV's ``distortion`` (k1, k2, p1, p2, k3) whose pose maps the page's
    points X to R X + ``translation_mm``, R = ``rotation`` (Rodrigues vector) after the half turn
    about x that makes rotation 0 a view of the printed side, its top up. Each photo pixel is the mean of
    ``supersample``^2 bilinear samples of the page along the rays of its sub-points; ``outside``
    where a ray misses the page. ``size`` is (width, height)."""
    import cv2

    width, height = size
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    cols = (np.arange(width)[None, :, None, None] + offsets[None, None, None, :]).repeat(height, 0)
    rows = (np.arange(height)[:, None, None, None] + offsets[None, None, :, None]).repeat(width, 1)
    cols, rows = np.broadcast_arrays(cols, rows)
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), np.asarray(camera_matrix, np.float64),
                               np.asarray(distortion, np.float64)).reshape(-1, 2)
    turn, _ = cv2.Rodrigues(np.asarray(rotation, np.float64))
    turn = turn @ np.diag([1.0, -1.0, -1.0])  # rotation 0: the printed side faces the camera, its top up
    direction = np.c_[rays, np.ones(len(rays))] @ turn  # R^T d, row-wise
    origin = -turn.T @ np.asarray(translation_mm, np.float64)  # the camera centre on the page's axes
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -origin[2] / direction[:, 2]
    x, y = origin[0] + s * direction[:, 0], origin[1] + s * direction[:, 1]
    page_rows, page_cols = page.shape
    map_x = (x / mm_per_px + page_cols / 2 - 0.5).astype(np.float32)
    map_y = (page_rows / 2 - y / mm_per_px - 0.5).astype(np.float32)
    map_x[~(s > 0)] = -1e6
    seen = cv2.remap(page.astype(np.float64), map_x.reshape(height, -1), map_y.reshape(height, -1), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=outside)
    return seen.reshape(height, width, supersample, supersample).mean(axis=(2, 3))
