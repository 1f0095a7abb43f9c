"""Prints with defects of known kind, place and size, made from a design, for the defect benchmark
(experiments/paper/reproduce_defects.py) and the tests.

Each defect is built here independently of the report's own defect models (framework/defects/models.py):
ends rounded by an error function of 0.3 mm (printed glass has no sharp steps), drops shaped as
(1 - r^2 / R^2)^(3/2) caps, the feature's direction from the design's Hessian, the change limited across
to the feature's own half-width (moves and width changes joining the glass beside it), so that a defect of
one feature leaves its neighbours as designed. Lengths in mm; the
design (m, m) in scene units on [-W, W]^2, row i at y = -W + i h, column j at x = -W + j h.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage
from scipy.special import erf

__all__ = ["PlannedDefect", "feature_sites", "apply_defect"]

EDGE_MM = 0.3  # the rounding of a defect's ends
BAND_MM = 8.0  # most half-width across the feature that a defect changes


@dataclass(frozen=True)
class PlannedDefect:
    """A defect put into a print: ``kind`` (interruption, too_low, too_high, excess, too_wide,
    too_narrow, displaced), centre (x_mm, y_mm), ``length_mm`` along the feature and ``size`` (the
    report's measure: the fraction of height missing, the relative width change, the shift in mm,
    or the drop's volume in mm^3)."""

    kind: str
    x_mm: float
    y_mm: float
    length_mm: float
    size: float

    def as_dict(self) -> dict[str, float | str]:
        return asdict(self)


def _frame(design: np.ndarray, row: int, col: int) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) unit vectors (row, col) of the feature at a sample: the Hessian's eigenvector
    of least curvature (along) of the design smoothed over two samples."""
    smooth = ndimage.gaussian_filter(design, 2.0)
    grr = ndimage.sobel(ndimage.sobel(smooth, 0), 0)[row, col]
    gcc = ndimage.sobel(ndimage.sobel(smooth, 1), 1)[row, col]
    grc = ndimage.sobel(ndimage.sobel(smooth, 0), 1)[row, col]
    values, vectors = np.linalg.eigh(np.array([[grr, grc], [grc, gcc]]))
    along = vectors[:, int(np.argmin(np.abs(values)))]
    return along, np.array([-along[1], along[0]])


def feature_sites(design: np.ndarray, cell_mm: float, count: int, spacing_mm: float, rng: np.random.Generator,
                  border_mm: float = 6.0) -> list[tuple[int, int]]:
    """Up to ``count`` samples on the design's ridges (at >= 95% of the local peak within 4 mm and
    >= 30% of the global one), ``spacing_mm`` apart, ``border_mm`` inside the grid, in random order."""
    local = ndimage.maximum_filter(design, size=2 * int(round(4.0 / cell_mm)) + 1)
    border = int(math.ceil(border_mm / cell_mm))
    ok = (design >= 0.95 * local) & (design >= 0.3 * design.max())
    ok[:border], ok[-border:], ok[:, :border], ok[:, -border:] = False, False, False, False
    rows, cols = np.nonzero(ok)
    order = rng.permutation(rows.size)
    sites: list[tuple[int, int]] = []
    for k in order:
        r, c = int(rows[k]), int(cols[k])
        if all(math.hypot(r - a, c - b) * cell_mm >= spacing_mm for a, b in sites):
            sites.append((r, c))
            if len(sites) == count:
                break
    return sites


def _box(t_mm: np.ndarray, length_mm: float) -> np.ndarray:
    scale = math.sqrt(2.0) * EDGE_MM
    return 0.5 * (erf((t_mm + length_mm / 2) / scale) - erf((t_mm - length_mm / 2) / scale))


def _half_width(design: np.ndarray, row: int, col: int, across: np.ndarray, cell_mm: float) -> float:
    """The feature's half-width at a site (mm): twice the nearer distance across it at which the
    design falls to half the site's height, plus 0.5 mm, at most BAND_MM (a defect of one feature
    leaves its neighbours alone, also where another feature joins it)."""
    m = design.shape[0]
    level = 0.5 * design[row, col]
    reach = int(math.ceil(BAND_MM / cell_mm))
    widths = []
    for sign in (1.0, -1.0):
        steps = np.arange(reach + 1)
        rr = np.clip(np.round(row + sign * steps * across[0]).astype(int), 0, m - 1)
        cc = np.clip(np.round(col + sign * steps * across[1]).astype(int), 0, m - 1)
        below = np.nonzero(design[rr, cc] < level)[0]
        widths.append((below[0] if below.size else reach) * cell_mm)
    return float(min(2.0 * min(widths) + 0.5, BAND_MM))


def _fade(s_mm: np.ndarray, plateau_mm: float, fade_mm: float) -> np.ndarray:
    """1 within ``plateau_mm`` across the feature, falling linearly to 0 over ``fade_mm`` beyond:
    a moved cross-section joins the unchanged glass beside it without tearing it."""
    return np.clip((plateau_mm + fade_mm - np.abs(s_mm)) / fade_mm, 0.0, 1.0)


def _source(s_mm: np.ndarray, plateau_mm: float, size: float, fade_mm: float = 2.0) -> np.ndarray:
    """Where a width change by the factor 1 + ``size`` takes each offset across the feature from (mm):
    s / (1 + size) over the feature; a narrowed feature leaves the glass at its old edge beside it,
    a widened one joins the glass beside it over ``fade_mm``; unchanged beyond."""
    a = np.abs(s_mm)
    if size < 0:
        source = np.where(a <= plateau_mm, np.minimum(a / (1.0 + size), plateau_mm), a)
    else:
        outer = plateau_mm * (1.0 + size)
        source = np.where(a <= outer, a / (1.0 + size),
                          a - size * plateau_mm * np.clip((outer + fade_mm - a) / fade_mm, 0.0, 1.0))
    return np.sign(s_mm) * source


def apply_defect(
    design: np.ndarray,
    printed: np.ndarray,
    site: tuple[int, int],
    kind: str,
    size: float,
    length_mm: float,
    cell_mm: float,
    mm_per_unit: float,
    offset_mm: float = 2.5,
) -> tuple[np.ndarray, PlannedDefect]:
    """``printed`` with one defect at ``site`` (row, col) of the design; returns the new print and
    the defect as planned (its centre where the change is)."""
    m = design.shape[0]
    row, col = site
    along, across = _frame(design, row, col)
    index = np.arange(m, dtype=float)
    rr, cc = np.meshgrid(index, index, indexing="ij")
    t = ((rr - row) * along[0] + (cc - col) * along[1]) * cell_mm
    s = ((rr - row) * across[0] + (cc - col) * across[1]) * cell_mm
    width = _half_width(design, row, col, across, cell_mm)
    window = _box(t, length_mm) * _box(s, 2.0 * width)
    half = 0.5 * (m - 1) * cell_mm
    centre = (col * cell_mm - half, row * cell_mm - half)
    if kind in ("interruption", "too_low", "too_high"):
        out = printed * (1.0 - size * window)
    elif kind == "displaced":
        shift = size / cell_mm * _box(t, length_mm) * _fade(s, width, 2.0 + abs(size))
        out = ndimage.map_coordinates(
            printed, [rr - shift * across[0], cc - shift * across[1]], order=1, mode="nearest"
        )
    elif kind in ("too_wide", "too_narrow"):
        back = (s - _source(s, width, size)) / cell_mm * _box(t, length_mm)
        out = ndimage.map_coordinates(printed, [rr - back * across[0], cc - back * across[1]], order=1, mode="nearest")
    elif kind == "excess":
        radius = 0.6 + 0.5 * size ** (1.0 / 3.0)  # mm: larger drops spread wider
        r0, c0 = row + offset_mm / cell_mm * across[0], col + offset_mm / cell_mm * across[1]
        rho2 = ((rr - r0) ** 2 + (cc - c0) ** 2) * cell_mm ** 2
        cap = np.clip(1.0 - rho2 / radius ** 2, 0.0, None) ** 1.5
        volume = cap.sum() * cell_mm ** 2  # mm^3 per mm of peak height
        out = printed + cap * (size / volume) / mm_per_unit
        centre = (c0 * cell_mm - half, r0 * cell_mm - half)
        length_mm = 2.0 * radius
    else:
        raise ValueError(f"defect kind {kind!r} is not one of interruption, too_low, too_high, excess, too_wide, "
                         "too_narrow, displaced")
    return np.clip(out, 0.0, None), PlannedDefect(kind, float(centre[0]), float(centre[1]), float(length_mm),
                                                  float(size))
