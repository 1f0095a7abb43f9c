"""Defects found one after another, each on top of those found before (docs/method.md, "Defects
against the design").

The heights that explain the photo so far start as the design c. Each round: the candidates of the
deviation that is still unexplained, e = d - (c with the defects found), restricted to a defect's
reach around each candidate's peak (framework/defects/regions.py); each screened by putting the
explained heights back at its samples in d (the photo must object: the misfit rises by at least half
the evidence asked for); the one whose reset raises the misfit most is fitted
(framework/defects/fit.py) on top of the explained heights. A fit with enough evidence joins them and
closes the samples it changed (and a margin) to later rounds: what is left there is that defect's
imperfect fit, not another defect. A later fit whose centre lands there anyway is refitted in that
defect's place and takes it if it then explains the photo better (a first fit that found a shallow
lowering where the line is interrupted); otherwise it reworked the leftovers and is not taken. A fit
without enough evidence closes the candidate's samples. A print with several defects thus gets one
candidate per defect even where a faint deviation joins them into one region, and each defect's fit
sees the others already in place.

Two pieces of one kind on one feature, close along it (a long height error that the search found
as its two ends), are then tried as one defect spanning both: where the photo does not need the
second piece (the misfit of the one rises by less than the evidence asked for), they are one.

At the end every defect's evidence is what removing it alone from the final explanation costs (the
misfit rise in noise variances); defects that fall below the evidence asked for are dropped, and the
confidences are corrected for the number of fits tried (Bonferroni).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy import ndimage

from framework.defects.fit import FEATURE_MM, Defect, Fit, Misfit, chance_of, fit_candidate, refit
from framework.defects.matched_filter import photo_candidates
from framework.defects.models import Frame
from framework.defects.regions import Candidate, candidate_regions

__all__ = ["Search", "find_defects"]

REACH_MM = FEATURE_MM + 1.0  # a candidate keeps the samples this close to its peak
FOOTPRINT = 0.1  # a found defect's samples: changed by at least this fraction of its largest change
MARGIN_MM = 1.0  # and those this close to them
JOIN_GAP_MM = 3.0  # pieces of one kind on one feature at most this far apart along it ...
JOIN_ACROSS_MM = 1.0  # ... and this far across it are tried as one defect


@dataclass(frozen=True)
class Search:
    """What the search compares with: the significance levels of framework/defects/regions.py,
    the evidence asked for, the fits allowed, and the geometry (mm per sample, scene units^2 per
    sample, mm per scene unit)."""

    z_min: float
    grow: float
    cluster_mm: float
    min_evidence: float
    max_fits: int
    evaluations: int
    cell_mm: float
    cell_area: float
    mm_per_unit: float


def _screened(d: torch.Tensor, explained: torch.Tensor, candidates: list[Candidate],
              misfit: Misfit, at_d: float, noise: float, needed: float) -> Candidate | None:
    """The candidate whose reset to the explained heights raises the misfit of d most, if by ``needed``
    noise variances or more."""
    best, best_rise = None, needed
    for candidate in candidates:
        rows, cols = torch.from_numpy(candidate.rows), torch.from_numpy(candidate.cols)
        reset = d.clone()
        reset[rows, cols] = explained[rows, cols]
        rise = (misfit(reset) - at_d) / noise ** 2
        if rise >= best_rise:
            best, best_rise = candidate, rise
    return best


def _footprint(change: np.ndarray, cell_mm: float) -> np.ndarray:
    """The samples a found defect changed by at least :data:`FOOTPRINT` of its largest change, grown by
    :data:`MARGIN_MM`: what is left there is that defect's, not another's."""
    magnitude = np.abs(change)
    changed = magnitude >= FOOTPRINT * max(float(magnitude.max()), 1e-300)
    return ndimage.binary_dilation(changed, iterations=max(int(round(MARGIN_MM / cell_mm)), 1))


def _inside(defect: Defect, closed: np.ndarray, cell_mm: float) -> bool:
    """Whether a defect's centre lies on a found defect's samples (or on a closed candidate's): the
    fit then reworks that defect's leftovers."""
    m = closed.shape[0]
    half = 0.5 * (m - 1) * cell_mm
    row = int(np.clip(round((defect.y_mm + half) / cell_mm), 0, m - 1))
    col = int(np.clip(round((defect.x_mm + half) / cell_mm), 0, m - 1))
    return bool(closed[row, col])


def _in_place_of(fits: list[Fit], owner: int, fit: Fit, design: torch.Tensor, at_explained: float,
                 misfit: Misfit, noise: float, search: Search) -> Fit | None:
    """A fit that landed on the samples of ``fits[owner]``, refitted in its place (on top of the
    others), if it explains the photo better than all the fits so far; else None (it reworked the
    leftovers of that defect)."""
    base = _rebuilt(design, fits[:owner] + fits[owner + 1:], search.cell_area)
    swapped = refit(design, base, fit.frame, fit.defect.model, fit.defect.params, misfit, misfit(base), noise,
                    search.cell_area, search.cell_mm, search.mm_per_unit, search.evaluations)
    return swapped if swapped.misfit < at_explained else None


def _rebuilt(design: torch.Tensor, fits: list[Fit], cell_area: float) -> torch.Tensor:
    heights = design
    for fit in fits:
        heights = fit.added_to(heights, cell_area)
    return heights


def _span(fit: Fit, frame: Frame) -> tuple[float, float, float]:
    """(start, end) along ``frame``'s feature of a feature fit's window (samples) and its offset across
    from that frame's ridge."""
    own = fit.frame
    t0, length, _ = fit.defect.params
    row = own.row + t0 * own.along[0] + own.ridge * own.across[0] - frame.row
    col = own.col + t0 * own.along[1] + own.ridge * own.across[1] - frame.col
    t = row * frame.along[0] + col * frame.along[1]
    s = row * frame.across[0] + col * frame.across[1] - frame.ridge
    return t - length / 2.0, t + length / 2.0, s


def _joined_start(a: Fit, b: Fit, search: Search) -> np.ndarray | None:
    """The start (t0, L, amount) in ``a``'s frame of one defect spanning ``a`` and ``b``, if they are
    pieces of one kind on one feature (same model and sign, parallel, close along and across)."""
    if a.defect.model != b.defect.model or a.defect.model == "blob":
        return None
    if a.defect.params[2] * b.defect.params[2] <= 0.0:
        return None
    if abs(a.frame.along[0] * b.frame.along[0] + a.frame.along[1] * b.frame.along[1]) < 0.9:
        return None
    lo_a, hi_a, _ = _span(a, a.frame)
    lo_b, hi_b, across = _span(b, a.frame)
    gap = max(lo_b - hi_a, lo_a - hi_b)
    if gap * search.cell_mm > JOIN_GAP_MM or abs(across) * search.cell_mm > JOIN_ACROSS_MM:
        return None
    lo, hi = min(lo_a, lo_b), max(hi_a, hi_b)
    la, lb = a.defect.params[1], b.defect.params[1]
    amount = (a.defect.params[2] * la + b.defect.params[2] * lb) / (la + lb)
    return np.array([0.5 * (lo + hi), hi - lo, amount])


def _joined(fits: list[Fit], design: torch.Tensor, at_explained: float, misfit: Misfit, noise: float,
            search: Search) -> tuple[list[Fit], float]:
    """The fits with pieces of one defect joined where the photo does not need them apart, and the
    misfit of all of them."""
    joined = True
    while joined:
        joined = False
        for i, a in enumerate(fits):
            for j in range(i + 1, len(fits)):
                start = _joined_start(a, fits[j], search)
                if start is None:
                    continue
                others = [fit for k, fit in enumerate(fits) if k not in (i, j)]
                base = _rebuilt(design, others, search.cell_area)
                one = refit(design, base, a.frame, a.defect.model, start, misfit, misfit(base), noise,
                            search.cell_area, search.cell_mm, search.mm_per_unit, search.evaluations)
                if (one.misfit - at_explained) / noise ** 2 < search.min_evidence:
                    fits, at_explained, joined = others + [one], one.misfit, True
                    break
            if joined:
                break
    return fits, at_explained


def find_defects(d: torch.Tensor, at_d: float, design: torch.Tensor, mask: np.ndarray, z_map: np.ndarray,
                 misfit: Misfit, noise: float, search: Search, column_norms: np.ndarray | None = None
                 ) -> tuple[list[Defect], int]:
    """The defects that the photo needs, most evident first, and the number of fits tried. When no
    place where the reconstruction leaves the design is left, and ``column_norms`` are given, the
    photo's own candidates (framework/defects/matched_filter.py) are fitted next.

    Args:
        d: The reconstruction (m, m), scene units. at_d: its misfit. design: c (m, m), scene units.
        mask: bool (m, m), the samples the fit could change. z_map: each sample's uncertainty (m, m),
            scene units, > 0 (the deviation's significance is |e| / z_map).
        misfit: ||F(h) - b||_W^2 of heights h (m, m) (and its gradient, read with
            ``column_norms``). noise: pixel noise standard deviation s.
        column_norms: ||w J_j|| per sample (m, m) (framework/defects/information.py), or None: no
            candidates from the photo.
    """
    reach = REACH_MM / search.cell_mm
    explained, at_explained = design, misfit(design)
    rejected = np.zeros_like(mask, dtype=bool)  # candidates whose fit the photo did not need
    fits: list[Fit] = []
    footprints: list[np.ndarray] = []
    tried = 0
    while tried < search.max_fits:
        closed = np.logical_or.reduce([rejected, *footprints])
        deviation = (d - explained).double().cpu().numpy()
        regions = candidate_regions(deviation, z_map, mask & ~closed, search.cell_mm, search.z_min, search.grow,
                                    search.cluster_mm)
        candidate = _screened(d, explained, [region.near(reach) for region in regions], misfit, at_d, noise,
                              0.5 * search.min_evidence)
        if candidate is None and column_norms is not None:  # what the reconstruction does not show
            found = photo_candidates(misfit.gradient(explained).double().cpu().numpy(), column_norms, mask & ~closed,
                                     noise, 0.5 * search.min_evidence, search.cell_mm, search.cluster_mm)
            candidate = found[0] if found else None
        if candidate is None:
            break
        tried += 1
        fit = fit_candidate(design, explained, candidate, misfit, at_explained, noise, search.cell_area,
                            search.cell_mm, search.mm_per_unit, search.evaluations)
        owner = next((i for i, footprint in enumerate(footprints) if _inside(fit.defect, footprint, search.cell_mm)),
                     None)
        if owner is not None and fit.defect.evidence >= search.min_evidence:
            fit = _in_place_of(fits, owner, fit, design, at_explained, misfit, noise, search)
            if fit is not None:
                del fits[owner], footprints[owner]
        if fit is None or fit.defect.evidence < search.min_evidence or _inside(fit.defect, rejected, search.cell_mm):
            rejected[candidate.rows, candidate.cols] = True
            continue
        base = _rebuilt(design, fits, search.cell_area)
        fits.append(fit)
        footprints.append(_footprint((fit.heights - base).double().cpu().numpy(), search.cell_mm))
        explained, at_explained = fit.heights, fit.misfit
    fits, at_explained = _joined(fits, design, at_explained, misfit, noise, search)
    defects = []
    for i, fit in enumerate(fits):  # each defect's evidence: what leaving it alone out costs
        without = misfit(_rebuilt(design, fits[:i] + fits[i + 1:], search.cell_area))
        evidence = (without - at_explained) / noise ** 2
        if evidence >= search.min_evidence:
            defects.append(replace(fit.defect, evidence=float(evidence),
                                   confidence=1.0 - chance_of(evidence, len(fit.defect.params), tried)))
    return sorted(defects, key=lambda item: -item.evidence), tried
