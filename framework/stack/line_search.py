"""A search across basins, per printed line, by the misfit of every photo (docs/method.md,
"Lines that focus before the screen").

A thin printed line focuses its light a millimetre or less below the top, so every screen sees
it past its focus, where a narrow tall line and a wide low ridge light the same band: a fit of
the near photo alone keeps the wide ridge (the basin it started in), and a stack fitted on from
there stays in it. The search takes the heights d (m, m) of such a fit, finds its elongated
features (:func:`line_features`) and tries, one feature after the other, other cross-sections of
the same volume: each line's heights collapsed, slice by slice along its axis, onto a Gaussian of
width s centred at an offset along its normal (:func:`collapsed`). Each hypothesis is rendered
into every shot and kept where it lowers the stack's misfit: every width and offset of a grid
together, then the best one's neighbours at half a cell and 15% of width.

Renders use the operator's cheap end (``photons`` per shot, the run's seed: every hypothesis sees
the same photons, so differences between them are not photon noise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy import ndimage

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.core.problem import Problem
from operators.values import checked_whole

__all__ = ["LineFeature", "line_features", "collapsed", "FeatureSearch", "SearchedLines"]

PRINTED_FRACTION = 0.1  # cells above this fraction of the highest belong to a feature
ORIENTATION_BINS = 4  # features are split where their normal turns by more than 180 / bins degrees
ELONGATION = 1.2  # a feature is a line when its axis's variance is at least this times its normal's
MIN_CELLS = 8  # smaller features are left alone
ONE_DIRECTION = 0.6  # a connected part with this share of its normals in one bin is one feature
MIN_SHARE = 0.1  # a part of one direction split off a joint feature keeps at least this share of its cells
WIDTH_FACTORS = (1.0, 0.7, 0.5, 0.35, 0.25)  # of the feature's present width
OFFSETS_CELLS = (-4, -3, -2, -1, 0, 1, 2, 3, 4)  # along the normal, in height cells
MIN_WIDTH_CELLS = 0.6  # no narrower cross-section than this many cells (standard deviation)
CENTRE_SMOOTHING = 2.0  # slices: the standard deviation of the smoothing of the slices' centres
REFINE_WIDTH = 1.15  # the refinement's width steps (factor) around the grid's best


@dataclass(frozen=True)
class LineFeature:
    """One elongated feature of a height field.

    Attributes:
        cells: (m, m) bool, the feature's own cells (above the printed fraction).
        region: (m, m) bool, the cells its hypotheses may change (its cells widened, never into
            another feature's).
        centre: (2,) x, y in cells (column, row), height-weighted.
        axis, normal: (2,) unit vectors (column, row) along and across the line.
        width: Height-weighted standard deviation of its cells across it, cells (a Gaussian
            cross-section cut at the printed fraction: 0.9 of its own).
    """

    cells: np.ndarray
    region: np.ndarray
    centre: np.ndarray
    axis: np.ndarray
    normal: np.ndarray
    width: float


def _normals(gx: np.ndarray, gy: np.ndarray, scale: float) -> np.ndarray:
    """Angle (m, m) in [0, pi) of each cell's normal from the gradients ``gx``, ``gy`` (m, m): the
    dominant eigenvector of their structure tensor, integrated over ``scale`` cells (across a
    ridge on both of its flanks)."""
    jxx, jyy, jxy = (ndimage.gaussian_filter(a, scale) for a in (gx * gx, gy * gy, gx * gy))
    return np.mod(0.5 * np.arctan2(2.0 * jxy, jxx - jyy), math.pi)


def _pieces(d: np.ndarray) -> list[np.ndarray]:
    """The printed cells of ``d`` (above :data:`PRINTED_FRACTION` of the highest) as pieces of
    one direction each: a connected part whose normals (weighted by the squared gradient) mostly
    (:data:`ONE_DIRECTION`) fall in one of :data:`ORIENTATION_BINS` bins stays whole; one that
    joins lines of several directions is split by bin into its parts of at least
    :data:`MIN_SHARE` of its cells (the joints between them are left out)."""
    printed = d > PRINTED_FRACTION * float(d.max())
    gy, gx = np.gradient(ndimage.gaussian_filter(d, 1.0))
    strength = gx * gx + gy * gy
    bins = np.floor(_normals(gx, gy, 3.0) / math.pi * ORIENTATION_BINS + 0.5) % ORIENTATION_BINS
    parts, count = ndimage.label(printed)
    pieces = []
    for label in range(1, count + 1):
        part = parts == label
        shares = np.bincount(bins[part].astype(np.int64), weights=strength[part], minlength=ORIENTATION_BINS)
        if shares.max() >= ONE_DIRECTION * max(shares.sum(), 1e-300):
            pieces.append(part)
            continue
        for k in range(ORIENTATION_BINS):
            split, n = ndimage.label(part & (bins == k))
            pieces += [split == j for j in range(1, n + 1) if (split == j).sum() >= MIN_SHARE * part.sum()]
    return pieces


def line_features(d: np.ndarray) -> list[LineFeature]:
    """The elongated features of heights ``d`` (m, m): the pieces of one direction
    (:func:`_pieces`) of at least :data:`MIN_CELLS` cells whose height-weighted spread along
    their principal axis is at least :data:`ELONGATION` times that across; the largest first."""
    if not float(d.max()) > 0.0:
        return []
    pieces = [p for p in _pieces(d) if p.sum() >= MIN_CELLS]
    labels = np.zeros(d.shape, dtype=np.int64)
    for label, piece in enumerate(pieces, start=1):
        labels[piece] = label
    # Every cell belongs to its nearest piece: a hypothesis may widen a line but not into another.
    _, (near_rows, near_cols) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    owner = labels[near_rows, near_cols]
    features = []
    for label, cells in enumerate(pieces, start=1):
        rows, cols = np.nonzero(cells)
        w = d[rows, cols]
        centre = np.array([np.average(cols, weights=w), np.average(rows, weights=w)])
        offsets = np.stack([cols - centre[0], rows - centre[1]], axis=1)
        values, vectors = np.linalg.eigh((offsets * w[:, None]).T @ offsets / w.sum())
        if values[1] < ELONGATION * max(values[0], 1e-12):
            continue
        width = math.sqrt(max(values[0], 1e-12))
        reach = ndimage.binary_dilation(cells, iterations=int(math.ceil(3.0 * width)) + max(OFFSETS_CELLS) + 2)
        features.append(LineFeature(cells, reach & (owner == label), centre, vectors[:, 1], vectors[:, 0], width))
    return sorted(features, key=lambda f: -int(f.cells.sum()))


def collapsed(d: np.ndarray, feature: LineFeature, width: float, offset: float) -> np.ndarray:
    """``d`` with the feature's region remade: the heights of each one-cell slice along its axis
    gathered onto a Gaussian cross-section of standard deviation ``width`` (cells) centred
    ``offset`` cells along the normal from the slice's own centre (the slices' height-weighted
    centres, smoothed over :data:`CENTRE_SMOOTHING` slices); every slice keeps its volume, the
    rest of ``d`` is unchanged."""
    rows, cols = np.nonzero(feature.region)
    dx, dy = cols - feature.centre[0], rows - feature.centre[1]
    along = dx * feature.axis[0] + dy * feature.axis[1]
    across = dx * feature.normal[0] + dy * feature.normal[1]
    slices = np.rint(along).astype(np.int64)
    slices -= slices.min()
    values = d[rows, cols]
    volume = np.bincount(slices, weights=values)
    centres = (ndimage.gaussian_filter1d(np.bincount(slices, weights=values * across), CENTRE_SMOOTHING)
               / np.maximum(ndimage.gaussian_filter1d(volume, CENTRE_SMOOTHING), 1e-300))
    profile = np.exp(-0.5 * ((across - centres[slices] - offset) / width) ** 2)
    norm = np.bincount(slices, weights=profile)
    out = d.copy()
    out[rows, cols] = volume[slices] * profile / np.maximum(norm[slices], 1e-300)
    return out


class FeatureSearch:
    """Module docstring: the per-line search of one problem (a stack or one shot).

    Args:
        problem: What the hypotheses are judged on (its operator renders every shot).
        photons: Photons per shot and render (the operator's own if it traces fewer).
        seed: Their pattern.
    """

    def __init__(self, problem: Problem, photons: int, seed: int) -> None:
        photons = checked_whole(photons, "feature search photons", 1)
        self.problem = problem
        self.operator = problem.operator.with_photons(min(photons, int(problem.operator.photons)), seed)
        self.renders = 0

    def misfit(self, d: np.ndarray) -> float:
        """The relative discrepancy of heights ``d`` (m, m) on every shot together."""
        self.renders += 1
        image = self.operator.render(torch.from_numpy(d).to(self.operator.dtype))
        return self.problem.fidelity.relative_discrepancy(image)

    @staticmethod
    def _grid(feature: LineFeature) -> list[tuple[float, float]]:
        """Every (width, offset) of :data:`WIDTH_FACTORS` x :data:`OFFSETS_CELLS`, in cells."""
        return [(max(feature.width * f, MIN_WIDTH_CELLS), float(o)) for f in WIDTH_FACTORS for o in OFFSETS_CELLS]

    @staticmethod
    def _refined(best: tuple[float, float]) -> list[tuple[float, float]]:
        """The neighbours of the grid's best (width, offset): half a cell either way, 15% either way."""
        width, offset = best
        return [(width, offset + step) for step in (-0.5, 0.5)] + [
            (max(width * f, MIN_WIDTH_CELLS), offset) for f in (1.0 / REFINE_WIDTH, REFINE_WIDTH)]

    def __call__(self, d: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
        """The heights after trying every line's hypotheses (module docstring), and what the search
        did: ``feature_search_{lines,changed,renders}`` and the misfit before and after."""
        best = d.copy()
        best_misfit = before = self.misfit(best)
        features = line_features(d)
        changed = 0
        for feature in features:
            base, chosen = best, None
            for trials in (self._grid(feature), None):
                if trials is None:
                    if chosen is None:
                        break
                    trials = self._refined(chosen)
                for trial in trials:
                    heights = collapsed(base, feature, *trial)
                    value = self.misfit(heights)
                    if value < best_misfit:
                        best, best_misfit, chosen = heights, value, trial
            changed += chosen is not None
        return best, {"feature_search_lines": float(len(features)), "feature_search_changed": float(changed),
                      "feature_search_renders": float(self.renders), "feature_search_misfit_before": before,
                      "feature_search_misfit_after": best_misfit}


@dataclass(frozen=True)
class SearchedLines(Start):
    """A stack's last start (``data.first_fit=lines``): ``start`` computed on the nearest shot
    (``request``), the nearest shot fitted alone from it, its lines searched by every shot's misfit
    (:class:`FeatureSearch`), then the stack (framework/stack/stack_stage.py)."""

    start: Any
    request: StartRequest

    @property
    def reads_design(self) -> bool:  # type: ignore[override]
        """Whether the wrapped start reads the print's design."""
        return bool(self.start.reads_design)

    def __call__(self, _: StartRequest) -> StartResult:
        """The start on the nearest shot, whatever shot the run's own request reads."""
        return self.start(self.request)
