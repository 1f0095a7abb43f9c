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
from numba.extending import overload

from operators.kernels.numba_settings import jit_inline, jit_parallel
from operators.kernels.simd import (data_pointer, gather_box8, gather_spans, splat_box8_f32, splat_box8_f64,
                                    splat_spans_f32, splat_spans_f64)

# Photons farther than this from the image (pixels) are skipped: nothing of theirs can land.
FAR_PX = 1e7


@jit_inline
def footprint_usable(f, px, py, q00, q01, q11) -> bool:
    """Whether a photon of flux f at pixel (px, py) with metric Q has a finite, positive-definite footprint."""
    return (f != 0.0 and math.isfinite(f) and abs(px) < FAR_PX and abs(py) < FAR_PX
            and q00 > 0.0 and q11 > 0.0 and q00 * q11 - q01 * q01 > 0.0)


@jit_inline
def footprint_box(px, py, q00, q01, q11) -> tuple[int, int, int, int]:
    """Pixel columns x0 .. x1 and rows y0 .. y1 of the ellipse's bounding box (half extents
    sqrt(q11 / det Q) and sqrt(q00 / det Q))."""
    det = q00 * q11 - q01 * q01
    hx = math.sqrt(q11 / det)
    hy = math.sqrt(q00 / det)
    return int(math.ceil(px - hx)), int(math.floor(px + hx)), int(math.ceil(py - hy)), int(math.floor(py + hy))


@jit_inline
def row_terms(q01, q11, ry) -> tuple[float, float]:
    """(b, e) of the footprint's row at offset ``ry`` (pixels): t(rx, ry) = (q00 rx + b) rx + e."""
    return 2.0 * q01 * ry, q11 * ry * ry


@jit_inline
def falloff(q00, rx, b, e) -> float:
    """1 - t(r) at column offset ``rx`` of a row with terms (b, e) (:func:`row_terms`); the
    Silverman weight is its square where positive."""
    return 1.0 - ((q00 * rx + b) * rx + e)


# Side (pixels) of the fixed box that footprints of a few pixels' radius take: with constant trip
# counts LLVM unrolls the loops over the box and vectorises them, and the box's pixels outside the
# ellipse simply get weight 0.
LANES = 8


@jit_inline
def _fits_fixed_box(x0, x1, y0, y1, lo, hi) -> bool:
    """Whether the bounding box x0 .. x1, y0 .. y1 fits in a LANES x LANES box at (x0, y0) that
    lies in columns and rows lo .. hi."""
    return (x1 - x0 < LANES and y1 - y0 < LANES and x0 >= lo and y0 >= lo
            and x0 + LANES - 1 <= hi and y0 + LANES - 1 <= hi)


# Columns past a bounding box that the AVX2 kernels of larger footprints read and write: they take
# each row's chord in vectors of 4 pixels, the last of which may reach 3 pixels beyond the box
# (those pixels lie outside the ellipse and weigh 0).
SPAN_TAIL = 3


@nb.njit(cache=True, inline="always")
def _fits_spans(x0, x1, y0, y1, lo, hi) -> bool:
    """Whether the bounding box x0 .. x1, y0 .. y1 and SPAN_TAIL columns past it lie in columns
    and rows lo .. hi."""
    return x0 >= lo and y0 >= lo and y1 <= hi and x1 + SPAN_TAIL <= hi


@jit_inline
def _box_weights(buf, x0, y0, width, rows, px, py, q00, q01, q11) -> float:
    """Silverman weights max(1 - t, 0)^2 of the ``rows`` x ``width`` pixels from (x0, y0) into
    ``buf`` (row-major); returns their sum. Branch-free and free of per-row square roots."""
    s = 0.0
    rx0 = x0 - px
    for r in range(rows):
        b, e = row_terms(q01, q11, y0 + r - py)
        for j in range(width):
            u = max(falloff(q00, rx0 + j, b, e), 0.0)
            buf[r * width + j] = u * u
            s += u * u
    return s


@jit_inline
def _deposit(img, c, buf, x0, y0, width, lo, hi, ylo, yhi, scale) -> None:
    """Add ``scale`` times the weights ``buf`` of the box from (x0, y0), ``width`` pixels wide,
    to the pixels lo .. hi, ylo .. yhi of channel ``c`` of ``img``."""
    for iy in range(ylo, yhi + 1):
        # Row views: unit-stride loops that LLVM vectorises (12-16% faster than 3-D indexing).
        row = img[c, iy, lo:hi + 1]
        weights = buf[(iy - y0) * width + lo - x0:(iy - y0) * width + hi - x0 + 1]
        for j in range(hi - lo + 1):
            row[j] += scale * weights[j]


@nb.njit(cache=True, inline="always")
def _offset(a, c, y, x) -> int:
    """Element offset of a[c, y, x] from a's first element (a's last axis unit-stride)."""
    return (c * a.strides[0] + y * a.strides[1]) // a.itemsize + x


def _splat_box8_simd(img, c, x0, y0, rows, px, py, q00, q01, q11, f) -> None:
    """The AVX2 splat (:mod:`operators.kernels.simd`) of the first ``rows`` rows of the fixed box from
    (x0, y0), for numba."""


@overload(_splat_box8_simd, inline="always")
def _splat_box8_simd_impl(img, c, x0, y0, rows, px, py, q00, q01, q11, f):
    native = splat_box8_f32 if img.dtype == nb.types.float32 else splat_box8_f64

    def impl(img, c, x0, y0, rows, px, py, q00, q01, q11, f):
        native(data_pointer(img), _offset(img, c, y0, x0), img.strides[1] // img.itemsize, rows, x0 - px, y0 - py,
               q00, q01, q11, f)

    return impl


def _splat_spans_simd(img, c, x0, y0, rows, width, px, py, q00, q01, q11, f) -> None:
    """The AVX2 splat (:mod:`operators.kernels.simd`) of a footprint over the bounding box of
    ``rows`` rows and ``width`` columns from (x0, y0), each row over its chord, for numba."""


@overload(_splat_spans_simd, inline="always")
def _splat_spans_simd_impl(img, c, x0, y0, rows, width, px, py, q00, q01, q11, f):
    native = splat_spans_f32 if img.dtype == nb.types.float32 else splat_spans_f64

    def impl(img, c, x0, y0, rows, width, px, py, q00, q01, q11, f):
        native(data_pointer(img), _offset(img, c, y0, x0), img.strides[1] // img.itemsize, rows, width, x0 - px,
               y0 - py, q00, q01, q11, f)

    return impl


@jit_inline
def splat_photon(img, c, px, py, q00, q01, q11, f, buf, simd) -> None:
    """Add one photon's flux ``f`` into channel ``c`` of ``img`` (c, n, n), rows unit-stride.

    Two passes over the footprint's bounding box (a fixed LANES x LANES box where it fits, see
    LANES): the weights go into ``buf`` while their sum s is taken, then f / s times each weight
    lands on the pixels that lie on the image. Photons whose box has more pixels than ``buf``
    holds are left out (the caller sizes it for the largest footprint). With ``simd`` (only where
    :data:`operators.kernels.simd.AVAILABLE`) the AVX2 kernels do the fixed box, over the bounding
    box's rows only, and larger footprints whose box and SPAN_TAIL columns past it lie on the
    image, each row over its chord of the ellipse (the same weights, summed in another order).
    """
    if not footprint_usable(f, px, py, q00, q01, q11):
        return
    x0, x1, y0, y1 = footprint_box(px, py, q00, q01, q11)
    n = img.shape[1]
    if _fits_fixed_box(x0, x1, y0, y1, 0, n - 1) and buf.shape[0] >= LANES * LANES:
        if simd:
            _splat_box8_simd(img, c, x0, y0, y1 - y0 + 1, px, py, q00, q01, q11, f)
            return
        s = _box_weights(buf, x0, y0, LANES, LANES, px, py, q00, q01, q11)
        if s > 0.0:
            _deposit(img, c, buf, x0, y0, LANES, x0, x0 + LANES - 1, y0, y0 + LANES - 1, f / s)
        return
    width = x1 - x0 + 1
    if width <= 0 or y1 < y0:
        return
    if simd and _fits_spans(x0, x1, y0, y1, 0, n - 1):
        _splat_spans_simd(img, c, x0, y0, y1 - y0 + 1, width, px, py, q00, q01, q11, f)
        return
    if width * (y1 - y0 + 1) > buf.shape[0]:
        return
    s = _box_weights(buf, x0, y0, width, y1 - y0 + 1, px, py, q00, q01, q11)
    if s > 0.0:
        _deposit(img, c, buf, x0, y0, width, max(x0, 0), min(x1, n - 1), max(y0, 0), min(y1, n - 1), f / s)


@jit_parallel
def splat_forward(pos, metric, flux, channel, out, capacity, simd):
    """Accumulate photons into ``out`` (threads, c, n, n) (flux per pixel); sum over axis 0 after.

    pos (2, N) pixel coordinates (x = column, y = row), metric (3, N) = (q00, q01, q11),
    flux (N,), channel (N,) int; ``capacity`` bounds the pixels of one footprint; ``simd``: see
    :func:`splat_photon`.
    """
    nthreads = out.shape[0]
    count = flux.shape[0]
    per = (count + nthreads - 1) // nthreads
    for th in nb.prange(nthreads):
        img = out[th]
        buf = np.empty(capacity)
        for p in range(th * per, min(count, (th + 1) * per)):
            splat_photon(img, channel[p], pos[0, p], pos[1, p], metric[0, p], metric[1, p], metric[2, p],
                         flux[p], buf, simd)


@jit_inline
def gather_photon(padded, pad, c, px, py, q00, q01, q11, f) -> tuple[float, float, float, float, float, float]:
    """One photon's adjoint: gradients of <G, splat> w.r.t. (flux, px, py, q00, q01, q11).

    ``padded`` is G (c, n, n) with ``pad`` zero pixels added on every side (:func:`pad_for_gather`);
    ``pad`` must exceed the half extents of every footprint's bounding box, so the loops below
    need no bounds checks. With I = f / s * sum_k G_k w_k: dI/df = sum G w / s and, for theta in
    (px, py, q00, q01, q11), dI/dtheta = f / s * (sum_k G_k dw_k - (sum_k G_k w_k / s) sum_k dw_k),
    dw = -2 (1 - t) dt, dt/dp = -2 Q r, dt/dq00 = rx^2, dt/dq01 = 2 rx ry, dt/dq11 = ry^2.
    Every dw sum is a combination of the row moments sum (1 - t) rx^j, j = 0, 1, 2 (ry is fixed
    on a row), so the per-pixel loop over the bounding box only accumulates those, with and
    without G (branch-free; w = max(1 - t, 0)^2 is zero outside the ellipse), over the fixed
    LANES x LANES box where the bounding box fits it.
    """
    x0, y0, width, rows, _ = _gather_plan(padded, pad, px, py, q00, q01, q11, f)
    if width == 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return _gather_result(_gather_box(padded, pad, c, x0, y0, width, rows, px, py, q00, q01, q11), f)


@jit_inline
def gather_photon_simd(padded, pad, c, px, py, q00, q01, q11, f, simd, sums
                       ) -> tuple[float, float, float, float, float, float]:
    """:func:`gather_photon` with the sums taken by the AVX2 kernels when ``simd`` (only where
    :data:`operators.kernels.simd.AVAILABLE`): the fixed box's, and those of larger footprints
    whose box and SPAN_TAIL columns past it lie on the padded image, each row over its chord of
    the ellipse (the same terms, summed in another order). ``sums`` (12,) is their scratch. CPU
    only."""
    x0, y0, width, rows, span = _gather_plan(padded, pad, px, py, q00, q01, q11, f)
    if width == 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    fixed = width == LANES and rows == LANES
    if simd and (fixed or _fits_spans(x0, x0 + width - 1, y0, y0 + rows - 1, -pad, padded.shape[2] - 1 - pad)):
        offset, stride = _offset(padded, c, y0 + pad, x0 + pad), padded.strides[1] // 8
        if fixed:
            gather_box8(data_pointer(padded), offset, stride, span, x0 - px, y0 - py, q00, q01, q11,
                        data_pointer(sums))
        else:
            gather_spans(data_pointer(padded), offset, stride, rows, width, x0 - px, y0 - py, q00, q01, q11,
                         data_pointer(sums))
        return _gather_result((sums[0], sums[1], sums[2], sums[3], sums[4], sums[5], sums[6], sums[7], sums[8],
                               sums[9], sums[10], sums[11]), f)
    return _gather_result(_gather_box(padded, pad, c, x0, y0, width, rows, px, py, q00, q01, q11), f)


@jit_inline
def _gather_plan(padded, pad, px, py, q00, q01, q11, f) -> tuple[int, int, int, int, int]:
    """(x0, y0, width, rows, span) of the pixels :func:`gather_photon` sums over: the fixed
    LANES x LANES box where the footprint's bounding box fits it, else the bounding box cut to
    the padded image; width 0 where the photon contributes nothing (unusable, or off the image,
    where G = 0 on its whole footprint). ``span``: the first rows that hold the bounding box
    (the rest of a fixed box weighs 0)."""
    if not footprint_usable(f, px, py, q00, q01, q11):
        return 0, 0, 0, 0, 0
    n = padded.shape[1] - 2 * pad
    x0, x1, y0, y1 = footprint_box(px, py, q00, q01, q11)
    if x1 < 0 or y1 < 0 or x0 > n - 1 or y0 > n - 1 or x1 < x0 or y1 < y0:
        return 0, 0, 0, 0, 0
    if _fits_fixed_box(x0, x1, y0, y1, -pad, n - 1 + pad):
        return x0, y0, LANES, LANES, y1 - y0 + 1
    x0, x1 = max(x0, -pad), min(x1, n - 1 + pad)
    y0, y1 = max(y0, -pad), min(y1, n - 1 + pad)
    return x0, y0, x1 - x0 + 1, y1 - y0 + 1, y1 - y0 + 1


@jit_inline
def _gather_result(sums, f) -> tuple[float, float, float, float, float, float]:
    """The gradients (flux, px, py, q00, q01, q11) from the box's sums (:func:`_gather_box`)."""
    s, gw, v0, v1, v2, v3, v4, u0, u1, u2, u3, u4 = sums
    if s <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mean = gw / s
    scale = -2.0 * f / s
    return (mean, scale * (u0 - mean * v0), scale * (u1 - mean * v1), scale * (u2 - mean * v2),
            scale * (u3 - mean * v3), scale * (u4 - mean * v4))


@jit_inline
def _gather_box(padded, pad, c, x0, y0, width, rows, px, py, q00, q01, q11):
    """The sums :func:`gather_photon` needs over the ``rows`` x ``width`` pixels from (x0, y0):
    (s, sum_k G_k w_k, v0 .. v4, u0 .. u4) with v_i = sum_k dw_k / dtheta_i and
    u_i = sum_k G_k dw_k / dtheta_i over -2, theta = (px, py, q00, q01, q11)."""
    s = gw = 0.0
    v0 = v1 = v2 = v3 = v4 = 0.0
    u0 = u1 = u2 = u3 = u4 = 0.0
    for r in range(rows):
        ry = y0 + r - py
        b, e = row_terms(q01, q11, ry)
        row = padded[c, y0 + r + pad]
        sw = a0 = a1 = a2 = 0.0
        gsw = g0 = g1 = g2 = 0.0
        for j in range(width):
            rx = x0 + j - px
            u = max(falloff(q00, rx, b, e), 0.0)
            g = row[x0 + pad + j]
            sw += u * u
            a0 += u
            a1 += u * rx
            a2 += u * rx * rx
            gu = g * u
            gsw += gu * u
            g0 += gu
            g1 += gu * rx
            g2 += gu * rx * rx
        s += sw
        gw += gsw
        v0 -= 2.0 * (q00 * a1 + q01 * ry * a0)
        v1 -= 2.0 * (q01 * a1 + q11 * ry * a0)
        v2 += a2
        v3 += 2.0 * ry * a1
        v4 += ry * ry * a0
        u0 -= 2.0 * (q00 * g1 + q01 * ry * g0)
        u1 -= 2.0 * (q01 * g1 + q11 * ry * g0)
        u2 += g2
        u3 += 2.0 * ry * g1
        u4 += ry * ry * g0
    return s, gw, v0, v1, v2, v3, v4, u0, u1, u2, u3, u4


def gather_padding(max_half_extent_px: float) -> int:
    """Zero border (pixels) that :func:`gather_photon` needs for bounding boxes up to this half
    extent, with SPAN_TAIL more on the right for the AVX2 kernels of larger footprints."""
    return int(math.ceil(max_half_extent_px)) + 2 + SPAN_TAIL


def pad_for_gather(grad_image: np.ndarray, pad: int, divisor: float = 1.0, reuse: np.ndarray | None = None
                   ) -> np.ndarray:
    """G / divisor (c, n, n) float64 with ``pad`` zero pixels on every side, for
    :func:`gather_photon`, written in one pass (no float64 or quotient temporaries). ``reuse``:
    what an earlier call returned for the same shape and pad, whose border is still zero (the
    gathers only read it): its interior is overwritten instead of new memory zeroed, which on a
    2048 x 2048 receiver costs more in page faults than the copy."""
    grad_image = np.asarray(grad_image)
    c, rows, cols = grad_image.shape
    shape = (c, rows + 2 * pad, cols + 2 * pad)
    fits = reuse is not None and reuse.shape == shape and reuse.dtype == np.float64 and reuse.flags.c_contiguous
    padded = reuse if fits else np.zeros(shape)
    interior = padded[:, pad:pad + rows, pad:pad + cols]
    if divisor == 1.0:
        interior[...] = grad_image  # a plain copy is twice as fast as the division's loop
    else:
        np.divide(grad_image, divisor, out=interior, dtype=np.float64)
    return padded


GATHER_BLOCK = 4096  # photons per task of splat_backward's threads


@jit_parallel
def splat_backward(pos, metric, flux, channel, padded, pad, g_pos, g_metric, g_flux, simd, threads):
    """Gather the adjoint (see :func:`gather_photon`): gradients of <G, splat(...)> w.r.t.
    pos (2, N), metric (3, N) and flux (N,), written into g_pos, g_metric and g_flux; ``padded``
    is G with ``pad`` zero pixels on every side (:func:`pad_for_gather`); ``simd``: see
    :func:`gather_photon_simd`; ``threads``: numba's thread count (an argument: a kernel that asks
    numba for it cannot be cached)."""
    count = flux.shape[0]
    blocks = (count + GATHER_BLOCK - 1) // GATHER_BLOCK
    # Thread t takes the blocks t, t + threads, ...: photons with large footprints come in runs
    # (neighbours on the print land near each other), which a split into contiguous shares leaves
    # to one thread (a two-lens gradient's gather 17% slower that way). Every photon's gradients
    # are its own, so the split does not change them.
    for t in nb.prange(threads):
        sums = np.empty(12)
        for b in range(t, blocks, threads):
            for p in range(b * GATHER_BLOCK, min(count, (b + 1) * GATHER_BLOCK)):
                _gather_into(padded, pad, pos, metric, flux, channel, p, g_pos, g_metric, g_flux, simd, sums)


@jit_inline
def _gather_into(padded, pad, pos, metric, flux, channel, p, g_pos, g_metric, g_flux, simd, sums) -> None:
    """Photon p's gradients (:func:`gather_photon_simd`) into g_pos, g_metric and g_flux."""
    g = gather_photon_simd(padded, pad, channel[p], pos[0, p], pos[1, p], metric[0, p], metric[1, p],
                           metric[2, p], flux[p], simd, sums)
    g_flux[p] = g[0]
    g_pos[0, p] = g[1]
    g_pos[1, p] = g[2]
    g_metric[0, p] = g[3]
    g_metric[1, p] = g[4]
    g_metric[2, p] = g[5]
