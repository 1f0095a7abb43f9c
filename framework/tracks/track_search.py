"""The global search of each track's cross-section: along each path, windows of a few knots whose
part of the photo the fit explains worst try a set of alternative cross-sections with the rest of
the print held, and keep the best where it lowers the objective.

A bead past its focus lights a band; a bead moved by more than its width, interrupted, or traded
for a wide low ridge lights a band the gradient cannot reach from the nominal one (no overlap, no
slope). So each window tries, from its current values: offsets moved by +-0.5 and +-1 widths,
the height times 0.1 (an interruption), 0.6 and 1.4, the width times 0.7 and 1.4, and the width
times 0.6 and 1.6 with the height divided by the same factor (the same glass as a thin tall or a
wide low bead). The change
is full on the window's inner knots and half on its two end knots.

Windows are ranked by the misfit of the receiver pixels beneath them (the receiver and the
substrate share x, y; light from far above lands near below the glass), in noise variances; those
above ``min_excess`` times their expected noise are searched, worst first, at most ``max_windows``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["Window", "SearchSettings", "search_tracks"]


@dataclass(frozen=True)
class SearchSettings:
    """Knots per window, the windows searched at most and the misfit excess that calls for a search."""

    knots: int = 4
    max_windows: int = 16
    min_excess: float = 1.0


@dataclass(frozen=True)
class Window:
    """Knots [first, last] of track ``track``, with the receiver pixels beneath them."""

    track: int
    first: int
    last: int
    pixels: np.ndarray  # flat indices into an (n, n) receiver image


def _alternatives(theta: Tensor, slices: tuple[slice, slice, slice], window: Window, nominal_width: float,
                  clip: Callable[[Tensor], Tensor]) -> list[tuple[str, Tensor]]:
    """The window's alternative cross-sections (module docstring), each a full theta."""
    heights, widths, offsets = slices
    span = np.arange(window.first, window.last + 1)
    weight = torch.ones(span.size, dtype=theta.dtype)
    if span.size > 2:
        weight[0] = weight[-1] = 0.5

    def changed(label: str, **factors: float) -> tuple[str, Tensor]:
        out = theta.clone()
        h = heights.start + span
        w = widths.start + span
        o = offsets.start + span
        if "shift" in factors:
            out[o] = theta[o] + weight * factors["shift"]
        if "height" in factors:
            out[h] = theta[h] * (1.0 + weight * (factors["height"] - 1.0))
        if "width" in factors:
            out[w] = theta[w] * (1.0 + weight * (factors["width"] - 1.0))
        return label, clip(out)

    out = [changed(f"offset {s:+.1f} widths", shift=s * nominal_width) for s in (-1.0, -0.5, 0.5, 1.0)]
    out += [changed(f"height x{f}", height=f) for f in (0.1, 0.6, 1.4)]
    out += [changed(f"width x{f}", width=f) for f in (0.7, 1.4)]
    out += [changed(f"width x{f}, height / {f}", width=f, height=1.0 / f) for f in (0.6, 1.6)]
    return out


def search_tracks(theta: Tensor, windows: list[Window], slices: Callable[[int], tuple[slice, slice, slice]],
                  nominal_width: Callable[[int], float], clip: Callable[[Tensor], Tensor],
                  objective: Callable[[Tensor], float], residual: np.ndarray, noise_variance: float,
                  settings: SearchSettings) -> tuple[Tensor, list[str]]:
    """theta after the search (module docstring) and what it changed, in words.

    Args:
        theta: The current parameters.
        windows: The windows of every track.
        slices: Track index -> its (height, width, offset) slices of theta.
        nominal_width: Track index -> its nominal width (scene units).
        clip: Projection onto the bounds.
        objective: theta -> the objective (one render).
        residual: (n * n,) the squared residual per receiver pixel summed over channels.
        noise_variance: The expected squared noise per pixel (summed over channels).
        settings: :class:`SearchSettings`.
    """
    excess = [float(residual[w.pixels].sum()) / (noise_variance * max(len(w.pixels), 1)) for w in windows]
    order = [i for i in np.argsort(excess)[::-1] if excess[i] > settings.min_excess][:settings.max_windows]
    best = objective(theta)
    changes = []
    for i in order:
        window = windows[i]
        trials = _alternatives(theta, slices(window.track), window, nominal_width(window.track), clip)
        values = [(objective(candidate), label, candidate) for label, candidate in trials]
        value, label, candidate = min(values, key=lambda v: v[0])
        if value < best:
            theta, best = candidate, value
            changes.append(f"track {window.track + 1} knots {window.first}-{window.last}: {label}")
    return theta, changes


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
