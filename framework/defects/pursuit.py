"""Defects found one after another, each on top of those found before (docs/method.md, "Defects
against the design").

The heights that explain the photo so far start as the design c. Each round: the candidates of the
deviation that is still unexplained, e = d - (c with the defects found), restricted to a defect's
reach around each candidate's peak (framework/defects/regions.py); each screened by putting the
explained heights back at its samples in d (the photo must object: the misfit rises by at least half
the evidence asked for); the one whose reset raises the misfit most is fitted
(framework/defects/fit.py) on top of the explained heights. A fit with enough evidence joins them and
closes the samples it changed (and a margin) to later rounds: what is left there is that defect's
imperfect fit, not another defect (a fit whose centre lands there is not taken either); a fit
without it closes the candidate's samples. A print with several defects thus gets one
candidate per defect even where a faint deviation joins them into one region, and each defect's fit
sees the others already in place.

At the end every defect's evidence is what removing it alone from the final explanation costs (the
misfit rise in noise variances); defects that fall below the evidence asked for are dropped, and the
confidences are corrected for the number of fits tried (Bonferroni).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy import ndimage

from framework.defects.fit import FEATURE_MM, Defect, Fit, Misfit, chance_of, fit_candidate
from framework.defects.regions import Candidate, candidate_regions

__all__ = ["Search", "find_defects"]

REACH_MM = FEATURE_MM + 1.0  # a candidate keeps the samples this close to its peak
FOOTPRINT = 0.1  # a found defect's samples: changed by at least this fraction of its largest change
MARGIN_MM = 1.0  # and those this close to them


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


def _rebuilt(design: torch.Tensor, fits: list[Fit], cell_area: float) -> torch.Tensor:
    heights = design
    for fit in fits:
        heights = fit.added_to(heights, cell_area)
    return heights


def find_defects(d: torch.Tensor, at_d: float, design: torch.Tensor, mask: np.ndarray, z_map: np.ndarray,
                 misfit: Misfit, noise: float, search: Search) -> tuple[list[Defect], int]:
    """The defects that the photo needs, most evident first, and the number of fits tried.

    Args:
        d: The reconstruction (m, m), scene units. at_d: its misfit. design: c (m, m), scene units.
        mask: bool (m, m), the samples the fit could change. z_map: each sample's uncertainty (m, m),
            scene units, > 0 (the deviation's significance is |e| / z_map).
        misfit: ||F(h) - b||_W^2 of heights h (m, m). noise: pixel noise standard deviation s.
    """
    reach = REACH_MM / search.cell_mm
    explained, at_explained = design, misfit(design)
    closed = np.zeros_like(mask, dtype=bool)
    fits: list[Fit] = []
    tried = 0
    while tried < search.max_fits:
        deviation = (d - explained).double().cpu().numpy()
        regions = candidate_regions(deviation, z_map, mask & ~closed, search.cell_mm, search.z_min, search.grow,
                                    search.cluster_mm)
        candidate = _screened(d, explained, [region.near(reach) for region in regions], misfit, at_d, noise,
                              0.5 * search.min_evidence)
        if candidate is None:
            break
        tried += 1
        fit = fit_candidate(design, explained, candidate, misfit, at_explained, noise, search.cell_area,
                            search.cell_mm, search.mm_per_unit, search.evaluations)
        if fit.defect.evidence >= search.min_evidence and not _inside(fit.defect, closed, search.cell_mm):
            fits.append(fit)
            closed |= _footprint((fit.heights - explained).double().cpu().numpy(), search.cell_mm)
            explained, at_explained = fit.heights, fit.misfit
        else:
            closed[candidate.rows, candidate.cols] = True
    defects = []
    for i, fit in enumerate(fits):  # each defect's evidence: what leaving it alone out costs
        without = misfit(_rebuilt(design, fits[:i] + fits[i + 1:], search.cell_area))
        evidence = (without - at_explained) / noise ** 2
        if evidence >= search.min_evidence:
            defects.append(replace(fit.defect, evidence=float(evidence),
                                   confidence=1.0 - chance_of(evidence, len(fit.defect.params), tried)))
    return sorted(defects, key=lambda item: -item.evidence), tried
