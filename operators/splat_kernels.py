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


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _weights(px, py, q00, q01, q11, buf) -> tuple[float, int]:
    """Weights (1 - t)^2 of the ellipse's pixels, row by row, into ``buf``; returns (sum, count).

    Pixels beyond ``buf``'s capacity are left out (the caller sizes it for the largest footprint).
    """
    s = 0.0
    count = 0
    y0, y1 = _row_range(q00, q01, q11, py)
    for iy in range(y0, y1 + 1):
        ry = iy - py
        x0, x1 = _row_span(q00, q01, q11, ry, px)
        for ix in range(x0, x1 + 1):
            rx = ix - px
            t = q00 * rx * rx + 2.0 * q01 * rx * ry + q11 * ry * ry
            w = (1.0 - t) ** 2 if t < 1.0 else 0.0
            if count < buf.shape[0]:
                buf[count] = w
            count += 1
            s += w
    return s, count


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def splat_forward(pos, metric, flux, channel, out, capacity):
    """Accumulate photons into ``out`` (threads, c, n, n) (flux per pixel); sum over axis 0 after.

    pos (2, N) pixel coordinates (x = column, y = row), metric (3, N) = (q00, q01, q11),
    flux (N,), channel (N,) int; ``capacity`` bounds the pixels of one footprint.
    """
    nthreads, _, n, _ = out.shape
    count = flux.shape[0]
    per = (count + nthreads - 1) // nthreads
    for th in nb.prange(nthreads):
        img = out[th]
        buf = np.empty(capacity)
        for p in range(th * per, min(count, (th + 1) * per)):
            f, px, py = flux[p], pos[0, p], pos[1, p]
            q00, q01, q11 = metric[0, p], metric[1, p], metric[2, p]
            if not _usable(f, px, py, q00, q01, q11):
                continue
            s, used = _weights(px, py, q00, q01, q11, buf)
            if s <= 0.0 or used > capacity:
                continue
            scale = f / s
            c = channel[p]
            k = 0
            y0, y1 = _row_range(q00, q01, q11, py)
            for iy in range(y0, y1 + 1):
                ry = iy - py
                x0, x1 = _row_span(q00, q01, q11, ry, px)
                if 0 <= iy < n:
                    for ix in range(x0, x1 + 1):
                        if 0 <= ix < n:
                            img[c, iy, ix] += scale * buf[k]
                        k += 1
                else:
                    k += max(x1 - x0 + 1, 0)


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def splat_backward(pos, metric, flux, channel, grad_image, g_pos, g_metric, g_flux):
    """Gather the adjoint: gradients of <grad_image, splat(...)> w.r.t. pos, metric and flux.

    With I = f / s * sum_k G_k w_k: dI/df = sum G w / s and, for theta in (px, py, q00, q01, q11),
    dI/dtheta = f / s * (sum_k G_k dw_k - (sum_k G_k w_k / s) sum_k dw_k),
    dw = -2 (1 - t) dt, dt/dp = -2 Q r, dt/dq00 = rx^2, dt/dq01 = 2 rx ry, dt/dq11 = ry^2.
    """
    _, n, _ = grad_image.shape
    for p in nb.prange(flux.shape[0]):
        f, px, py = flux[p], pos[0, p], pos[1, p]
        q00, q01, q11 = metric[0, p], metric[1, p], metric[2, p]
        g_flux[p] = 0.0
        g_pos[0, p] = 0.0
        g_pos[1, p] = 0.0
        g_metric[0, p] = 0.0
        g_metric[1, p] = 0.0
        g_metric[2, p] = 0.0
        if not _usable(f, px, py, q00, q01, q11):
            continue
        c = channel[p]
        s = gw = 0.0
        u0 = u1 = u2 = u3 = u4 = 0.0  # sum_k G_k dw_k / dtheta
        v0 = v1 = v2 = v3 = v4 = 0.0  # sum_k dw_k / dtheta
        y0, y1 = _row_range(q00, q01, q11, py)
        for iy in range(y0, y1 + 1):
            ry = iy - py
            x0, x1 = _row_span(q00, q01, q11, ry, px)
            row_on = 0 <= iy < n
            for ix in range(x0, x1 + 1):
                rx = ix - px
                t = q00 * rx * rx + 2.0 * q01 * rx * ry + q11 * ry * ry
                if t >= 1.0:
                    continue
                w = (1.0 - t) ** 2
                k = -2.0 * (1.0 - t)
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
                if row_on and 0 <= ix < n:
                    g = grad_image[c, iy, ix]
                    gw += g * w
                    u0 += g * d0
                    u1 += g * d1
                    u2 += g * d2
                    u3 += g * d3
                    u4 += g * d4
        if s <= 0.0:
            continue
        mean = gw / s
        scale = f / s
        g_flux[p] = mean
        g_pos[0, p] = scale * (u0 - mean * v0)
        g_pos[1, p] = scale * (u1 - mean * v1)
        g_metric[0, p] = scale * (u2 - mean * v2)
        g_metric[1, p] = scale * (u3 - mean * v3)
        g_metric[2, p] = scale * (u4 - mean * v4)
