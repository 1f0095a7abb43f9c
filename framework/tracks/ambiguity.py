"""What the photos leave undecided: two low ridges, or one thin tall bead between them.

A bead past its focus lights a band with bright edges; a fit whose rays do not cross (the free
grid, the transport start) explains the band by two low ridges under the edges
(framework/tracks/twins.py). Both may explain one photo within its noise. For every pair of
ridges side by side in a fit's heights, the other hypothesis is built (the pair's glass moved into
one bead on their midline, the width whose render fits best) and fitted by the run's own solver;
then, by the discrepancy principle:

- the bead reaches the photos' noise level and the run's heights do not: the photos decided for
  the bead, and it replaces the pair;
- the run's heights reach it and the bead's fit stalls above it: the photos decided for the pair;
- both reach it, or neither does (two fits short of the noise level say nothing of which basin is
  the print's): undecided. Both are rendered with the screen at each of
  ``screens_mm``; the nearest screen where their images differ by ``APART`` times the noise level
  (relative L2 over the receiver, as the discrepancy principle measures) is the second photo to take.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from framework.tracks.from_design import skeleton_tracks
from framework.tracks.geometry import path_length, resampled_path
from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.tracks.track_set import DEFAULT_SHAPE, Track, TrackSet
from framework.tracks.twins import Twins, twin_pairs

__all__ = ["Hypotheses", "AmbiguityReport", "bead_between", "undecided_beads", "APART", "BEAD_WIDTHS", "SCREENED"]

APART = 3.0  # images that differ by this many times the noise level: a photo tells them apart
BEAD_WIDTHS = (0.15, 0.25, 0.4)  # the bead between twins: its width, times their separation, tried
KNOT_MM = 1.0  # the bead's knots along its path
SCREENED = 6  # pairs whose bead is rendered at most, the longest first (a noisy fit's skeleton has many short ones)
PRESCREEN = 3.0  # a bead whose render (before its fit) misses by more than this times the fit's is not fitted


@dataclass
class Hypotheses:
    """One pair of ridges and the bead between them (mm), and what the photos say.

    Attributes:
        pair: The two ridges as tracks.
        bead: The bead between them.
        pair_discrepancy: The run's relative discrepancy; bead_discrepancy: the bead's, fitted.
        outcome: "undecided", "bead" (the photos decided for it), "pair", or "unchecked" (over the
            budget of fits).
        apart_mm: The nearest screen distance (mm) of ``screens_mm`` that tells the two apart, and
            ``apart_ratio`` their images' difference there over the noise level; None: none does.
        bead_heights: (m, m) the bead hypothesis fitted (scene units).
    """

    pair: tuple[Track, Track]
    bead: Track
    pair_discrepancy: float
    bead_discrepancy: float
    outcome: str = "undecided"
    apart_mm: float | None = None
    apart_ratio: float = 0.0
    bead_heights: np.ndarray | None = field(default=None, repr=False)


def _describe(track: Track) -> str:
    """Where a track runs and its size, mm."""
    start, end = track.path[0], track.path[-1]
    return (f"({start[0]:.1f}, {start[1]:.1f}) to ({end[0]:.1f}, {end[1]:.1f}) mm, {float(np.mean(track.height)):.2f} "
            f"mm high and {float(np.mean(track.width)):.2f} mm wide")


@dataclass
class AmbiguityReport:
    """Every pair of ridges checked, the heights to return (the run's, or where the photos decided for
    a bead, that bead's fit), the noise level, the discrepancy principle's goal, the pairs left
    unchecked beyond SCREENED, the check's seconds."""

    checked: list[Hypotheses]
    heights: Tensor
    delta: float
    goal: float
    unscreened: int = 0
    seconds: float = 0.0

    def lines(self) -> list[str]:
        """One sentence per pair fitted or left unchecked, one for the pairs rejected before a fit."""
        if not self.checked:
            return ["No ridges side by side in the heights: no bead's basin is in question."]
        out, k = [], 0
        rejected = [h for h in self.checked if h.outcome == "pair" and h.bead_heights is None]
        for h in self.checked:
            pair = f"two ridges, {_describe(h.pair[0])} and {_describe(h.pair[1])}"
            bead = f"one bead between them, {_describe(h.bead)}"
            ratios = (f"{h.pair_discrepancy / self.delta:.2f} and {h.bead_discrepancy / self.delta:.2f} x the "
                      "noise level")
            if h.outcome == "bead":
                out.append(f"The photos decided for {bead}, over {pair} ({ratios}).")
            elif h.outcome == "pair" and h.bead_heights is not None:
                out.append(f"The photos decided for {pair}, over {bead} ({ratios}).")
            elif h.outcome == "undecided":
                k += 1
                advice = (f"a photo with the screen {h.apart_mm:g} mm below the glass tells them apart (their "
                          f"images differ there by {h.apart_ratio:.1f} x the noise level); add it as a shot "
                          "(data=stack)" if h.apart_mm is not None else "no screen distance tried tells them apart")
                alike = ("explain the photos alike" if max(h.pair_discrepancy, h.bead_discrepancy) <= self.goal else
                         "the bead's fit ran out of iterations above the noise level (raise solver.max_iter)"
                         if h.pair_discrepancy <= self.goal else
                         "both fall short of the photos' noise level, so the photos cannot choose")
                out.append(f"Undecided ({k}): {pair}, or {bead}: {alike} ({ratios}); the run keeps the ridges, the "
                           f"bead is height_field_alternative_{k}.npy; {advice}.")
        unchecked = [h for h in self.checked if h.outcome == "unchecked"]
        if unchecked:
            places = "; ".join(f"({np.mean(h.bead.path[:, 0]):.1f}, {np.mean(h.bead.path[:, 1]):.1f}) mm"
                               for h in unchecked)
            out.append(f"Not fitted: {len(unchecked)} more pairs of ridges side by side, one bead between them "
                       f"centred at {places} (raise ambiguity.pairs to fit them).")
        if self.unscreened:
            out.append(f"{self.unscreened} shorter pairs of ridges side by side not checked (the {SCREENED} longest "
                       "were).")
        if rejected:
            misses = [h.bead_discrepancy / self.delta for h in rejected]
            out.append(f"{len(rejected)} more pairs of ridges side by side stay as they are: one bead between them "
                       f"misses the photos by {min(misses):.2f}-{max(misses):.2f} x the noise level before any fit "
                       f"(more than {PRESCREEN:g} x the run's).")
        return out

    def metrics(self) -> dict[str, Any]:
        """For metrics.json and MLflow: the sentences, the check's seconds and the pairs by outcome."""
        return {"ambiguity": " ".join(self.lines()), "ambiguity_time_s": self.seconds,
                "ridge_pairs_checked": len(self.checked),
                "ridge_pairs_undecided": sum(h.outcome == "undecided" for h in self.checked),
                "ridge_pairs_bead": sum(h.outcome == "bead" for h in self.checked)}


def _owned(shape: tuple[int, int], tracks: TrackSet, chosen: Sequence[int], reach_mm: float, half_width: float,
           mm_per_unit: float) -> np.ndarray:
    """(m, m) bool: the samples nearer to the paths of ``chosen`` than to any other track's, within
    ``reach_mm`` of them."""
    m = shape[0]
    axis = np.linspace(-half_width, half_width, m) * mm_per_unit
    x, y = np.meshgrid(axis, axis)
    points = [resampled_path(t.path, 0.25) for t in tracks.tracks]
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(points)])
    distance, nearest = cKDTree(np.vstack(points)).query(np.stack([x.ravel(), y.ravel()], axis=1))
    mine = np.isin(owner[nearest], list(chosen)) & (distance <= reach_mm)
    return mine.reshape(shape)


def bead_between(d: np.ndarray, tracks: TrackSet, twins: Twins, width_mm: float, half_width: float,
                 mm_per_unit: float) -> tuple[np.ndarray, Track]:
    """The heights (m, m, scene units) with the twins' glass (the samples nearer to them than to any
    other track, within their separation) moved into one bead of ``width_mm`` on their midline with
    the same volume, and that bead."""
    taken = np.where(_owned(d.shape, tracks, (twins.first, twins.second), twins.separation_mm, half_width,
                            mm_per_unit), np.maximum(d, 0.0), 0.0)
    knots = max(2, int(round(path_length(twins.midline) / KNOT_MM)) + 1)
    unit = Track("bead between", twins.midline, np.ones(knots), np.full(knots, width_mm), np.zeros(knots),
                 DEFAULT_SHAPE)
    representation = TrackHeights(TrackSet((unit,)), d.shape[0], half_width, mm_per_unit,
                                  TrackSettings(residual_mm=0.0))
    drawn = representation.heights(representation.initial()).numpy()  # 1 mm high
    height = float(taken.sum()) / max(float(drawn.sum()), 1e-300)  # mm: the bead holds the twins' glass
    return d - taken + height * drawn, replace(unit, height=np.full(knots, height))


def _apart(first: Tensor, second: Tensor, render_at: Callable[[float], Callable[[Tensor], Tensor]],
           screens_mm: Sequence[float], delta: float) -> tuple[float | None, float]:
    """The nearest screen (mm) where the two heights' images differ by APART x the noise level."""
    for screen in sorted(screens_mm):
        render = render_at(screen)
        a, b = render(first).double(), render(second).double()
        ratio = float(torch.linalg.vector_norm(a - b) / (delta * torch.linalg.vector_norm(a)))
        if ratio >= APART:
            return screen, ratio
    return None, 0.0


def undecided_beads(d: Tensor, discrepancy: Callable[[Tensor], float],
                    refit: Callable[[Tensor], tuple[Tensor, float, bool]],
                    render_at: Callable[[float], Callable[[Tensor], Tensor]], goal: float, delta: float,
                    half_width: float, mm_per_unit: float, screen_mm: float, screens_mm: Sequence[float],
                    pairs: int) -> AmbiguityReport:
    """Check the pairs of ridges side by side in the fit ``d`` (m, m): the SCREENED longest rendered
    with their bead, at most ``pairs`` beads fitted, the likeliest first (module docstring).

    Args:
        d: The run's heights, scene units.
        discrepancy: heights -> the relative discrepancy against the photos (one render).
        refit: heights -> (the run's solver's fit from them, its relative discrepancy, whether it ended
            by a stopping rule rather than the iteration cap).
        render_at: screen distance (mm) -> heights -> image (the configured setup, its screen moved).
        goal: The discrepancy principle's goal, tau * delta.
        delta: The photos' noise level.
        half_width: The heights grid's half width, scene units; mm_per_unit: mm per scene unit.
        screen_mm: The photos' farthest screen (mm); screens_mm: the distances one more photo may take
            (those beyond it).
        pairs: The beads fitted at most (each costs a fit; a bead the photo rejects before its fit costs
            three renders).
    """
    heights = d.detach().cpu().double().numpy()
    try:
        skeleton = skeleton_tracks(heights, half_width, mm_per_unit)
    except ValueError:  # no branch long enough: no beads
        return AmbiguityReport([], d, delta, goal)
    tracks, twins = skeleton, twin_pairs(skeleton)
    if not twins:
        return AmbiguityReport([], d, delta, goal)
    current, current_discrepancy = d, discrepancy(d)
    twins = sorted(twins, key=lambda t: -min(tracks.tracks[t.first].length, tracks.tracks[t.second].length))
    screened = []
    for pair in twins[:SCREENED]:  # each pair's bead at the width whose render fits best, before any fit
        tried = [bead_between(heights, tracks, pair, factor * pair.separation_mm, half_width, mm_per_unit)
                 for factor in BEAD_WIDTHS]
        misses = [discrepancy(torch.from_numpy(h).to(d)) for h, _ in tried]
        best = int(np.argmin(misses))
        screened.append((misses[best], pair, BEAD_WIDTHS[best] * pair.separation_mm, tried[best][1]))
    checked: list[Hypotheses] = []
    fits = 0
    for miss, pair, width, bead in sorted(screened, key=lambda found: found[0]):  # the likeliest first
        ridges = (tracks.tracks[pair.first], tracks.tracks[pair.second])
        if miss > PRESCREEN * current_discrepancy or fits == pairs:  # rejected before any fit, or over budget
            checked.append(Hypotheses(ridges, bead, current_discrepancy, miss,
                                      "pair" if miss > PRESCREEN * current_discrepancy else "unchecked"))
            continue
        fits += 1
        start, _ = bead_between(current.detach().cpu().double().numpy(), tracks, pair, width, half_width, mm_per_unit)
        fitted, fitted_discrepancy, finished = refit(torch.from_numpy(start).to(d))
        h = Hypotheses(ridges, bead, current_discrepancy, fitted_discrepancy,
                       bead_heights=fitted.detach().cpu().double().numpy())
        if fitted_discrepancy <= goal < current_discrepancy:
            h.outcome, current, current_discrepancy = "bead", fitted, fitted_discrepancy
        elif current_discrepancy <= goal < fitted_discrepancy and finished:
            h.outcome = "pair"
        else:
            h.apart_mm, h.apart_ratio = _apart(current, fitted, render_at,
                                               [s for s in screens_mm if s > screen_mm], delta)
        checked.append(h)
    return AmbiguityReport(checked, current, delta, goal, unscreened=len(twins) - len(screened))
