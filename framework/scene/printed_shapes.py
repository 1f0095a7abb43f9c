"""Built-in printed-glass height fields d(x, y) >= 0, in scene units (docs/method.md,
"Built-in height fields").

Every shape is sampled on an m x m grid with samples at linspace(-1, 1, m) on both axes and
returned as a float64 array indexed [row, col] = [y, x] (y grows with the row index, so plots
use origin='lower').

The "print lines" ground truth uses the scaled coordinates X = 6x, Y = 6y and

    g(s, mu, t)              = exp(-(t - mu)^2 / (2 s^2)) / (s sqrt(2 pi))
    G2(s1, s2, m1, m2, X, Y) = exp(-((X - m1)^2 / s1^2 + (Y - m2)^2 / s2^2) / 2) / (2 pi s1 s2)

Example:
    >>> d = make_shape("print_lines", 64)
    >>> d.shape, d.dtype, bool(d.min() >= 0.0)
    ((64, 64), dtype('float64'), True)
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence

import numpy as np

from operators.values import checked_number, checked_whole

__all__ = ["SHAPES", "make_shape", "grid", "g", "G2", "line_v", "line_h", "print_lines_on",
           "flat", "gaussian", "print_lines", "oblique_lines", "bump", "letter_a", "segment_distance"]

COORDINATE_SCALE = 6.0  # X = 6x, Y = 6y (docs/method.md, "Built-in height fields")
OBLIQUE_ANGLE_DEG = 15.0
HEIGHT_SCALE = 0.1  # d = 0.1 * (l1 + ... + l6)


def grid(resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample coordinates (x, y), each (m, m): x varies along columns, y along rows, both in [-1, 1]."""
    t = np.linspace(-1.0, 1.0, resolution)
    y, x = np.meshgrid(t, t, indexing="ij")
    return x, y


def g(s: float, mu: float, t: np.ndarray) -> np.ndarray:
    """1-D normal density g(s, mu, t) = exp(-(t - mu)^2 / (2 s^2)) / (s sqrt(2 pi))."""
    return np.exp(-((t - mu) ** 2) / (2.0 * s * s)) / (s * math.sqrt(2.0 * math.pi))


def G2(s1: float, s2: float, m1: float, m2: float, X: np.ndarray, Y: np.ndarray) -> np.ndarray:  # noqa: N802
    """2-D axis-aligned normal density centred at (m1, m2) with standard deviations (s1, s2)."""
    q = (X - m1) ** 2 / (s1 * s1) + (Y - m2) ** 2 / (s2 * s2)
    return np.exp(-q / 2.0) / (2.0 * math.pi * s1 * s2)


def line_v(s: float, B: float, T: float, X: np.ndarray, Y: np.ndarray) -> np.ndarray:  # noqa: N803
    """Line along Y from B to T with cross-section g(s, 0, X) and round caps.

    Between the ends the value is g(s, 0, X); at Y >= T it is c G2(s, s, 0, T, X, Y) and at
    Y <= B it is c G2(s, s, 0, B, X, Y), with c = max g / max G2 over the grid so that the caps
    meet the line at the same peak height.
    """
    body = g(s, 0.0, X)
    top = G2(s, s, 0.0, T, X, Y)
    bottom = G2(s, s, 0.0, B, X, Y)
    c = float(body.max()) / float(top.max())
    return np.where(Y >= T, c * top, np.where(Y <= B, c * bottom, body))


def line_h(s: float, L: float, R: float, X: np.ndarray, Y: np.ndarray) -> np.ndarray:  # noqa: N803
    """Line along X from L to R with cross-section g(s, 0, Y) and round caps (line_v with X, Y swapped)."""
    return line_v(s, L, R, Y, X)


def print_lines_on(X: np.ndarray, Y: np.ndarray) -> np.ndarray:  # noqa: N803
    """d = 0.1 (l1 + ... + l6) evaluated at scaled coordinates X, Y (any equal shapes), scene units."""
    l1 = line_v(0.5, -4.5, 4.5, X, Y)
    l2 = 0.75 * line_v(0.5, -4.5, 1.0, X - 3.0, Y)
    l3 = 0.75 * line_v(0.5, 2.5, 4.5, X - 3.0, Y)
    l4 = line_h(0.5, -4.5, -2.0, X, Y)
    l5 = 0.5 * line_h(0.25, -4.5, -2.0, X, Y - 2.5)
    l5 = l5 * (float(l1.max()) / float(l5.max()))
    # The official code adds the unrescaled l6; its analytic peak 0.25 / (0.125 sqrt(2 pi)) equals l1's.
    l6 = 0.25 * line_h(0.125, -4.5, -2.0, X, Y - 4.5)
    return HEIGHT_SCALE * (l1 + l2 + l3 + l4 + l5 + l6)


def flat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """No printed glass: d = 0 everywhere (the bare substrate)."""
    return np.zeros_like(x)


def gaussian(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ridge along y: d = 0.5 g(1, 0, 6x), peak 0.5 / sqrt(2 pi) ~ 0.1995 at x = 0."""
    return 0.5 * g(1.0, 0.0, COORDINATE_SCALE * x)


def print_lines(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The paper's "print lines" ground truth (docs/method.md, "Built-in height fields");
    peak ~ 0.1 / (0.5 sqrt(2 pi))."""
    return print_lines_on(COORDINATE_SCALE * x, COORDINATE_SCALE * y)


def oblique_lines(x: np.ndarray, y: np.ndarray, angle_deg: float = OBLIQUE_ANGLE_DEG) -> np.ndarray:
    """The print lines on a grid rotated by ``angle_deg`` (default 15 degrees).

    X, Y are taken from the rotated coordinates x' = cos(a) x - sin(a) y, y' = sin(a) x + cos(a) y.
    """
    a = math.radians(angle_deg)
    xr = math.cos(a) * x - math.sin(a) * y
    yr = math.sin(a) * x + math.cos(a) * y
    return print_lines_on(COORDINATE_SCALE * xr, COORDINATE_SCALE * yr)


def bump(x: np.ndarray, y: np.ndarray, center: Sequence[float] = (0.0, 0.0), sigma: float = 0.25,
         height: float = 0.05) -> np.ndarray:
    """Smooth Gaussian bump d = height exp(-|(x, y) - center|^2 / (2 sigma^2)); lengths in scene units."""
    if len(center) != 2:
        raise ValueError(f"bump center={list(center)} must have two coordinates [x, y], e.g. [0.0, 0.0]")
    if not sigma > 0.0:
        raise ValueError(f"bump sigma={sigma} must be positive, e.g. 0.25")
    if not height >= 0.0:
        raise ValueError(f"bump height={height} must be >= 0 (printed glass), e.g. 0.05")
    r2 = (x - float(center[0])) ** 2 + (y - float(center[1])) ** 2
    return float(height) * np.exp(-r2 / (2.0 * float(sigma) ** 2))


def segment_distance(x: np.ndarray, y: np.ndarray, start: Sequence[float], end: Sequence[float]) -> np.ndarray:
    """Distance of the points (x, y) to the segment from ``start`` to ``end`` (scene units)."""
    ax, ay = float(start[0]), float(start[1])
    bx, by = float(end[0]), float(end[1])
    length2 = (bx - ax) ** 2 + (by - ay) ** 2
    t = np.clip(((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / length2, 0.0, 1.0)
    return np.hypot(x - ax - t * (bx - ax), y - ay - t * (by - ay))


def letter_a(x: np.ndarray, y: np.ndarray, height: float = 0.08, stroke: float = 0.05, size: float = 1.4
             ) -> np.ndarray:
    """A printed letter "A": two legs from the apex (0, size/2) to the feet (+-0.36 size, -size/2)
    and a crossbar at y = -0.1 size, each stroke with a Gaussian cross-section of standard deviation
    ``stroke`` and peak ``height`` (where strokes meet, the higher one counts). The defaults give
    the print lines' peak height (0.08) on narrower strokes (0.05 against 0.083): steeper slopes,
    on lines that are not aligned with the grid."""
    checked_number(height, "letter_a height", least=0.0)
    checked_number(stroke, "letter_a stroke", above=0.0)
    checked_number(size, "letter_a size", above=0.0)
    half, foot = 0.5 * size, 0.36 * size
    bar_y = -0.1 * size
    bar_x = foot * (half - bar_y) / size  # where the crossbar meets the legs
    strokes = [((0.0, half), (-foot, -half)), ((0.0, half), (foot, -half)), ((-bar_x, bar_y), (bar_x, bar_y))]
    nearest = np.min([segment_distance(x, y, a, b) for a, b in strokes], axis=0)
    return float(height) * np.exp(-nearest ** 2 / (2.0 * float(stroke) ** 2))


ShapeFunction = Callable[..., np.ndarray]

SHAPES: dict[str, ShapeFunction] = {
    "flat": flat,
    "gaussian": gaussian,
    "print_lines": print_lines,
    "oblique_lines": oblique_lines,
    "bump": bump,
    "letter_a": letter_a,
}


def _check_params(name: str, function: ShapeFunction, params: dict[str, object]) -> None:
    allowed = [p for p in inspect.signature(function).parameters if p not in ("x", "y")]
    for key in params:
        if key not in allowed:
            hint = ", ".join(allowed) if allowed else "none"
            raise ValueError(f"shape {name!r} has no parameter {key!r}; its parameters: {hint}")


def make_shape(name: str, resolution: int, **params: object) -> np.ndarray:
    """Height field ``name`` on an m x m grid (m = ``resolution``), float64 (m, m), scene units, >= 0.

    ``params`` are passed to the shape function (e.g. ``sigma`` for ``bump``); unknown names and
    parameters raise ValueError listing what is available.
    """
    if name not in SHAPES:
        raise ValueError(f"unknown shape {name!r}; known shapes: {', '.join(sorted(SHAPES))}")
    resolution = checked_whole(resolution, "resolution", 2, example="128")
    function = SHAPES[name]
    _check_params(name, function, params)
    x, y = grid(resolution)
    d = np.asarray(function(x, y, **params), dtype=np.float64)
    return np.clip(d, 0.0, None)
