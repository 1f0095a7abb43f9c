"""Photon differential splatting (Frisvad et al. 2014) as a differentiable torch operation."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import torch

from operators.kernels.numba_settings import to_numpy
from operators.kernels.simd import AVAILABLE as SIMD_AVAILABLE
from operators.splat import compiled
from operators.splat.native import gather_padding, pad_for_gather, splat_backward, splat_forward

MAX_DIFFERENTIAL_PX = 1e6


def footprint_metric(footprint: torch.Tensor, min_radius_px: float, max_radius_px: float) -> torch.Tensor:
    """Metric Q (3, N) = (q00, q01, q11) of each photon's footprint ellipse, in pixel units.

    ``footprint`` (2, 2, N) holds the positional differentials Du, Dv (in pixels) on the
    receiver; the footprint {a Du + b Dv : a^2 + b^2 <= 1} is the ellipse r^T A^-1 r <= 1 with
    A = Du Du^T + Dv Dv^T. A is scaled down where its major semi-axis exceeds the cut-off
    (the paper's maximum radius), then widened by min_radius_px^2 I, a pixel filter: no photon
    falls between pixel centres, even at a focus. Returns Q = (A + r0^2 I)^-1, computed in
    float64 with det = det A + r0^2 tr A + r0^4 so that near-degenerate footprints stay exact.
    """
    # Grazing photons can carry astronomically large differentials; bound them (far above any
    # footprint the cut-off lets through) so that squaring cannot overflow.
    bounded = footprint.double().clamp(-MAX_DIFFERENTIAL_PX, MAX_DIFFERENTIAL_PX)
    du, dv = bounded[0], bounded[1]
    a00 = du[0] ** 2 + dv[0] ** 2
    a01 = du[0] * du[1] + dv[0] * dv[1]
    a11 = du[1] ** 2 + dv[1] ** 2
    major = 0.5 * (a00 + a11) + torch.sqrt(0.25 * (a00 - a11) ** 2 + a01 ** 2 + 1e-300)
    r2 = min_radius_px ** 2
    scale = torch.clamp((max_radius_px ** 2 - r2) / major.clamp(min=1e-300), max=1.0)
    a00, a01, a11 = a00 * scale, a01 * scale, a11 * scale
    det = (a00 * a11 - a01 ** 2).clamp(min=0.0) + r2 * (a00 + a11) + r2 * r2
    return torch.stack([(a11 + r2) / det, -a01 / det, (a00 + r2) / det]).to(footprint.dtype)


def footprint_half_extent(metric: np.ndarray) -> float:
    """Largest half extent (pixels, at most 1e4) of the footprints' bounding boxes, (3, N) metric."""
    if metric.shape[1] == 0:
        return 0.0
    det = metric[0] * metric[2] - metric[1] ** 2
    half = np.sqrt(np.maximum(metric[0], metric[2]) / np.maximum(det, 1e-30))
    return float(np.nanmax(np.minimum(half, 1e4)))


def footprint_capacity(metric: np.ndarray) -> int:
    """Upper bound on the pixels of any footprint: its bounding box (3, N) metric."""
    side = 2 * math.ceil(footprint_half_extent(metric)) + 3
    return side * side


class _Splat(torch.autograd.Function):
    @staticmethod
    def forward(ctx, pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor,
                channel: torch.Tensor, channels: int, resolution: int) -> torch.Tensor:
        image = ImageAccumulator(channels, resolution, to_numpy(flux).dtype)
        image.add(to_numpy(pos), to_numpy(metric), to_numpy(flux), to_numpy(channel))
        ctx.save_for_backward(pos, metric, flux, channel)
        return image.image().to(flux.device)

    @staticmethod
    def backward(ctx, grad_image: torch.Tensor):
        pos, metric, flux, channel = ctx.saved_tensors
        return (*splat_photons_vjp(pos, metric, flux, channel, grad_image), None, None, None)


def splat_photons_vjp(pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor, channel: torch.Tensor,
                      grad_image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Adjoint of :func:`splat_photons` at these photons: gradients of <image, grad_image> w.r.t.
    pos (2, N), metric (3, N) and flux (N,), by the native gather (no forward splat needed)."""
    g_pos, g_metric, g_flux = PaddedAdjoint(to_numpy(grad_image)).gather(to_numpy(pos), to_numpy(metric),
                                                                         to_numpy(flux), to_numpy(channel))

    def back(a: np.ndarray, like: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(a).to(dtype=like.dtype, device=like.device)

    return back(g_pos, pos), back(g_metric, metric), back(g_flux, flux)


class ImageAccumulator:
    """Photons of several chunks splatted into one image (c, n, n): each thread's share into a
    buffer of its own (threads, c, n, n) of ``dtype``, summed once in :meth:`image`, instead of
    a buffer and a sum over the threads per chunk. The photons' arguments are taken in float64.
    ``c_kernels``: splat with the C kernels (:mod:`operators.splat.compiled`) where the extension
    was built, else with numba's (:func:`operators.splat.native.splat_forward`)."""

    def __init__(self, channels: int, resolution: int, dtype: np.dtype, c_kernels: bool = True) -> None:
        self.out = np.zeros((nb.get_num_threads(), channels, resolution, resolution), dtype=dtype)
        self.c_kernels = c_kernels and compiled.AVAILABLE

    def add(self, pos: np.ndarray, metric: np.ndarray, flux: np.ndarray, channel: np.ndarray) -> None:
        """Splat photons at ``pos`` (2, N) with metrics (3, N), ``flux`` (N,), ``channel`` (N,) int64."""
        if self.c_kernels:
            compiled.splat_spots(pos, metric, flux, channel, self.out, footprint_capacity(metric))
            return
        pos, metric, flux = (a.astype(np.float64, copy=False) for a in (pos, metric, flux))
        splat_forward(pos, metric, flux, channel, self.out, footprint_capacity(metric), SIMD_AVAILABLE)

    def image(self) -> torch.Tensor:
        """Flux per pixel (c, n, n) of every photon added."""
        return torch.from_numpy(self.out.sum(axis=0))


PAD_STEP = 8  # pixels: PaddedAdjoint's borders are multiples of this


class PaddedAdjoint:
    """The adjoint image G (c, n, n) with the zero border the gather needs, padded once for the
    photons of several chunks (again only where a chunk's footprints need a wider border); the
    photons are gathered in float64. ``c_kernels``: gather with the C kernels
    (:mod:`operators.splat.compiled`) where the extension was built, else with numba's.
    The border is rounded up to a multiple of PAD_STEP pixels, so that the gradients of nearby
    heights pad alike: ``spare``, an earlier gradient's (:attr:`padded`, :attr:`pad`), is
    overwritten where its border is the same (:func:`operators.splat.native.pad_for_gather`).
    The border decides which of the gather's paths a photon at the edge takes (the sums' order),
    so it depends only on these photons, never on the spare."""

    def __init__(self, grad_image: np.ndarray, c_kernels: bool = True,
                 spare: tuple[np.ndarray | None, int] | None = None) -> None:
        self.grad_image, self.pad, self.padded = grad_image, -1, None
        self.c_kernels = c_kernels and compiled.AVAILABLE
        self._spare = spare

    def gather(self, pos: np.ndarray, metric: np.ndarray, flux: np.ndarray, channel: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gradients of <splat(...), G> w.r.t. pos (2, N), metric (3, N) and flux (N,), float64."""
        pos, metric, flux = (np.ascontiguousarray(a, dtype=np.float64) for a in (pos, metric, flux))
        pad = gather_padding(footprint_half_extent(metric))
        pad = -(-pad // PAD_STEP) * PAD_STEP
        if pad > self.pad:
            spare, spare_pad = self._spare if self._spare is not None else (None, -1)
            reuse = spare if spare_pad == pad else None
            self.pad, self.padded, self._spare = pad, pad_for_gather(self.grad_image, pad, reuse=reuse), None
        if self.c_kernels:
            return compiled.gather_spots(pos, metric, flux, channel, self.padded, self.pad, nb.get_num_threads())
        g_pos, g_metric, g_flux = np.empty_like(pos), np.empty_like(metric), np.empty_like(flux)
        splat_backward(pos, metric, flux, channel, self.padded, self.pad, g_pos, g_metric, g_flux, SIMD_AVAILABLE,
                       nb.get_num_threads())
        return g_pos, g_metric, g_flux


def splat_photons(pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor, channel: torch.Tensor,
                  channels: int, resolution: int) -> torch.Tensor:
    """Image (channels, n, n) of flux per pixel from photons at ``pos`` (2, N) (pixel coordinates,
    x = column, y = row, centres on integers) with footprint metrics (3, N), ``flux`` (N,) in W and
    ``channel`` (N,) int64. Differentiable w.r.t. pos, metric and flux (native adjoint gather).
    """
    return _Splat.apply(pos, metric, flux, channel, channels, resolution)
