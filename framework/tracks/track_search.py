"""The global search of each track's cross-section: along each path, windows of a few knots whose
part of the photo the fit explains worst try a set of alternative cross-sections with the rest of
the print held, and keep the best where it lowers the objective.

A bead past its focus lights a band; a bead moved by more than its width, interrupted, or traded
for a wide low ridge lights a band the gradient cannot reach from the nominal one (no overlap, no
slope). So each window tries, from its current values: offsets moved by +-0.5 and +-1 widths,
the height times 0.1 (an interruption), 0.6 and 1.4, the width times 0.7 and 1.4, and the width
times 0.6 and 1.6 with the height divided by the same factor (the same glass as a thin tall or a
wide low bead). The change is full on the window's inner knots and half on its two end knots.
And where the track has a closed gap left, that gap opened 1, 2 or 3 knot spacings long at the
window's middle or half a spacing either side (an interruption with its sharp ends).

Then glass off the beads: a drop is a lens of its own whose light a screen sees past its focus
too, so the residual grid's gradient never grows it (a bilinear bump has flat facets and focuses
nothing). At the highest peaks of what the beads leave unexplained (at most ``drop_sites``, one
per free drop slot of the representation), a round drop is tried at each pair of
``drop_heights`` and ``drop_radii``.

Windows are ranked by the misfit of the receiver pixels beneath them (the receiver and the
substrate share x, y; light from far above lands near below the glass), in noise variances; those
above ``min_excess`` times their expected noise are searched, worst first, at most ``max_windows``.
Windows whose pixels do not overlap are searched together in one round: one render tries an
alternative in every window of the round, each window judged by the misfit of its own pixels; the
round's winners are then kept together if the whole objective falls (one more render), else one
at a time where each lowers it. A search costs about 16 renders per round instead of 14 per window.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from framework.tracks.search_sites import DropSite, Window

__all__ = ["TrackMoves", "SearchSettings", "search_tracks"]


@dataclass(frozen=True)
class SearchSettings:
    """Knots per window, the windows searched at most, the misfit excess that calls for a search, the
    drop sites searched at most, the drops' peak heights tried (times the mean nominal bead height) and
    their radii (standard deviations, times the mean nominal bead width)."""

    knots: int = 4
    max_windows: int = 16
    min_excess: float = 1.0
    drop_sites: int = 4
    drop_heights: tuple[float, ...] = (0.2, 0.4, 0.8)
    drop_radii: tuple[float, ...] = (0.4, 0.8)


def _drop_alternatives(theta: Tensor, site: DropSite, heights: list[float], radii: list[float],
                       clip: Callable[[Tensor], Tensor]) -> list[tuple[str, Tensor]]:
    """A drop at the site in its slot: every pair of ``heights`` and ``radii`` (scene units)."""
    out = []
    for height in heights:
        for radius in radii:
            candidate = theta.clone()
            candidate[site.slot:site.slot + 4] = torch.tensor([site.x, site.y, radius, height], dtype=theta.dtype)
            out.append((f"a drop {height:.3g} high, {radius:.3g} in radius", clip(candidate)))
    return out


Site = Window | DropSite


@dataclass(frozen=True)
class TrackMoves:
    """What the search changes: each track's (height, width, offset) slices of theta and nominal
    width, the drops' heights and radii tried, each track's knot spacing (scene units) and the
    indices in theta of the gaps it may open (each a centre, then a length)."""

    slices: Callable[[int], tuple[slice, slice, slice]]
    widths: list[float]
    drop_heights: list[float]
    drop_radii: list[float]
    spacings: list[float]
    gaps: Callable[[int], list[int]]

    def alternatives(self, theta: Tensor, site: Site, clip: Callable[[Tensor], Tensor]) -> list[tuple[str, Tensor]]:
        if isinstance(site, DropSite):
            return _drop_alternatives(theta, site, self.drop_heights, self.drop_radii, clip)
        out = _alternatives(theta, self.slices(site.track), site, self.widths[site.track], clip)
        closed = [g for g in self.gaps(site.track) if float(theta[g + 1]) <= 0.0]
        return out + (_gap_alternatives(theta, closed[0], site, self.spacings[site.track], clip) if closed else [])

    @staticmethod
    def where(site: Site) -> str:
        if isinstance(site, DropSite):
            return f"at ({site.x:.3g}, {site.y:.3g})"
        return f"track {site.track + 1} knots {site.first}-{site.last}"


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


def _gap_alternatives(theta: Tensor, slot: int, window: Window, spacing: float, clip: Callable[[Tensor], Tensor]
                      ) -> list[tuple[str, Tensor]]:
    """The closed gap at ``slot`` opened 1, 2 or 3 knot spacings long at the window's middle or half a
    spacing either side of it."""
    middle = 0.5 * (window.first + window.last) * spacing
    out = []
    for shift in (-0.5, 0.0, 0.5):
        for knots in (1.0, 2.0, 3.0):
            gap = theta.clone()
            gap[slot], gap[slot + 1] = middle + shift * spacing, knots * spacing
            out.append((f"a gap {knots:g} knots long", clip(gap)))
    return out


def _rounds(sites: list[Site], pixels: int) -> list[list[Site]]:
    """The sites (worst first) in rounds whose receiver pixels do not overlap: a round's sites are
    searched together, one render per alternative."""
    rounds: list[tuple[list[Site], np.ndarray]] = []
    for site in sites:
        for members, taken in rounds:
            if not taken[site.pixels].any():
                members.append(site)
                taken[site.pixels] = True
                break
        else:
            taken = np.zeros(pixels, dtype=bool)
            taken[site.pixels] = True
            rounds.append(([site], taken))
    return [members for members, _ in rounds]


def _round(theta: Tensor, best: float, group: list[Site], tracks: TrackMoves, clip: Callable[[Tensor], Tensor],
           objective: Callable[[Tensor], float], pixel_misfit: Callable[[Tensor], np.ndarray],
           penalty: Callable[[Tensor], float], misfit: np.ndarray) -> tuple[Tensor, float, list[str]]:
    """One round of sites whose pixels do not overlap (module docstring): (theta, its objective, what
    changed)."""
    start = theta
    before = np.array([misfit[site.pixels].sum() for site in group])
    moves = [[(label, candidate - start) for label, candidate in tracks.alternatives(start, site, clip)]
             for site in group]
    local = np.full((len(group), max(len(m) for m in moves)), np.inf)
    for i, site_moves in enumerate(moves):
        local[i, :len(site_moves)] = [penalty(start + move) for _, move in site_moves]
    local -= penalty(start)
    for a in range(local.shape[1]):  # alternative a in every site of the round at once
        tried = pixel_misfit(start + sum(m[a][1] for m in moves if a < len(m)))
        local[:, a] += [tried[site.pixels].sum() for site in group]
    chosen = sorted(((before[i] - local[i].min(), i, int(np.argmin(local[i]))) for i in range(len(group))
                     if local[i].min() < before[i]), reverse=True)
    if not chosen:
        return theta, best, []
    together = start + sum(moves[i][a][1] for _, i, a in chosen)
    value = objective(together)
    if value < best:
        theta, best = together, value
    else:  # the sites' light met after all, or the penalties add up: one at a time
        accepted = []
        for gain, i, a in chosen:
            candidate = theta + moves[i][a][1]
            value = objective(candidate)
            if value < best:
                theta, best = candidate, value
                accepted.append((gain, i, a))
        chosen = accepted
    return theta, best, [f"{tracks.where(group[i])}: {moves[i][a][0]}" for _, i, a in chosen]


def search_tracks(theta: Tensor, windows: list[Window], drops: Callable[[np.ndarray], list[DropSite]],
                  tracks: TrackMoves,
                  clip: Callable[[Tensor], Tensor], objective: Callable[[Tensor], float],
                  pixel_misfit: Callable[[Tensor], np.ndarray], penalty: Callable[[Tensor], float],
                  noise_variance: float, settings: SearchSettings) -> tuple[Tensor, list[str]]:
    """theta after the search (module docstring) and what it changed, in words.

    Args:
        theta: The current parameters.
        windows: The windows of every track.
        drops: The pixels' misfit (as ``pixel_misfit``) -> the drop sites to try.
        tracks: Where each track's profiles sit in theta, its nominal width and the drops' heights.
        clip: Projection onto the bounds.
        objective: theta -> the objective (one render).
        pixel_misfit: theta -> (n * n,) each receiver pixel's share of the data term (one render).
        penalty: theta -> the objective's other terms (priors, volume; no caustic render).
        noise_variance: Each pixel's expected share of the data term at the noise level.
        settings: :class:`SearchSettings`.
    """
    misfit = pixel_misfit(theta)
    best = objective(theta)
    changes: list[str] = []

    def excess(site: Site) -> float:
        return float(misfit[site.pixels].sum()) / (noise_variance * max(len(site.pixels), 1))

    for phase in ("beads", "drops"):  # the beads first; glass off them for what they leave unexplained
        found = windows if phase == "beads" else drops(misfit)
        sites = sorted((s for s in found if excess(s) > settings.min_excess), key=excess, reverse=True)
        for group in _rounds(sites[:settings.max_windows] if phase == "beads" else sites, misfit.size):
            theta, best, kept = _round(theta, best, group, tracks, clip, objective, pixel_misfit, penalty, misfit)
            changes += kept
            if kept:
                misfit = pixel_misfit(theta)
    return theta, changes
