"""Per-stage cost of the fused numba photon kernels, for ``sfc-bench``'s ``stage_profile`` (the C
kernels of operators/kernels/heightfield_photons.c run the same stages in the same order).

One thread runs the kernels' own functions (:mod:`operators.heightfield.kernels_native`) cut after each
stage: emission; emission + hit search (in lockstep over packets); + the surface jet at the hit
(as in the kernels); then the kernels' own loop (:func:`operators.heightfield.kernels_native.render_range`)
without the splat (adds the optics with differentials and the footprint, vectorised across each
packet of photons) and with it. Each stage's cost is the difference of consecutive cuts, in
nanoseconds per photon (differences of best-of-three timings: a few tens of ns of noise). For the
gradient: :func:`operators.heightfield.adjoint_native.vjp_range` (trace again, splat-adjoint gather,
reverse-mode optics, 4 x 4 height patch and its scatter), once searching the hits again and once
replaying the hits that the forward pass recorded (what ``loss_and_grad`` does). Beside them:
the cost of one evaluation of the surface and its gradient (the hit search's inner step) in a loop
of independent evaluations, i.e. its throughput, not its latency.
"""

from __future__ import annotations

import time

import numba as nb
import numpy as np

from operators.heightfield.adjoint_native import vjp_range
from operators.heightfield.intersect_native import packet_gaps, solve_hits
from operators.heightfield.kernels_native import PACKET, emit, packet_jets, render_range
from operators.heightfield.trace_native import NO_HITS
from operators.kernels.numba_settings import FAST_MATH

# Cuts of the forward photon path, in order; each includes the ones before.
FORWARD_CUTS = ("emission", "hit_search", "surface_jet", "optics_and_footprint", "splat")


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _hit_cut(d, sc, shifts, count, cut) -> float:
    """Photons 0 .. count-1 emitted (cut 0), and, packet by packet as in the kernels, their hits
    searched in lockstep (1) and the surface jets there taken (2); returns a checksum that keeps
    the compiler from dropping the work."""
    dirs = np.empty((3, PACKET))
    t = np.zeros(PACKET)
    search = np.empty((5, PACKET))
    jets = np.zeros((5, PACKET))
    acc = 0.0
    for first in range(0, count, PACKET):
        size = min(PACKET, count - first)
        for k in range(size):
            _, w, _, _, flux = emit(first + k, sc, shifts)
            dirs[0, k], dirs[1, k], dirs[2, k] = w
            acc += w[0] + flux
        if cut >= 1:
            solve_hits(d, sc.base, sc.light_x, sc.light_y, sc.light_z, dirs, size, -sc.half, sc.spacing, sc.zlo,
                       sc.zstart, sc.zhi, sc.slope_x, sc.slope_y, t, search)
        if cut == 2:
            packet_jets(d, sc, dirs, t, size, jets)
        for k in range(size):
            acc += t[k] + jets[0, k] + jets[4, k]
    return acc


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _surface_evaluations(d, sc, shifts, count) -> float:
    """Gap and slope (S, S_x, S_y) of each photon's ray at the plane of the substrate top, as one
    round of the lockstep hit search takes them (independent evaluations, a packet at a time)."""
    dirs = np.empty((3, PACKET))
    search = np.ones((5, PACKET))
    t = np.empty(PACKET)
    acc = 0.0
    for first in range(0, count, PACKET):
        size = min(PACKET, count - first)
        for k in range(size):
            _, w, _, _, _ = emit(first + k, sc, shifts)
            dirs[0, k], dirs[1, k], dirs[2, k] = w
            t[k] = (sc.base - sc.light_z) / w[2]
        packet_gaps(d, sc.base, sc.light_x, sc.light_y, sc.light_z, dirs, size, -sc.half, sc.spacing, t, search)
        for k in range(size):
            acc += search[3, k] + search[4, k]
    return acc


def _best_ns(run, count: int, repeats: int) -> float:
    """Shortest of ``repeats`` runs, in nanoseconds per photon."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t0)
    return best / count * 1e9


def stage_profile(fused, d: np.ndarray, grad_image: np.ndarray, count: int, repeats: int = 3
                  ) -> dict[str, float]:
    """Nanoseconds per photon of each stage on one thread (see the module docstring).

    ``fused`` is the operator's :class:`operators.heightfield.trace_native.FusedTracer`, ``d`` (m, m) float64
    heights, ``grad_image`` (c, n, n) an adjoint image for the gradient stages.
    """
    sc = fused.constants(d)
    img = fused.image_buffers(np.dtype(np.float32))[0]
    padded = fused.pad_gradient(grad_image)
    grad = np.zeros_like(d)
    args = (d, sc, fused.shifts, fused.indices)
    warm = min(count, 1000)  # photons of the compile / warm-up calls
    cuts = [lambda n, cut=cut: _hit_cut(d, sc, fused.shifts, n, cut) for cut in range(3)]
    cuts += [lambda n, splat=splat: render_range(*args, 0, n, img, fused.capacity, splat, NO_HITS, 0)
             for splat in (False, True)]
    cumulative = []
    for run in cuts:
        run(warm)  # compile / warm up
        cumulative.append(_best_ns(lambda: run(count), count, repeats))
    report = {name: cumulative[k] - (cumulative[k - 1] if k else 0.0) for k, name in enumerate(FORWARD_CUTS)}
    report["forward_total"] = cumulative[-1]
    hit_t = np.empty(count)
    render_range(*args, 0, count, img, fused.capacity, True, hit_t, 0)  # record the hits
    for name, hits in (("adjoint_searching_hits", NO_HITS), ("adjoint_replaying_hits", hit_t)):
        vjp_range(*args, 0, warm, padded, fused.gather_pad, grad, hits, 0)
        report[name] = _best_ns(lambda: vjp_range(*args, 0, count, padded, fused.gather_pad, grad, hits, 0),
                                count, repeats)
    report["forward_backward_total"] = cumulative[-1] + report["adjoint_replaying_hits"]
    _surface_evaluations(d, sc, fused.shifts, warm)
    report["one_surface_evaluation"] = _best_ns(lambda: _surface_evaluations(d, sc, fused.shifts, count), count,
                                                repeats) - report["emission"]
    return {f"{name}_ns": value for name, value in report.items()}
