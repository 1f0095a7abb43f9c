"""sfc-bench's scale section (experiments/benchmarks/bench.py, ``--only scale``): how one iteration's cost,
the time to the noise level and the process's peak memory grow with the grid and the number of
photos.

An iteration of every solver is a render and a gradient at its image (the data term's two
passes). At m = n = 128, 256, 512 (print_lines sampled at m, an n x n receiver) each traces the
photons the photon budget's cap gives that receiver (``per_pixel`` photons a pixel,
framework/reconstruction/photon_budget.py); a stack of 1, 2, 3 photos (screens 0.05, 0.1, 0.2
below the substrate, operators/stack.py) at the middle size. Every case runs in a fresh process,
so that its peak resident memory is its own. The time to the noise level is a whole
``sfc-reconstruct`` run of a built-in scene sampled at m = n (its reference caustic at 2m,
experiments/benchmarks/bench_reconstruction.py), also each in a fresh process: its seconds of solving, its
photon-traces and whether it met Morozov's rule. The growth exponents are fitted by least squares
in log-log: seconds ~ (m^2)^p over the sizes, ~ shots^q over the stacks.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import tempfile
import time
from pathlib import Path
from typing import Any
from collections.abc import Callable, Sequence

import numpy as np
import torch

from experiments.benchmarks.bench_reconstruction import run_once
from experiments.benchmarks.timing import peak_rss_mb
from framework.scene.printed_shapes import make_shape
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene
from operators.stack import StackOperator

__all__ = ["SCREENS", "growth_exponent", "noise_level_report", "scale_report"]

SCREENS = (0.05, 0.1, 0.2)  # the photos' screen distances below the substrate (scene units)


def _operator(n: int, photons: int, distance: float, footprint_px: float, chunk_size: int) -> CausticOperator:
    scene = Scene(receiver=Receiver(resolution=n, z=-distance))
    return CausticOperator(scene, OperatorSettings(photons=photons, footprint_px=footprint_px, chunk_size=chunk_size))


def _iteration_worker(m: int, shots: int, photons: int, footprint_px: float, chunk_size: int, repeats: int,
                      queue: Any) -> None:
    """Best seconds of ``repeats`` iterations (render, then the gradient at its image) and the peak
    resident memory (MiB) of this process."""
    heights = torch.from_numpy(make_shape("print_lines", m)).double()
    ops = [_operator(m, photons, SCREENS[i], footprint_px, chunk_size) for i in range(shots)]
    op = ops[0] if shots == 1 else StackOperator(ops)
    target = op.render(torch.zeros_like(heights))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        op.loss_and_grad(heights, target, image=op.render(heights))
        best = min(best, time.perf_counter() - t0)
    queue.put({"seconds": best, "peak_rss_mb": peak_rss_mb()})


def _solve_worker(overrides: list[str], workdir: str, name: str, queue: Any) -> None:
    """One reconstruction's figures (experiments/benchmarks/bench_reconstruction.py, ``run_once``) and the
    peak resident memory (MiB) of this process."""
    queue.put({**run_once(overrides, Path(workdir), name), "peak_rss_mb": peak_rss_mb()})


def _in_fresh_process(*args: Any, target: Callable[..., None] = _iteration_worker) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def growth_exponent(sizes: list[float], seconds: list[float]) -> float:
    """The least-squares slope of log(seconds) against log(sizes)."""
    return float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0])


def scale_report(sizes: tuple[int, ...] = (128, 256, 512), per_pixel: float = 64.0, footprint_px: float = 3.0,
                 chunk_size: int = 1 << 18, repeats: int = 2) -> dict[str, Any]:
    """Seconds per iteration and peak memory at m = n in ``sizes`` (``per_pixel`` photons a receiver
    pixel) and for stacks of 1 to 3 photos at the middle size; the fitted growth exponents."""
    grid = {}
    for m in sizes:
        photons = int(per_pixel * m * m)
        grid[str(m)] = {"photons": photons, **_in_fresh_process(m, 1, photons, footprint_px, chunk_size, repeats)}
    middle = sizes[len(sizes) // 2]
    photons = int(per_pixel * middle * middle)
    # One photo at the middle size is that size's own iteration, measured above.
    stacks = {"1": {key: value for key, value in grid[str(middle)].items() if key != "photons"}}
    stacks.update({str(k): _in_fresh_process(middle, k, photons, footprint_px, chunk_size, repeats)
                   for k in range(2, len(SCREENS) + 1)})
    samples = [float(m * m) for m in sizes]
    return {
        "per_pixel": per_pixel, "scene": "print_lines, m = n, light (0, 0, 10), screen 0.05",
        "grid": grid,
        "seconds_exponent_in_samples": growth_exponent(samples, [grid[str(m)]["seconds"] for m in sizes]),
        "memory_exponent_in_samples": growth_exponent(samples, [grid[str(m)]["peak_rss_mb"] for m in sizes]),
        "stack_m": middle, "stack_photons_per_shot": photons, "stacks": stacks,
        "seconds_exponent_in_shots": growth_exponent([1.0, 2.0, 3.0], [stacks[k]["seconds"] for k in ("1", "2", "3")]),
    }


def noise_level_report(sizes: Sequence[int] = (128, 256, 512), scene: str = "print_lines",
                       overrides: Sequence[str] = (), beside: Sequence[str] | None = None) -> dict[str, Any]:
    """``sfc-reconstruct scene=<scene>`` sampled at m = n in ``sizes`` (reference caustic at 2m),
    each in a fresh process, with ``overrides`` on top: iterations, seconds of solving
    (``run_time_s``), photon-traces, whether it met Morozov's rule, peak memory; each size's
    iterations over the smallest size's; the growth exponents of the seconds and photon-traces in
    m^2 (with two sizes or more). With ``beside`` (more overrides, e.g. another solver), that
    configuration runs too, right after the first at each size, under ``"beside"``, with the ratios
    beside / first per size."""
    configurations = {"runs": list(overrides)}
    if beside is not None:
        configurations["beside"] = [*overrides, *beside]
    runs: dict[str, dict[str, dict[str, Any]]] = {key: {} for key in configurations}
    with tempfile.TemporaryDirectory() as tmp:
        for m in sizes:
            grid = [f"scene={scene}", f"receiver.resolution={m}", f"height_field.resolution={m}",
                    f"data.reference_resolution={2 * m}"]
            for key, extra in configurations.items():
                runs[key][str(m)] = _in_fresh_process([*grid, *extra], tmp, f"{key}{m}", target=_solve_worker)
    report: dict[str, Any] = {"scene": scene, "overrides": list(overrides), **_growth(runs["runs"], sizes)}
    if beside is not None:
        report["beside"] = {"overrides": list(beside), **_growth(runs["beside"], sizes)}
        report["beside_over_runs"] = {
            str(m): {key: runs["beside"][str(m)][key] / runs["runs"][str(m)][key]
                     for key in ("iterations", "run_time_s", "photon_traces")} for m in sizes}
    return report


def _growth(runs: dict[str, dict[str, Any]], sizes: Sequence[int]) -> dict[str, Any]:
    """``runs`` (by m), each size's iterations over the smallest's, and the growth exponents of the
    seconds and photon-traces in m^2 (with two sizes or more)."""
    smallest = runs[str(min(sizes))]["iterations"]
    out: dict[str, Any] = {"runs": runs,
                           "iterations_over_smallest": {str(m): runs[str(m)]["iterations"] / smallest for m in sizes}}
    if len(sizes) >= 2:
        samples = [float(m * m) for m in sizes]
        for key in ("run_time_s", "photon_traces"):
            out[f"{key}_exponent_in_samples"] = growth_exponent(samples, [runs[str(m)][key] for m in sizes])
    return out
