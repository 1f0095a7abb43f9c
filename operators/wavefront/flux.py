"""The flux the wavefront renderer's aim triangles carry: each triangle's solid angle seen from the
light in closed form (Van Oosterom and Strackee 1983), so the emitted flux is exact, times the mean
of its vertices' Fresnel transmittances, for triangles whose three vertices took one light path
(operators/wavefront/renderer.py). Whole grids are computed ROW_BLOCK rows at a time.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from operators.heightfield.side_walls import LOST

__all__ = ["ROW_BLOCK", "grid_flux", "grid_solid_angles", "triangle_solid_angle"]

# Grid rows per block of the whole-grid array steps (their temporaries stay in the cache).
ROW_BLOCK = 64


def triangle_solid_angle(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray, cx: np.ndarray,
                         cy: np.ndarray, dz: float) -> np.ndarray:
    """Solid angles (sr) of triangles (a, b, c) on a plane dz below the light (dz < 0), arrays of
    one shape; the vertices' x, y are relative to the light's. Van Oosterom-Strackee:
    tan(Omega / 2) = |a . (b x c)| / (|a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|), with
    a . (b x c) = dz ((b - a) x (c - a))_z for a flat triangle (no cancellation)."""
    num = np.abs(dz * ((bx - ax) * (cy - ay) - (by - ay) * (cx - ax)))
    dz2 = dz * dz
    la = np.sqrt(ax * ax + ay * ay + dz2)
    lb = np.sqrt(bx * bx + by * by + dz2)
    lc = np.sqrt(cx * cx + cy * cy + dz2)
    den = (la * lb * lc + (ax * bx + ay * by + dz2) * lc + (ax * cx + ay * cy + dz2) * lb
           + (bx * cx + by * cy + dz2) * la)
    return 2.0 * np.arctan2(num, den)


def _row_blocks(rows: int) -> Iterator[tuple[int, int]]:
    """(start, stop) of the consecutive blocks of ``ROW_BLOCK`` grid rows that cover 0 .. rows."""
    for start in range(0, rows, ROW_BLOCK):
        yield start, min(start + ROW_BLOCK, rows)


def grid_solid_angles(k: int, half: float, base: float, light: tuple[float, float, float]) -> np.ndarray:
    """Solid angles (2, K-1, K-1) of the grid's triangles (split as in coverage.rasterize_grid)
    with aim points x_j = -half + 2 half j / (K - 1) (y likewise by row) on z = base; computed
    ``ROW_BLOCK`` rows at a time (see :func:`grid_flux`)."""
    axis = -half + (2.0 * half) * np.arange(k) / (k - 1)
    x = (axis - light[0])[None, :]
    y = (axis - light[1])[:, None]
    x0, x1 = x[:, :-1], x[:, 1:]
    dz = base - light[2]
    omega = np.empty((2, k - 1, k - 1))
    for a, b in _row_blocks(k - 1):
        y0, y1 = y[a:b], y[a + 1:b + 1]
        omega[0, a:b] = triangle_solid_angle(x0, y0, x1, y0, x1, y1, dz)
        omega[1, a:b] = triangle_solid_angle(x0, y0, x1, y1, x0, y1, dz)
    return omega


def grid_flux(omega: np.ndarray, ratio: np.ndarray, path: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(flux, mixed), each (2, K-1, K-1): flux = scale * omega * the mean vertex transmittance
    ``ratio`` (K, K) for triangles whose three vertices took one path (``path`` (K, K), the
    codes of operators/heightfield/side_walls.py, 0 for lost), else 0; mixed: its vertices took
    different paths, not all lost. Computed ``ROW_BLOCK`` rows at a time: whole-grid temporaries
    (33 MB each at K = 2049) made this step take 0.6-1.2 s of a 4 M-vertex render, the blocks 0.06 s."""
    flux = np.empty(omega.shape)
    mixed = np.empty(omega.shape, dtype=np.bool_)
    for a, b in _row_blocks(ratio.shape[0] - 1):
        top, bottom = ratio[a:b], ratio[a + 1:b + 1]
        r00, r01, r10, r11 = top[:, :-1], top[:, 1:], bottom[:, :-1], bottom[:, 1:]
        c_top, c_bottom = path[a:b], path[a + 1:b + 1]
        c00, c01, c10, c11 = c_top[:, :-1], c_top[:, 1:], c_bottom[:, :-1], c_bottom[:, 1:]
        corners = r00 + r11
        for k, (third, code) in enumerate(((r01, c01), (r10, c10))):
            one_path = (c00 == c11) & (c00 == code)
            block = scale * omega[k, a:b] * (corners + third) / 3.0
            block[~one_path | (c00 == LOST)] = 0.0
            flux[k, a:b] = block
            mixed[k, a:b] = ~one_path
    return flux, mixed
