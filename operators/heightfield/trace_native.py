"""Host side of the fused photon kernels: image and gradient, by the C kernels compiled at install
(:mod:`operators.heightfield.trace_compiled`) where the extension was built, else by the numba
kernels (:mod:`operators.heightfield.kernels_native`, :mod:`operators.heightfield.adjoint_native`)."""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np

from operators.emission import LightEmitter
from operators.heightfield import trace_compiled
from operators.heightfield.adjoint_native import vjp_photons
from operators.heightfield.kernels_native import FusedScene, render_photons
from operators.heightfield.surface import HeightFieldGrid
from operators.heightfield.tangent_native import jvp_photons
from operators.kernels.simd import AVAILABLE as SIMD_AVAILABLE
from operators.scene import Scene
from operators.splat.native import gather_padding, pad_for_gather

NO_HITS = np.empty(0)  # kernels' marker for "no hit cache"


class FusedTracer:
    """Photons ``start .. stop-1`` of ``emitter`` traced through ``scene`` in one native pass each.

    Matches the torch path (LightEmitter.batch, trace_substrate, footprint_metric,
    splat_photons) photon by photon, computed in float64. ``kernels``: ``c`` or ``numba``
    (OperatorSettings.kernels; C only where the extension was built); ``simd``: both take the
    AVX2 splat, gather, jets and hit adjoint where the CPU has them.
    """

    def __init__(self, scene: Scene, emitter: LightEmitter, filter_px: float,
                 max_pixel_radius: float, fresnel: bool, simd: bool, kernels: str = "c") -> None:
        self.scene = scene
        self.simd = bool(simd) and SIMD_AVAILABLE  # whether the kernels use the AVX2 extension
        # Whether the C kernels trace (else the numba kernels).
        self.compiled = trace_compiled.AVAILABLE and kernels == "c"
        self.emitter = emitter
        self.shifts = np.ascontiguousarray(emitter.shifts.numpy(), dtype=np.float64)
        self.indices = np.asarray(scene.indices, dtype=np.float64)
        self.capacity = (2 * math.ceil(max_pixel_radius) + 3) ** 2
        # Footprints' major semi-axes are capped at max_pixel_radius, so are their boxes' half extents.
        self.gather_pad = gather_padding(max_pixel_radius)
        self._padded: np.ndarray | None = None  # the adjoint image buffer that pad_gradient fills
        self._heights: tuple[np.ndarray, dict[str, Any]] | None = None  # the last heights' constants
        light, sub, rec = scene.light, scene.substrate, scene.receiver
        self._constants = dict(
            light_x=float(light.position[0]), light_y=float(light.position[1]), light_z=float(light.position[2]),
            half=float(sub.half_width), base=float(sub.thickness), per_channel=int(emitter.per_channel),
            flux_scale=light.power / (4.0 * math.pi * scene.channels) * emitter.cell_area
            * (light.position[2] - sub.thickness), aim_half=float(emitter.aim_half),
            radius=float(emitter.footprint_radius), receiver_z=float(rec.z), receiver_half=float(rec.half_width),
            to_px=rec.resolution / (2.0 * rec.half_width), min_px=float(filter_px),
            max_px=float(max_pixel_radius), fresnel=bool(fresnel), simd=self.simd,
            clear_walls=sub.walls == "clear")

    def constants(self, d: np.ndarray, start: int = 0) -> FusedScene:
        """Kernel constants for heights ``d`` (m, m) (the bracketing planes and slope bounds depend
        on them) and the photons from ``start`` on (their emission point: the light's position)."""
        x, y, _ = self.emitter.origin(self.emitter.source_of(start))
        return FusedScene(**self._height_constants(d), **{**self._constants, "light_x": x, "light_y": y})

    def _height_constants(self, d: np.ndarray) -> dict[str, Any]:
        """The grid spacing, bracketing planes and slope bounds of heights ``d`` (m, m), kept for
        the last heights seen: the chunks of one render (an extended light's segments among them)
        read the same heights."""
        cached = self._heights
        if cached is not None and cached[0].shape == d.shape and np.array_equal(cached[0], d):
            return cached[1]
        grid = HeightFieldGrid(self.scene.substrate.thickness, self.scene.substrate.half_width, d.shape[0])
        zlo, zstart, zhi = grid.z_planes(d)
        slope_x, slope_y = grid.slope_bounds(d)
        values = {"spacing": grid.spacing, "zlo": zlo, "zstart": zstart, "zhi": zhi, "slope_x": slope_x,
                  "slope_y": slope_y}
        self._heights = (d.copy(), values)
        return values

    def image_buffers(self, dtype: np.dtype) -> np.ndarray:
        """Zeroed per-thread images (threads, c, n, n) for :meth:`render`."""
        n = self.scene.receiver.resolution
        return np.zeros((nb.get_num_threads(), self.scene.channels, n, n), dtype=dtype)

    def render(self, d: np.ndarray, start: int, stop: int, out: np.ndarray, splat: bool = True,
               hit_t: np.ndarray | None = None, replay: bool = False) -> float:
        """Add the flux per pixel of photons start .. stop-1 to ``out`` (threads, c, n, n) for
        float64 heights ``d`` (m, m); returns the flux that reached the receiver (W). ``hit_t``
        (stop - start,) float64, if given, receives the hits' ray parameters for :meth:`vjp`; with
        ``replay`` it holds them (for these heights and this light) and they are not searched."""
        _check_contiguous(d=d, out=out)
        if replay and hit_t is None:
            raise ValueError("replay needs the recorded hits (hit_t)")
        arguments = (d, self.constants(d, start), self.shifts, self.indices, start, stop, out, self.capacity, splat,
                     NO_HITS if hit_t is None else hit_t, replay)
        if self.compiled:
            return trace_compiled.render(*arguments)
        with nb.parallel_chunksize(1):
            return render_photons(*arguments)

    def pad_gradient(self, grad_image: np.ndarray, divisor: float = 1.0) -> np.ndarray:
        """The adjoint image G / divisor (c, n, n) as :meth:`vjp` takes it: float64 with a zero
        border wide enough for every footprint (pad it once per gradient, not per chunk). The
        buffer is this object's and the next call overwrites it."""
        self._padded = pad_for_gather(grad_image, self.gather_pad, divisor, reuse=self._padded)
        return self._padded

    def vjp(self, d: np.ndarray, start: int, stop: int, padded: np.ndarray, out: np.ndarray,
            hit_t: np.ndarray | None = None) -> None:
        """Add to ``out`` (threads, m, m) the gradient w.r.t. d of <flux per pixel of photons
        start .. stop-1, G>, ``padded`` = :meth:`pad_gradient` (G). ``hit_t``: the hits that
        :meth:`render` recorded for these photons and these heights, replayed instead of searched."""
        _check_contiguous(d=d, padded=padded, out=out)
        arguments = (d, self.constants(d, start), self.shifts, self.indices, start, stop, padded, self.gather_pad,
                     out, NO_HITS if hit_t is None else hit_t)
        if self.compiled:
            trace_compiled.vjp(*arguments)
            return
        with nb.parallel_chunksize(1):
            vjp_photons(*arguments)


    def jvp(self, d: np.ndarray, v: np.ndarray, start: int, stop: int, out: np.ndarray) -> None:
        """Add to ``out`` (threads, c, n, n) the change of the flux per pixel of photons start ..
        stop-1 when the float64 heights ``d`` (m, m) move along ``v`` (m, m): J v, by the numba
        kernels (:mod:`operators.heightfield.tangent_native`; the C kernels have no forward pass)."""
        _check_contiguous(d=d, v=v, out=out)
        if v.shape != d.shape or v.dtype != np.float64:
            raise ValueError(f"the direction has shape {v.shape} and dtype {v.dtype}; it must be float64 like the "
                             f"heights {d.shape}")
        with nb.parallel_chunksize(1):
            jvp_photons(d, v, self.constants(d, start), self.shifts, self.indices, start, stop, out, self.capacity)


def _check_contiguous(**arrays: np.ndarray) -> None:
    """The kernels (the AVX2 ones address rows by pointer) take C-contiguous arrays only."""
    for name, array in arrays.items():
        if not array.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous array (np.ascontiguousarray)")


class HitCache:
    """The hits' ray parameters of the last render, chunk by chunk, so that a gradient of the same
    heights replays them instead of searching again (the hit search is about a third of a trace).

    8 bytes per photon, for the chunks that fit in ``budget_mb`` (the rest are searched again), so
    the memory stays bounded whatever the photon count. Arrays are kept and reused across renders.
    Operators whose photons meet the print alike (the same light, substrate, photon pattern and
    chunks: the shots of a stack at several screen distances, operators/stack.py) may share one
    cache; a render then replays the hits another of them recorded for the same heights.
    """

    def __init__(self, budget_mb: float) -> None:
        self.budget = int(budget_mb * 2 ** 20) // 8  # photons
        self.slots: dict[tuple[int, int], np.ndarray] = {}
        self.heights: np.ndarray | None = None  # the heights the slots hold hits for; None: none valid
        self.recorded_by: object | None = None  # the operator whose render recorded them

    def start_render(self, recorder: object | None = None) -> None:
        """Forget the hits held: a render (of ``recorder``) is about to record new ones."""
        self.heights = None
        self.recorded_by = recorder

    def replayable(self, d: np.ndarray, renderer: object) -> bool:
        """Whether a render of ``renderer`` at heights ``d`` can replay the hits held: another
        operator sharing the cache recorded them for the same heights (an operator's own repeated
        render searches again, so that it costs what a render costs)."""
        return self.recorded_by is not renderer and self.heights is not None and np.array_equal(self.heights, d)

    def slot(self, start: int, stop: int) -> np.ndarray | None:
        """The array that records chunk start .. stop-1 of the render under way, or None if it
        would not fit in the budget."""
        key = (start, stop)
        if key not in self.slots:
            if sum(a.shape[0] for a in self.slots.values()) + stop - start > self.budget:
                return None
            self.slots[key] = np.empty(stop - start)
        return self.slots[key]

    def finish_render(self, d: np.ndarray) -> None:
        """The render under way, of heights ``d``, completed: its hits are valid for them."""
        self.heights = d.copy()

    def hits(self, d: np.ndarray, start: int, stop: int) -> np.ndarray | None:
        """The recorded hits of chunk start .. stop-1 if the last completed render had heights ``d``."""
        if self.heights is None or not np.array_equal(self.heights, d):
            return None
        return self.slots.get((start, stop))
