"""Candidate places of defects: where the reconstruction leaves its design by more than its
uncertainty (docs/method.md, "Defects against the design").

A region is a connected set of samples where |e| >= ``grow`` sigma (e = heights - design, sigma the
per-sample uncertainty) holding at least one sample with |e| >= ``z_min`` sigma (hysteresis: the peak
decides, the lower level gives the extent), of either sign. Regions closer than ``cluster_mm`` are one
candidate: a defect's deviation often comes with a compensating one beside it (a line moved leaves a
lobe of added and one of missing glass). Candidates are ordered by the |volume| of their deviation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Candidate", "candidate_regions"]


@dataclass(frozen=True)
class Candidate:
    """Samples (rows, cols) of one candidate and the deviation e there (scene units or mm, as given)."""

    rows: np.ndarray
    cols: np.ndarray
    e: np.ndarray

    @property
    def centre(self) -> tuple[float, float]:
        """The sample (row, col) of the largest |e| (a cluster's weighted centre may lie between its parts)."""
        k = int(np.argmax(np.abs(self.e)))
        return float(self.rows[k]), float(self.cols[k])

    def near(self, radius: float) -> Candidate:
        """The samples within ``radius`` (samples) of the centre: one defect's share of a region
        that a faint deviation joins to others."""
        row, col = self.centre
        inside = (self.rows - row) ** 2 + (self.cols - col) ** 2 <= radius ** 2
        return Candidate(self.rows[inside], self.cols[inside], self.e[inside])


def candidate_regions(deviation: np.ndarray, sigma: np.ndarray, tested: np.ndarray, cell_mm: float,
                      z_min: float, grow: float, cluster_mm: float, min_samples: int = 2) -> list[Candidate]:
    """The candidates, largest |deviation volume| first.

    Args:
        deviation: e (m, m). sigma: its uncertainty (m, m), same unit, > 0. tested: bool (m, m), the
            samples the fit could change. cell_mm: sample spacing. z_min, grow: the hysteresis levels
            (in sigma). cluster_mm: regions closer than this are one candidate. min_samples: smaller
            regions are dropped.
    """
    if deviation.shape != sigma.shape or deviation.shape != tested.shape:
        raise ValueError(f"deviation {deviation.shape}, sigma {sigma.shape} and mask {tested.shape} must share "
                         "the height grid")
    if not (np.isfinite(deviation).all() and np.isfinite(sigma).all() and (sigma > 0).all()):
        raise ValueError("deviation and sigma must be finite, sigma > 0")
    z = np.where(tested, np.abs(deviation) / sigma, 0.0)
    labels, count = ndimage.label(z >= grow)
    if count == 0:
        return []
    peaks = ndimage.maximum(z, labels, index=np.arange(1, count + 1))
    sizes = ndimage.sum(np.ones_like(z), labels, index=np.arange(1, count + 1))
    keep = np.zeros(count + 1, dtype=bool)
    keep[1:] = (peaks >= z_min) & (sizes >= min_samples)
    selected = keep[labels]
    radius = max(int(round(0.5 * cluster_mm / cell_mm)), 0)
    grown = ndimage.binary_dilation(selected, iterations=radius) if radius > 0 else selected
    clusters, found = ndimage.label(grown)
    candidates = []
    for label in range(1, found + 1):
        rows, cols = np.nonzero((clusters == label) & selected)
        if rows.size:
            candidates.append(Candidate(rows, cols, deviation[rows, cols]))
    return sorted(candidates, key=lambda c: -float(np.abs(c.e).sum()))
