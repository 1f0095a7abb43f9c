"""Defect candidates read from the photo, not from the reconstruction (docs/method.md, "Defects
against the design").

A drop or a cut steep enough to focus its light before the screen is a lens the reconstruction
need not show: its basin lies elsewhere, and the deviation of the result from the design has
nothing there. The photo still holds it. Around the heights explained so far c (m, m), the
misfit Phi(c + k t_p) of a small cap t_p (unit volume, radius R samples) added at sample p with
amount k is, to first order, Phi(c) + k <t_p, g> + k^2 ||J t_p||^2, with g = grad Phi(c) (one
adjoint pass) and ||J t_p||^2 taken as sum_j t_p(j)^2 ||J e_j||^2 (the column norms the
uncertainty map already estimated; cross terms left out). Its least misfit lies at
k = -<t_p, g> / (2 ||J t_p||^2) and lowers Phi by <t_p, g>^2 / (4 ||J t_p||^2): a matched
filter of the gradient, evaluated at every place at once by two correlations per radius. Places
where that drop (in noise variances) reaches the asked level, local maxima within the clustering
distance, become candidates with the deviation e = k t_p: added glass where k > 0 (a drop),
missing glass where k < 0 (a cut). The fit then sizes and names them by the full, nonlinear
model (framework/defects/fit.py); the linear score only says where to look.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from framework.defects.regions import Candidate

__all__ = ["RADII", "cap", "photo_candidates"]

RADII = (1.0, 1.5, 2.5)  # caps tried, radius in samples


def cap(radius: float) -> np.ndarray:
    """A cap (1 - r^2 / R^2)^(3/2) of radius R = ``radius`` samples on its own (2k+1)^2 grid, unit sum."""
    k = int(np.ceil(radius))
    rows, cols = np.mgrid[-k:k + 1, -k:k + 1]
    inside = np.clip(1.0 - (rows ** 2 + cols ** 2) / radius ** 2, 0.0, None) ** 1.5
    return inside / inside.sum()


def photo_candidates(gradient: np.ndarray, column_norms: np.ndarray, open_samples: np.ndarray, noise: float,
                     needed: float, cell_mm: float, cluster_mm: float) -> list[Candidate]:
    """Candidates where the photo asks for a cap (module docstring), best first.

    Args:
        gradient: g = grad Phi at the heights explained so far (m, m), image units^2 per scene unit.
        column_norms: ||w J_j|| per sample (m, m), image units per scene unit of height.
        open_samples: bool (m, m), where a candidate may lie (the printable samples not closed yet).
        noise: Pixel noise standard deviation s. needed: the misfit drop (noise variances) a place
            must promise. cell_mm, cluster_mm: sample spacing, and the distance within which only
            the best place counts.
    """
    if gradient.shape != column_norms.shape or gradient.shape != open_samples.shape:
        raise ValueError(f"gradient {gradient.shape}, column norms {column_norms.shape} and samples "
                         f"{open_samples.shape} must share the height grid")
    squares = column_norms.astype(np.float64) ** 2
    best_gain = np.zeros(gradient.shape)
    best_amount = np.zeros(gradient.shape)
    best_radius = np.zeros(gradient.shape)
    for radius in RADII:
        template = cap(radius)
        inner = ndimage.correlate(gradient.astype(np.float64), template, mode="constant")
        curvature = ndimage.correlate(squares, template ** 2, mode="constant")
        gain = np.divide(inner ** 2, 4.0 * curvature, out=np.zeros_like(inner), where=curvature > 0) / noise ** 2
        better = gain > best_gain
        best_gain[better] = gain[better]
        best_amount[better] = -inner[better] / (2.0 * curvature[better])
        best_radius[better] = radius
    size = 2 * max(int(round(0.5 * cluster_mm / cell_mm)), 1) + 1
    peaks = (best_gain == ndimage.maximum_filter(best_gain, size=size)) & open_samples & (best_gain >= needed)
    candidates = []
    for row, col in sorted(zip(*np.nonzero(peaks)), key=lambda rc: -best_gain[rc]):
        radius = best_radius[row, col]
        template = cap(radius)
        k = template.shape[0] // 2
        rows, cols = np.mgrid[row - k:row + k + 1, col - k:col + k + 1]
        keep = (template > 0) & (rows >= 0) & (cols >= 0) & (rows < gradient.shape[0]) & (cols < gradient.shape[1])
        candidates.append(Candidate(rows[keep], cols[keep], best_amount[row, col] * template[keep]))
    return candidates
