"""The screen's blur by its profile: the width at which the heights fitted under it explain the
photo best.

A Levenberg-Marquardt update of the blur's width at fixed heights (framework/lab/calibration.py)
hardly moves it: heights fitted under a wrong width have already absorbed the difference (a
blurred fold is also a weaker fold). The profile compares complete fits instead: for a width w the
misfit r(w) is the relative discrepancy that a reconstruction under w reaches with a fixed budget
(same start, same photons, no stopping at the noise level). Where the noise is low enough for the
photo to tell the blur apart from the heights, r(w) has a clear minimum at the true width
(docs/method.md, "The screen's blur from the photo"); where it is not, r is flat or falls towards
no blur, and the search says so.

:func:`search_width` brackets the minimum on a grid of widths a factor 2 apart (extended at its
edges within [lower, upper]) and refines it by parabolas in log w through the best width and its
neighbours, each vertex evaluated, until the vertex lies within ``tolerance`` of the best width and
either both neighbours lie within a factor BRACKET (1.25) of it or the previous parabola's vertex
agrees; a vertex on the best width with a wide bracket halves the bracket's wider side (in log w)
instead (on an even bracket the vertex's side), so that the parabola is fitted where the profile
is close to one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

__all__ = ["WidthProfile", "search_width", "MIN_RISE"]

# The profile must rise by at least this share of its minimum a factor 2 from the found width on
# both sides (by the fitted parabola) for the width to count as told by the data.
MIN_RISE = 0.05
# A bracket whose neighbours lie within this factor of the best width is narrow enough to end on.
BRACKET = 1.25


@dataclass
class WidthProfile:
    """The evaluated profile and the width found.

    Attributes:
        widths: Every evaluated width, receiver pixels, in evaluation order.
        misfits: The relative discrepancy reached under each width.
        width: The found width, pixels (the vertex of the parabola through the best three, or the
            best evaluated width at a bound).
        rise: The parabola's rise a factor 2 from the width, as a share of the minimum misfit
            (0 when the minimum lies at a bound).
        at_bound: "lower" / "upper" when the minimum lies at the search's bound, else "".
    """

    widths: list[float] = field(default_factory=list)
    misfits: list[float] = field(default_factory=list)
    width: float = float("nan")
    rise: float = 0.0
    at_bound: str = ""

    @property
    def identified(self) -> bool:
        """Whether the data tell the width: a minimum inside the bounds that rises by MIN_RISE."""
        return not self.at_bound and self.rise >= MIN_RISE

    def best(self) -> tuple[float, float]:
        """(width, misfit) of the best evaluated width."""
        i = min(range(len(self.misfits)), key=self.misfits.__getitem__)
        return self.widths[i], self.misfits[i]

    def sorted_points(self) -> list[tuple[float, float]]:
        """(width, misfit) pairs sorted by width, each width once."""
        return sorted(dict(zip(self.widths, self.misfits)).items())


def _vertex(points: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """(x*, c) of the parabola c (x - x*)^2 + m through three (x, y) points with distinct x."""
    (x0, y0), (x1, y1), (x2, y2) = points
    d01, d12 = (y1 - y0) / (x1 - x0), (y2 - y1) / (x2 - x1)
    c = (d12 - d01) / (x2 - x0)
    if c <= 0.0:  # no minimum: the best of the three
        return min(points, key=lambda p: p[1])[0], 0.0
    return min(max(0.5 * (x0 + x1) - d01 / (2.0 * c), x0), x2), c


def _three_around_best(profile: WidthProfile) -> list[tuple[float, float]]:
    """The best evaluated width and its neighbours on each side, as (log width, misfit)."""
    points = profile.sorted_points()
    i = min(range(len(points)), key=lambda k: points[k][1])
    i = min(max(i, 1), len(points) - 2)
    return [(math.log(w), r) for w, r in points[i - 1:i + 2]]


def search_width(misfit_of: Callable[[float], float], grid: Sequence[float] = (0.35, 0.7, 1.4, 2.8),
                 lower: float = 0.125, upper: float = 8.0, tolerance: float = 0.05,
                 max_evaluations: int = 10) -> WidthProfile:
    """The width (receiver pixels) that minimises ``misfit_of`` (one reconstruction per call).

    Args:
        misfit_of: Width in pixels -> the relative discrepancy a fit under that width reaches.
        grid: The first widths, pixels, increasing (at least three).
        lower, upper: The search's bounds, pixels.
        tolerance: Stop when a parabola's vertex moves the width by less than this share (and
            the bracket is narrow, BRACKET).
        max_evaluations: At most this many calls in all.
    """
    grid = sorted(float(w) for w in grid)
    if len(grid) < 3 or grid[0] <= 0.0 or not lower <= grid[0] or not grid[-1] <= upper:
        raise ValueError(f"width grid {grid} must hold >= 3 widths > 0 within [{lower}, {upper}] px")
    if not 0.0 < tolerance < 1.0:
        raise ValueError(f"tolerance={tolerance!r} must lie in (0, 1), e.g. 0.05 (5%)")
    profile = WidthProfile()

    def evaluate(width: float) -> None:
        profile.widths.append(width)
        profile.misfits.append(float(misfit_of(width)))

    for width in grid:
        evaluate(width)
    while len(profile.widths) < max_evaluations:  # extend the grid where the minimum sits at its edge
        points = profile.sorted_points()
        best = min(points, key=lambda p: p[1])[0]
        if best == points[0][0] and best / 2.0 >= lower:
            evaluate(best / 2.0)
        elif best == points[-1][0] and best * 2.0 <= upper:
            evaluate(best * 2.0)
        else:
            break
    points = profile.sorted_points()
    best = min(points, key=lambda p: p[1])[0]
    if best in (points[0][0], points[-1][0]):
        profile.width, profile.at_bound = best, "lower" if best == points[0][0] else "upper"
        return profile
    previous = math.inf
    while True:
        three = _three_around_best(profile)
        x_star, curvature = _vertex(three)
        profile.width = math.exp(x_star)
        profile.rise = curvature * math.log(2.0) ** 2 / profile.best()[1]
        (x0, _), (x1, _), (x2, _) = three
        close = math.log1p(tolerance)
        settled = abs(x_star - x1) < close
        narrow = max(x1 - x0, x2 - x1) <= math.log(BRACKET)
        if (settled and (narrow or abs(x_star - previous) < close)) or len(profile.widths) >= max_evaluations:
            return profile
        previous = x_star
        if settled:  # the vertex sits on the best width: halve the wider side of the bracket instead
            left, right = x1 - x0, x2 - x1  # (on a symmetric bracket the vertex's side)
            wider_left = left > 1.01 * right or (left >= 0.99 * right and x_star < x1)
            x_star = 0.5 * (x1 + (x0 if wider_left else x2))
        evaluate(math.exp(x_star))
