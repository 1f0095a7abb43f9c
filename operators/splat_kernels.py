"""Native (numba, multi-threaded) photon-differential splatting and its adjoint (eq. 1-3).

A photon at pixel coordinates (px, py) (pixel centres on integers) with footprint metric
Q = [[q00, q01], [q01, q11]] covers the ellipse t(r) = r^T Q r < 1, r = pixel - (px, py).
It deposits flux * w(r) / s into every pixel of that ellipse that lies on the image, with the
Silverman weight w = (1 - t)^2 (the kernel 3/pi (1 - t)^2 up to its constant) and the normaliser
s = sum of w over the whole ellipse, on or off the image. So each photon puts exactly its flux on
the pixel lattice (energy conservation to rounding) and loses only what falls off the receiver.

The forward pass scatters into one image per thread (no races, summed afterwards); the adjoint
is a gather per photon, so it needs no synchronisation at all. Neither ever materialises a
(photon x pixel) array.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from operators.native import FAST_MATH


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def _row_span(q00, q01, q11, ry, px) -> tuple[int, int]:
    """Integer pixel columns whose centres satisfy t < 1 on the row at offset ry."""
    disc = (q01 * ry) ** 2 - q00 * (q11 * ry * ry - 1.0)
    if disc <= 0.0:
        return 1, 0
    root = math.sqrt(disc)
    return int(math.ceil(px + (-q01 * ry - root) / q00)), int(math.floor(px + (-q01 * ry + root) / q00))


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def _row_range(q00, q01, q11, py) -> tuple[int, int]:
    """Integer pixel rows that the ellipse touches (half height sqrt(q00 / det Q))."""
    half = math.sqrt(q00 / (q00 * q11 - q01 * q01))
    return int(math.ceil(py - half)), int(math.floor(py + half))


# Photons farther than this from the image (pixels) are skipped: nothing of theirs can land.
FAR_PX = 1e7


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def _usable(f, px, py, q00, q01, q11) -> bool:
    return (f != 0.0 and math.isfinite(f) and abs(px) < FAR_PX and abs(py) < FAR_PX
            and q00 > 0.0 and q11 > 0.0 and q00 * q11 - q01 * q01 > 0.0)


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def _box(px, py, q00, q01, q11) -> tuple[int, int, int, int]:
    """Pixel columns x0 .. x1 and rows y0 .. y1 of the ellipse's bounding box (half extents
    sqrt(q11 / det Q) and sqrt(q00 / det Q))."""
    det = q00 * q11 - q01 * q01
    hx = math.sqrt(q11 / det)
    hy = math.sqrt(q00 / det)
    return int(math.ceil(px - hx)), int(math.floor(px + hx)), int(math.ceil(py - hy)), int(math.floor(py + hy))


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def splat_photon(img, c, px, py, q00, q01, q11, f, buf) -> None:
    """Add one photon's flux ``f`` into channel ``c`` of ``img`` (c, n, n).

    Two passes over the footprint's bounding box, free of per-row square roots and branches:
    the weights max(1 - t, 0)^2 go into ``buf`` while their sum s is taken, then f / s times each
    weight lands on the pixels that lie on the image. Photons whose box has more pixels than
    ``buf`` holds are left out (the caller sizes it for the largest footprint).
    """
    if not _usable(f, px, py, q00, q01, q11):
        return
    x0, x1, y0, y1 = _box(px, py, q00, q01, q11)
    width = x1 - x0 + 1
    if width <= 0 or y1 < y0 or width * (y1 - y0 + 1) > buf.shape[0]:
        return
    s = 0.0
    k = 0
    for iy in range(y0, y1 + 1):
        ry = iy - py
        b = 2.0 * q01 * ry
        e = q11 * ry * ry
        rx = x0 - px
        for _ in range(width):
            u = max(1.0 - ((q00 * rx + b) * rx + e), 0.0)
            buf[k] = u * u
            s += u * u
            k += 1
            rx += 1.0
    if s <= 0.0:
        return
    n = img.shape[1]
    scale = f / s
    lo, hi = max(x0, 0), min(x1, n - 1)
    for iy in range(max(y0, 0), min(y1, n - 1) + 1):
        k = (iy - y0) * width - x0
        for ix in range(lo, hi + 1):
            img[c, iy, ix] += scale * buf[k + ix]


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def splat_forward(pos, metric, flux, channel, out, capacity):
    """Accumulate photons into ``out`` (threads, c, n, n) (flux per pixel); sum over axis 0 after.

    pos (2, N) pixel coordinates (x = column, y = row), metric (3, N) = (q00, q01, q11),
    flux (N,), channel (N,) int; ``capacity`` bounds the pixels of one footprint.
    """
    nthreads = out.shape[0]
    count = flux.shape[0]
    per = (count + nthreads - 1) // nthreads
    for th in nb.prange(nthreads):
        img = out[th]
        buf = np.empty(capacity)
        for p in range(th * per, min(count, (th + 1) * per)):
            splat_photon(img, channel[p], pos[0, p], pos[1, p], metric[0, p], metric[1, p], metric[2, p],
                         flux[p], buf)


@nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
def gather_photon(grad_image, c, px, py, q00, q01, q11, f) -> tuple[float, float, float, float, float, float]:
    """One photon's adjoint: gradients of <grad_image, splat> w.r.t. (flux, px, py, q00, q01, q11).

    With I = f / s * sum_k G_k w_k: dI/df = sum G w / s and, for theta in (px, py, q00, q01, q11),
    dI/dtheta = f / s * (sum_k G_k dw_k - (sum_k G_k w_k / s) sum_k dw_k),
    dw = -2 (1 - t) dt, dt/dp = -2 Q r, dt/dq00 = rx^2, dt/dq01 = 2 rx ry, dt/dq11 = ry^2.
    """
    if not _usable(f, px, py, q00, q01, q11):
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    n = grad_image.shape[1]
    s = gw = 0.0
    u0 = u1 = u2 = u3 = u4 = 0.0  # sum_k G_k dw_k / dtheta
    v0 = v1 = v2 = v3 = v4 = 0.0  # sum_k dw_k / dtheta
    y0, y1 = _row_range(q00, q01, q11, py)
    for iy in range(y0, y1 + 1):
        ry = iy - py
        x0, x1 = _row_span(q00, q01, q11, ry, px)
        # Columns lo .. hi of the span lie on the image (none if the row is off it).
        lo, hi = (max(x0, 0), min(x1, n - 1)) if 0 <= iy < n else (x1 + 1, x1)
        rx = x0 - px
        for ix in range(x0, x1 + 1):
            u = max(1.0 - (q00 * rx * rx + 2.0 * q01 * rx * ry + q11 * ry * ry), 0.0)
            w = u * u
            k = -2.0 * u
            d0 = -2.0 * k * (q00 * rx + q01 * ry)
            d1 = -2.0 * k * (q01 * rx + q11 * ry)
            d2 = k * rx * rx
            d3 = 2.0 * k * rx * ry
            d4 = k * ry * ry
            s += w
            v0 += d0
            v1 += d1
            v2 += d2
            v3 += d3
            v4 += d4
            g = grad_image[c, iy, ix] if lo <= ix <= hi else 0.0
            gw += g * w
            u0 += g * d0
            u1 += g * d1
            u2 += g * d2
            u3 += g * d3
            u4 += g * d4
            rx += 1.0
    if s <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mean = gw / s
    scale = f / s
    return (mean, scale * (u0 - mean * v0), scale * (u1 - mean * v1), scale * (u2 - mean * v2),
            scale * (u3 - mean * v3), scale * (u4 - mean * v4))


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def splat_backward(pos, metric, flux, channel, grad_image, g_pos, g_metric, g_flux):
    """Gather the adjoint (see :func:`gather_photon`): gradients of <grad_image, splat(...)> w.r.t.
    pos (2, N), metric (3, N) and flux (N,), written into g_pos, g_metric and g_flux."""
    for p in nb.prange(flux.shape[0]):
        g = gather_photon(grad_image, channel[p], pos[0, p], pos[1, p], metric[0, p], metric[1, p],
                          metric[2, p], flux[p])
        g_flux[p] = g[0]
        g_pos[0, p] = g[1]
        g_pos[1, p] = g[2]
        g_metric[0, p] = g[3]
        g_metric[1, p] = g[4]
        g_metric[2, p] = g[5]
