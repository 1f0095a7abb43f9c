"""Where the tracks' global search looks (framework/tracks/track_search.py), in receiver pixels:
windows of a few knots along each track's path, and drop sites at the peaks of what the beads leave
unexplained. The receiver and the substrate share x and y (scene units): light from the glass
lands near below it, so a window's pixels are those beneath its part of the print.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Window", "DropSite", "windows_of", "pixels_beneath", "drop_sites", "misfit_peaks"]


@dataclass(frozen=True)
class Window:
    """Knots [first, last] of track ``track``, with the receiver pixels beneath them."""

    track: int
    first: int
    last: int
    pixels: np.ndarray  # flat indices into an (n, n) receiver image


@dataclass(frozen=True)
class DropSite:
    """Where glass off the beads may sit: the free drop slot it would take (its index in theta), its
    place (x, y, scene units) and the receiver pixels around it."""

    slot: int
    x: float
    y: float
    pixels: np.ndarray


def pixels_beneath(index: np.ndarray, m: int, half_width: float, receiver_half_width: float, pixels: int
                   ) -> np.ndarray:
    """The flat receiver pixel (of an (n, n) image over [-R, R]^2) beneath each height sample
    ``index`` (flat, of the (m, m) grid over [-W, W]^2)."""
    rows, cols = np.divmod(index, m)
    cell = 2.0 * half_width / (m - 1)
    pitch = 2.0 * receiver_half_width / pixels
    pc = np.clip(np.floor((cols * cell - half_width + receiver_half_width) / pitch).astype(int), 0, pixels - 1)
    pr = np.clip(np.floor((rows * cell - half_width + receiver_half_width) / pitch).astype(int), 0, pixels - 1)
    return pr * pixels + pc


def windows_of(paths_pixels: list[tuple[int, np.ndarray, np.ndarray]], knots_per_window: int) -> list[Window]:
    """Windows of ``knots_per_window`` knots along each track, overlapping by half; ``paths_pixels``:
    per track its knot count, each heights sample's knot position (p,) and flat receiver pixel (p,)."""
    windows = []
    stride = max(1, knots_per_window // 2)
    for track, (knots, position, pixels) in enumerate(paths_pixels):
        for first in range(0, max(knots - stride, 1), stride):
            last = min(first + knots_per_window, knots - 1)
            near = (position >= first - 0.5) & (position <= last + 0.5)
            windows.append(Window(track, first, last, np.unique(pixels[near])))
    return windows


def misfit_peaks(excess: np.ndarray, spacing: int, count: int) -> list[int]:
    """The flat indices of the ``count`` highest local maxima of the (n, n) map ``excess`` (a pixel's
    misfit in noise variances, smoothed), at least ``spacing`` pixels apart, above 1."""
    peaks = (excess == ndimage.maximum_filter(excess, size=2 * spacing + 1)) & (excess > 1.0)
    flat = np.flatnonzero(peaks)
    return [int(i) for i in flat[np.argsort(excess.reshape(-1)[flat])[::-1]][:count]]


def drop_sites(excess: np.ndarray, receiver_half_width: float, pixels: int, slots: list[int], reach: float
               ) -> list[DropSite]:
    """The highest peaks of the pixels' misfit (n * n,) in noise variances, smoothed over reach / 4,
    at least ``reach`` (scene units) apart, one per free drop slot (their indices in theta); each
    with the pixels within reach / 2."""
    pitch = 2.0 * receiver_half_width / pixels
    smooth = ndimage.gaussian_filter(excess.reshape(pixels, pixels), 0.25 * reach / pitch)
    centres = -receiver_half_width + (np.arange(pixels) + 0.5) * pitch
    sites = []
    for slot, peak in zip(slots, misfit_peaks(smooth, max(1, int(round(reach / pitch))), len(slots))):
        row, col = divmod(peak, pixels)
        x, y = float(centres[col]), float(centres[row])
        near = np.hypot(centres[None, :] - x, centres[:, None] - y) <= 0.5 * reach
        sites.append(DropSite(slot, x, y, np.flatnonzero(near)))
    return sites
