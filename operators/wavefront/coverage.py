"""Exact-coverage rasterisation of flux-carrying triangles (numba, multi-threaded).

A triangle T with flux f spreads f evenly over its area: pixel P receives f |T ∩ P| / |T|.
|T ∩ P| is computed exactly (to rounding) by polygon clipping: T is clipped to the pixel row's
horizontal strip (Sutherland-Hodgman against two half-planes, at most 5 vertices), that polygon to
each pixel column of the strip (at most 7 vertices), and the clipped polygon's area is taken by
the shoelace formula. Orientation is ignored (|area|), so a flipped triangle counts like any
other and overlapping triangles add. Light outside the image is lost.

Coordinates are in *pixel corner units*: pixel p (0 .. n-1) spans [p, p + 1] on both axes
(x = column, y = row; its centre is p + 1/2), so a scene point X maps to (X + W_r) / px
(docs/method.md, "Setup and units"). Each triangle is clipped in coordinates relative to the
lower corner of its bounding box's first pixel, so that rounding scales with the triangle, not
with the image. A triangle whose area is below ``DEGENERATE_AREA`` (pixel areas) puts all its
flux into the pixel containing its centroid; one that lies inside a single pixel skips clipping.

Threads: the work (rows of grid cells, or blocks of listed triangles) is dealt round-robin to a
fixed number of lanes, one image per lane, summed in lane order; so a rerun with the same thread
count is bit-identical whatever the scheduler does.

The same kernels in C (``operators/kernels/coverage_kernels.c``, compiled at install) do the work
where the extension was built; these numba kernels where it was not.
"""

from __future__ import annotations

import ctypes
import math

import numba as nb
import numpy as np

from operators.kernels import extension
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel

# Triangles with less area than this (in pixel areas) deposit at their centroid.
DEGENERATE_AREA = 1e-14
# Vertices farther than this from the image (pixels) make a triangle unusable (skipped).
FAR_PX = 1e9
# Vertices a clipped polygon may have: a convex one gains at most one per half-plane (3 -> 7), but
# each clip at most doubles any polygon (3 -> 48), so rounding can never overrun the buffers.
POLYGON_CAPACITY = 48
# Listed triangles per work item of rasterize_triangles.
TRIANGLE_BLOCK = 1024


@jit_inline
def _clip(xs, ys, count, axis, bound, upper, out_x, out_y) -> int:
    """Sutherland-Hodgman: clip the polygon (xs, ys)[:count] to coordinate ``axis`` (0 = x,
    1 = y) <= ``bound`` (``upper``) or >= ``bound``; writes it to (out_x, out_y), returns its size."""
    if count == 0:
        return 0
    sign = 1.0 if upper else -1.0
    sx = xs[count - 1]
    sy = ys[count - 1]
    sd = sign * ((sx if axis == 0 else sy) - bound)
    k = 0
    for i in range(count):
        ex = xs[i]
        ey = ys[i]
        ed = sign * ((ex if axis == 0 else ey) - bound)
        if (ed <= 0.0) != (sd <= 0.0):  # the edge crosses the boundary: add the crossing point
            t = sd / (sd - ed)
            if axis == 0:
                out_x[k] = bound
                out_y[k] = sy + t * (ey - sy)
            else:
                out_x[k] = sx + t * (ex - sx)
                out_y[k] = bound
            k += 1
        if ed <= 0.0:
            out_x[k] = ex
            out_y[k] = ey
            k += 1
        sx = ex
        sy = ey
        sd = ed
    return k


@jit_inline
def _area(xs, ys, count) -> float:
    """|area| of the polygon (xs, ys)[:count] (shoelace)."""
    s = 0.0
    jx = xs[count - 1]
    jy = ys[count - 1]
    for i in range(count):
        s += jx * ys[i] - xs[i] * jy
        jx = xs[i]
        jy = ys[i]
    return 0.5 * abs(s)


@jit_inline
def deposit_triangle(img, x0, y0, x1, y1, x2, y2, f, scratch) -> None:
    """Add flux ``f`` of the triangle (x0, y0), (x1, y1), (x2, y2) (pixel corner units) to
    ``img`` (n, n) by exact coverage; ``scratch`` (6, POLYGON_CAPACITY) float64 holds the
    clipped polygons. Dropped (f = 0), degenerate and one-pixel triangles are handled here, the
    rest by :func:`_deposit_clipped` (a call, so that the clipping is compiled once)."""
    if f == 0.0 or not (abs(x0) < FAR_PX and abs(x1) < FAR_PX and abs(x2) < FAR_PX
                        and abs(y0) < FAR_PX and abs(y1) < FAR_PX and abs(y2) < FAR_PX):
        return  # dropped, or a vertex at infinity / NaN (the comparisons are false for NaN)
    n = img.shape[0]
    xmin = min(x0, x1, x2)
    xmax = max(x0, x1, x2)
    ymin = min(y0, y1, y2)
    ymax = max(y0, y1, y2)
    if xmax <= 0.0 or ymax <= 0.0 or xmin >= n or ymin >= n:
        return  # wholly off the image
    ox = math.floor(xmin)
    oy = math.floor(ymin)
    # Relative coordinates: the pixel (ox, oy) spans [0, 1]^2.
    ax, ay = x0 - ox, y0 - oy
    bx, by = x1 - ox, y1 - oy
    cx, cy = x2 - ox, y2 - oy
    area = 0.5 * abs((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))
    if area < DEGENERATE_AREA:
        px = int(math.floor((x0 + x1 + x2) / 3.0))
        py = int(math.floor((y0 + y1 + y2) / 3.0))
        if 0 <= px < n and 0 <= py < n:
            img[py, px] += f
        return
    col_lo = int(ox)
    row_lo = int(oy)
    col_hi = int(math.ceil(xmax)) - 1  # last column the triangle reaches into
    row_hi = int(math.ceil(ymax)) - 1
    if col_hi <= col_lo and row_hi <= row_lo:  # inside one pixel (on the image: checked above)
        img[row_lo, col_lo] += f
        return
    _deposit_clipped(img, ax, ay, bx, by, cx, cy, col_lo, row_lo, col_hi, row_hi, f / area, scratch)


@jit_call
def _deposit_clipped(img, ax, ay, bx, by, cx, cy, col_lo, row_lo, col_hi, row_hi, scale, scratch) -> None:
    """Add ``scale`` times |T ∩ pixel| to every pixel of rows row_lo .. row_hi and columns
    col_lo .. col_hi (clamped to the image) for the triangle T with vertices (a, b, c) relative
    to the corner (col_lo, row_lo): strip clip per row, then column clip per pixel."""
    n = img.shape[0]
    tx = scratch[0]
    ty = scratch[1]
    sx = scratch[2]
    sy = scratch[3]
    px_ = scratch[4]
    py_ = scratch[5]
    for row in range(max(row_lo, 0), min(row_hi, n - 1) + 1):
        # Strip [row, row + 1] in relative coordinates [row - row_lo, row - row_lo + 1].
        lo = float(row - row_lo)
        tx[0], ty[0], tx[1], ty[1], tx[2], ty[2] = ax, ay, bx, by, cx, cy
        m = _clip(tx, ty, 3, 1, lo, False, px_, py_)
        m = _clip(px_, py_, m, 1, lo + 1.0, True, sx, sy)
        if m < 3:
            continue
        smin = sx[0]
        smax = sx[0]
        for i in range(1, m):
            smin = min(smin, sx[i])
            smax = max(smax, sx[i])
        c_lo = max(col_lo + int(math.floor(smin)), 0)
        c_hi = min(col_lo + int(math.ceil(smax)) - 1, n - 1, col_hi)
        if c_hi < c_lo:
            continue
        if c_lo == c_hi and smin >= c_lo - col_lo and smax <= c_lo - col_lo + 1.0:
            img[row, c_lo] += scale * _area(sx, sy, m)
            continue
        for col in range(c_lo, c_hi + 1):
            left = float(col - col_lo)
            k = _clip(sx, sy, m, 0, left, False, px_, py_)
            k = _clip(px_, py_, k, 0, left + 1.0, True, tx, ty)
            if k >= 3:
                img[row, col] += scale * _area(tx, ty, k)


@jit_inline
def _cell_triangles(img, vertices, flux, i, j, scratch) -> None:
    """The two triangles of grid cell (i, j): (v[i,j], v[i,j+1], v[i+1,j+1]) with flux[0, i, j]
    and (v[i,j], v[i+1,j+1], v[i+1,j]) with flux[1, i, j]."""
    f0 = flux[0, i, j]
    f1 = flux[1, i, j]
    if f0 == 0.0 and f1 == 0.0:
        return
    x00, y00 = vertices[i, j, 0], vertices[i, j, 1]
    x11, y11 = vertices[i + 1, j + 1, 0], vertices[i + 1, j + 1, 1]
    if f0 != 0.0:
        deposit_triangle(img, x00, y00, vertices[i, j + 1, 0], vertices[i, j + 1, 1], x11, y11, f0, scratch)
    if f1 != 0.0:
        deposit_triangle(img, x00, y00, x11, y11, vertices[i + 1, j, 0], vertices[i + 1, j, 1], f1, scratch)


@jit_parallel
def _rasterize_grid(vertices, flux, out) -> None:
    """Add the grid's triangles to ``out`` (lanes, n, n); cell row i goes to lane i % lanes."""
    lanes = out.shape[0]
    rows = flux.shape[1]
    cols = flux.shape[2]
    for lane in nb.prange(lanes):
        img = out[lane]
        scratch = np.empty((6, POLYGON_CAPACITY))
        for i in range(lane, rows, lanes):
            for j in range(cols):
                _cell_triangles(img, vertices, flux, i, j, scratch)


@jit_parallel
def _rasterize_list(triangles, flux, out) -> None:
    """Add listed triangles (T, 3, 2) with flux (T,) to ``out`` (lanes, n, n); block b of
    TRIANGLE_BLOCK triangles goes to lane b % lanes."""
    lanes = out.shape[0]
    count = flux.shape[0]
    blocks = (count + TRIANGLE_BLOCK - 1) // TRIANGLE_BLOCK
    for lane in nb.prange(lanes):
        img = out[lane]
        scratch = np.empty((6, POLYGON_CAPACITY))
        for b in range(lane, blocks, lanes):
            for t in range(b * TRIANGLE_BLOCK, min(count, (b + 1) * TRIANGLE_BLOCK)):
                deposit_triangle(img, triangles[t, 0, 0], triangles[t, 0, 1], triangles[t, 1, 0], triangles[t, 1, 1],
                                 triangles[t, 2, 0], triangles[t, 2, 1], flux[t], scratch)


def _lanes() -> int:
    return max(1, nb.get_num_threads())


def _compiled() -> ctypes.CDLL | None:
    """The extension with its C rasterisers bound, or None where it was not built."""
    library = extension.load()
    if library is not None and library.sfc_rasterize_grid.argtypes is None:
        p, i = ctypes.c_void_p, ctypes.c_int64
        library.sfc_rasterize_grid.argtypes = [p, i, p, p, i, i]
        library.sfc_rasterize_list.argtypes = [p, p, i, p, i, i]
    return library


def _check_status(status: int) -> None:
    if status != 0:
        raise MemoryError("the C rasteriser could not start its threads")


def rasterize_grid(vertices: np.ndarray, flux: np.ndarray, n: int) -> np.ndarray:
    """Flux per pixel (n, n) float64 of the triangles of a vertex grid.

    ``vertices`` (K, K, 2) float64: image positions (x, y) in pixel corner units of grid vertex
    [i, j]; ``flux`` (2, K-1, K-1) float64: flux of the two triangles of cell (i, j),
    (v[i,j], v[i,j+1], v[i+1,j+1]) and (v[i,j], v[i+1,j+1], v[i+1,j]); 0 drops a triangle.
    Image [row = y, col = x]; what falls off it is lost.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    flux = np.ascontiguousarray(flux, dtype=np.float64)
    k = vertices.shape[0]
    if vertices.shape != (k, k, 2) or flux.shape != (2, k - 1, k - 1) or k < 2:
        raise ValueError(f"need vertices (K, K, 2) and flux (2, K-1, K-1), got {vertices.shape} and {flux.shape}")
    out = np.zeros((_lanes(), int(n), int(n)))
    library = _compiled()
    if library is None:
        _rasterize_grid(vertices, flux, out)
    else:
        _check_status(library.sfc_rasterize_grid(vertices.ctypes.data, k, flux.ctypes.data, out.ctypes.data,
                                                 out.shape[0], out.shape[1]))
    return out.sum(axis=0)


def rasterize_triangles(triangles: np.ndarray, flux: np.ndarray, n: int) -> np.ndarray:
    """Flux per pixel (n, n) float64 of listed triangles: ``triangles`` (T, 3, 2) float64 vertex
    positions (x, y) in pixel corner units, ``flux`` (T,) float64 (0 drops a triangle)."""
    triangles = np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 3, 2)
    flux = np.ascontiguousarray(flux, dtype=np.float64).reshape(-1)
    if flux.shape[0] != triangles.shape[0]:
        raise ValueError(f"{triangles.shape[0]} triangles but {flux.shape[0]} fluxes")
    out = np.zeros((_lanes(), int(n), int(n)))
    library = _compiled()
    if flux.shape[0] and library is None:
        _rasterize_list(triangles, flux, out)
    elif flux.shape[0]:
        _check_status(library.sfc_rasterize_list(triangles.ctypes.data, flux.ctypes.data, flux.shape[0],
                                                 out.ctypes.data, out.shape[0], out.shape[1]))
    return out.sum(axis=0)
