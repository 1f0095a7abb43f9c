"""sfc-bench: speed and memory of the caustic operator, printed as JSON.

Measures, at the default scene (print_lines, 128 x 128 heights, 512 x 512 receiver):
forward and forward+backward photons/s of the operator (the fused native path), the same for the
torch reference path in the same process (side by side: timings on a shared machine are noisy),
the same with the numba kernels in place of the C kernels compiled at install
(``operator.kernels: numba``) and without the AVX2 splat / gather / jet kernels (``operator.simd:
false``), alternating with them, the time split between tracing and splatting in the fused kernel (a pass
with the splat switched off against the full pass), the Jacobian-vector product beside a render and a
gradient pass, the peak memory of a gradient evaluation
with the paper's 8.4 million photons, and the native splat against the straightforward PyTorch
splat on the same photons, side by side, each in a fresh process so that their peak memories are
comparable; the mesh-scene operator (plain scene, two lenses) beside the height-field operator (a
solver's iteration: a render, then the gradient from its image; experiments/benchmarks/bench_mesh.py); with
``--device cuda`` the operator on the GPU beside the CPU (experiments/benchmarks/bench_cuda.py);
a stack of two screens with its shots sharing the hit search and without (operators/stack.py);
the fidelity of each irradiance model against the exact caustic (experiments/benchmarks/bench_fidelity.py);
how an iteration's time, the time to the noise level and the peak memory grow with m = n and the
number of photos (experiments/benchmarks/bench_scale.py);
and the default reconstruction with today's solver beside the earlier one
(experiments/benchmarks/bench_reconstruction.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import tempfile
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch

from experiments.benchmarks.bench_cuda import cuda_report
from experiments.benchmarks.bench_fidelity import fidelity_report, wall_fidelity
from experiments.benchmarks.bench_mesh import mesh_footprint, time_mesh_scenes
from experiments.benchmarks.bench_reconstruction import reconstruction_report
from experiments.benchmarks.bench_scale import noise_level_report, scale_report
from experiments.benchmarks.bench_stages import stage_profile
from experiments.benchmarks.timing import best_seconds, peak_rss_mb
from framework.scene.printed_shapes import make_shape
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Scene
from operators.splat.reference import splat_photons_reference
from operators.splat.splat import splat_photons
from operators.stack import StackOperator

# Throughput the CPU path is held to on a 2-core machine (docs/performance.md): photons/s.
TARGET_FORWARD = 5e6
TARGET_FORWARD_BACKWARD = 2e6


def make_operator(photons: int, footprint_px: float, chunk_size: int, simd: bool = True,
                  pixel_integration: bool = True, kernels: str = "c") -> CausticOperator:
    return CausticOperator(Scene(), OperatorSettings(photons=photons, footprint_px=footprint_px,
                                                     chunk_size=chunk_size, simd=simd,
                                                     pixel_integration=pixel_integration, kernels=kernels))


def heights_print_lines() -> torch.Tensor:
    return torch.from_numpy(make_shape("print_lines", 128)).float()


def time_side_by_side(ops: tuple[CausticOperator, ...], heights: torch.Tensor, target: torch.Tensor,
                      rounds: int = 2) -> list[tuple[float, float]]:
    """(forward s, forward + backward s) of each operator: the best of ``rounds`` rounds that run
    them in turn, so that all see the same background load (after one warm-up call each)."""
    best = [[math.inf, math.inf] for _ in ops]
    for op in ops:
        op.loss_and_grad(heights, target)  # warm up: numba compilation
    for _ in range(rounds):
        for k, op in enumerate(ops):
            best[k][0] = min(best[k][0], best_seconds(lambda: op.render(heights), repeats=1))
            best[k][1] = min(best[k][1], best_seconds(lambda: op.loss_and_grad(heights, target), repeats=1))
    return [(forward, gradient) for forward, gradient in best]


def time_split(op: CausticOperator, heights: torch.Tensor, repeats: int = 5) -> dict[str, float]:
    """Seconds of one forward pass of the fused kernel with the splat switched off (emission,
    hit, optics, footprint) and the rest of the full pass (splat): the best of ``repeats``
    alternating runs of each, so that both see the same background load."""
    d = heights.double().numpy()
    out = op.fused.image_buffers(np.dtype(op.settings.dtype))

    def passes(splat: bool) -> None:
        for start, stop in op.chunks():
            op.fused.render(d, start, stop, out, splat)

    trace_s = full_s = math.inf
    for _ in range(repeats):
        trace_s = min(trace_s, best_seconds(lambda: passes(False), repeats=1))
        full_s = min(full_s, best_seconds(lambda: passes(True), repeats=1))
    return {"trace_s": trace_s, "splat_s": full_s - trace_s, "trace_fraction": trace_s / full_s}


def time_jvp(op: CausticOperator, heights: torch.Tensor, repeats: int = 3) -> dict[str, float]:
    """Seconds of the Jacobian-vector product J v (operators/heightfield/tangent_native.py) along the
    heights' shift by three rows, beside a render and a gradient pass of the same operator: the
    best of ``repeats`` alternating runs of each (after a warm-up, numba's compile)."""
    direction = torch.roll(heights, 3, 0) - heights
    grad_image = torch.ones(op.output_shape, dtype=op.dtype)
    op.jvp(heights, direction)
    jvp_s = render_s = vjp_s = math.inf
    for _ in range(repeats):
        render_s = min(render_s, best_seconds(lambda: op.render(heights), repeats=1))
        vjp_s = min(vjp_s, best_seconds(lambda: op.vjp(heights, grad_image), repeats=1))
        jvp_s = min(jvp_s, best_seconds(lambda: op.jvp(heights, direction), repeats=1))
    return {"seconds": jvp_s, "over_render": jvp_s / render_s, "over_gradient_pass": jvp_s / vjp_s}


def time_reference(heights: torch.Tensor, target: torch.Tensor, photons: int, footprint_px: float,
                   chunk_size: int) -> dict[str, float]:
    """Forward and forward+backward photons/s of the torch reference path (torch trace, native
    splat, torch autograd), the operator's implementation before the fused kernels."""
    op = make_operator(photons, footprint_px, chunk_size)
    op.vjp_reference(heights, op.render_reference(heights) - target)  # warm up
    t0 = time.perf_counter()
    image = op.render_reference(heights)
    forward_s = time.perf_counter() - t0
    op.vjp_reference(heights, image - target)
    gradient_s = time.perf_counter() - t0
    return {"photons": op.photons, "forward_photons_per_s": op.photons / forward_s,
            "forward_backward_photons_per_s": op.photons / gradient_s}


def _splat_worker(path: str, which: str, queue: mp.Queue) -> None:
    data = torch.load(path)
    splat = splat_photons if which == "native" else splat_photons_reference
    args = (data["pos"], data["metric"], data["flux"], data["channel"], 1, data["resolution"])
    splat(*[a[:, :1000] if a.dim() == 2 else a[:1000] for a in args[:4]], 1, args[5])  # compile / warm up
    base = peak_rss_mb()
    t0 = time.perf_counter()
    image = splat(*args)
    seconds = time.perf_counter() - t0
    queue.put({"seconds": seconds, "peak_extra_mb": peak_rss_mb() - base, "sum": float(image.sum())})


def compare_splats(op: CausticOperator, heights: torch.Tensor, photons: int) -> dict[str, float]:
    """Native vs straightforward PyTorch splat of the same traced photons, each in its own process."""
    with torch.no_grad():
        pos, metric, flux, channel = op.splat_inputs(heights, 0, photons)
    data = {"pos": pos, "metric": metric, "flux": flux, "channel": channel,
            "resolution": op.scene.receiver.resolution}
    results = {}
    ctx = mp.get_context("spawn")
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "photons.pt")
        torch.save(data, path)
        for which in ("native", "torch_reference"):
            queue = ctx.Queue()
            proc = ctx.Process(target=_splat_worker, args=(path, which, queue))
            proc.start()
            results[which] = queue.get()
            proc.join()
    native, ref = results["native"], results["torch_reference"]
    return {"photons": photons, "native_s": native["seconds"], "torch_s": ref["seconds"],
            "speedup": ref["seconds"] / native["seconds"],
            "native_peak_extra_mb": native["peak_extra_mb"], "torch_peak_extra_mb": ref["peak_extra_mb"],
            # The native splat's extra memory (one image per thread) is below the resolution of the
            # process high-water mark; 1 MiB as its floor makes this ratio a lower bound.
            "memory_ratio_lower_bound": ref["peak_extra_mb"] / max(native["peak_extra_mb"], 1.0),
            "relative_image_difference": abs(native["sum"] - ref["sum"]) / abs(ref["sum"])}


def time_stack(heights: torch.Tensor, photons: int, footprint_px: float, chunk_size: int,
               rounds: int = 3) -> dict[str, float]:
    """A stack of two shots (screens 0.05 and 0.2 below the substrate, operators/stack.py) with the
    second shot replaying the first one's hit search and without, side by side: the best of
    ``rounds`` alternating rounds of a render and of a render plus its gradient (one iteration's
    passes), and the one shot's alone for scale."""
    def shot(distance: float) -> CausticOperator:
        scene = Scene(receiver=dataclasses.replace(Scene().receiver, z=-distance))
        return CausticOperator(scene, OperatorSettings(photons=photons, footprint_px=footprint_px,
                                                       chunk_size=chunk_size))

    stacks = {"shared": StackOperator([shot(0.05), shot(0.2)]),
              "separate": StackOperator([shot(0.05), shot(0.2)], share_hits=False), "one_shot": shot(0.05)}
    targets = {name: op.render(torch.zeros_like(heights)) for name, op in stacks.items()}
    best = {name: [math.inf, math.inf] for name in stacks}

    def iteration(op, target) -> None:
        op.loss_and_grad(heights, target, image=op.render(heights))

    for _ in range(rounds):
        for name, op in stacks.items():
            best[name][0] = min(best[name][0], best_seconds(lambda: op.render(heights), repeats=1))
            best[name][1] = min(best[name][1], best_seconds(lambda: iteration(op, targets[name]), repeats=1))
    return {"photons_per_shot": photons, **{f"{name}_render_s": b[0] for name, b in best.items()},
            **{f"{name}_render_and_gradient_s": b[1] for name, b in best.items()},
            "render_speedup_shared": best["separate"][0] / best["shared"][0],
            "iteration_speedup_shared": best["separate"][1] / best["shared"][1]}


def profile_stages(op: CausticOperator, heights: torch.Tensor, target: torch.Tensor, photons: int
                   ) -> dict[str, object]:
    """The one-thread stage profile (experiments.benchmarks.bench_stages) with the per-photon time budget
    that the throughput targets leave each thread."""
    threads = numba.get_num_threads()
    residual = (op.render(heights) - target).double().numpy()
    return {
        "threads": 1, "photons": photons,
        **stage_profile(op.fused, heights.double().numpy(), residual, photons),
        # What one thread may spend per photon for the targets with all threads busy.
        "budget_at_targets_ns": {"forward": threads / TARGET_FORWARD * 1e9,
                                 "forward_backward": threads / TARGET_FORWARD_BACKWARD * 1e9},
    }


def scale_section(args: argparse.Namespace) -> dict[str, Any]:
    """The scale section: an iteration at each of ``--scale-sizes`` and the stacks, and the
    reconstructions to the noise level at each of ``--scale-solve-sizes`` (either may be empty)."""
    section: dict[str, Any] = {}
    if args.scale_sizes:
        section.update(scale_report(tuple(args.scale_sizes), args.scale_per_pixel, args.footprint_px, args.chunk_size))
    if args.scale_solve_sizes:
        section["to_noise_level"] = noise_level_report(tuple(args.scale_solve_sizes), args.scale_solve_scene,
                                                       args.scale_solve_overrides, args.scale_solve_beside)
    return section


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=1 << 22, help="photons for the speed runs")
    parser.add_argument("--grad-photons", type=int, default=128 * 128 * 32 * 16,
                        help="photons of the peak-memory gradient run (paper: 8388608)")
    parser.add_argument("--splat-photons", type=int, default=1 << 20, help="photons of the splat comparison")
    parser.add_argument("--reference-photons", type=int, default=1 << 20,
                        help="photons for the speed of the torch reference path")
    parser.add_argument("--stage-photons", type=int, default=1 << 20,
                        help="photons of the one-thread per-stage profile (0: leave it out)")
    parser.add_argument("--mesh-photons", type=int, default=1 << 18,
                        help="photons of the mesh-scene comparison (0: leave it out)")
    parser.add_argument("--mesh-footprint", default=None,
                        help="footprint of every operator in the mesh-scene comparison: pixels, or 'cell' (the "
                             "configs' default: each photon's own emission cell); default: --footprint-px")
    parser.add_argument("--mesh-supersample", type=int, default=1,
                        help="receiver supersampling of every operator in the mesh-scene comparison (the "
                             "configs' default: 4; 1 weighs the tracing, 4 the splat on the finer receiver)")
    parser.add_argument("--stack-photons", type=int, default=1 << 20,
                        help="photons per shot of the two-screen stack's timing (0: skip)")
    parser.add_argument("--reconstruction-rounds", type=int, default=1,
                        help="default reconstructions with today's and the earlier solver, each (0: leave them out)")
    parser.add_argument("--reconstruction-overrides", nargs="*", default=[],
                        help="Hydra overrides for both reconstructions, e.g. experiment=m3v1")
    parser.add_argument("--fidelity-photons", type=int, default=1 << 20,
                        help="photons of the fidelity section's budget renders (0: leave the section out)")
    parser.add_argument("--fidelity-bias-photons", type=int, default=1 << 24,
                        help="photons of the fidelity section's renders that measure the bias")
    parser.add_argument("--fidelity-reference-photons", type=int, default=1 << 25,
                        help="photons of the exact reference through the two lenses")
    parser.add_argument("--fidelity-resolutions", type=int, nargs="*", default=[128, 256],
                        help="receiver pixels per side of the fidelity section's renders")
    parser.add_argument("--wavefront-vertices", type=int, default=4097,
                        help="aim points per side of the height field's exact (wavefront-triangle) reference")
    parser.add_argument("--wall-vertices", type=int, default=2049,
                        help="aim points per side of the walls' exact references (fidelity section, ten renders at "
                             "the first of --fidelity-resolutions)")
    parser.add_argument("--scale-sizes", type=int, nargs="*", default=[128, 256, 512],
                        help="m = n of the scale section's iteration timings (none: skip them)")
    parser.add_argument("--scale-per-pixel", type=float, default=64.0,
                        help="photons per receiver pixel of the scale section (the photon budget's default cap)")
    parser.add_argument("--scale-solve-sizes", type=int, nargs="*", default=[128, 256, 512],
                        help="m = n of the scale section's reconstructions to the noise level (none: skip them)")
    parser.add_argument("--scale-solve-scene", default="print_lines",
                        help="built-in scene of the scale section's reconstructions")
    parser.add_argument("--scale-solve-overrides", nargs="*", default=[],
                        help="extra sfc-reconstruct overrides for the scale section's reconstructions")
    parser.add_argument("--scale-solve-beside", nargs="*", default=None,
                        help="overrides of a second configuration run beside the first at each size, with the "
                             "ratios, e.g. solver=gauss_newton stopping.stagnation.refine_share=0.25")
    parser.add_argument("--only", choices=("fidelity", "walls", "mesh_scene", "scale"), default=None,
                        help="print only that section (walls: the fidelity section's walls entry; mesh_scene: at "
                             "--mesh-photons, e.g. 262144 and 1048576)")
    parser.add_argument("--footprint-px", type=float, default=3.0)
    parser.add_argument("--chunk-size", type=int, default=1 << 18)
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cuda: measure the CUDA kernels (beside this machine's CPU path) instead")
    args = parser.parse_args(argv)
    mesh_fp = args.footprint_px if args.mesh_footprint is None else mesh_footprint(args.mesh_footprint)
    if mesh_fp is None:
        parser.error(f"--mesh-footprint={args.mesh_footprint!r} must be 'cell' or a number of pixels > 0")

    heights = heights_print_lines()
    if args.only == "fidelity":
        print(json.dumps({"fidelity": fidelity_report(
            args.fidelity_photons, args.fidelity_bias_photons, args.fidelity_reference_photons,
            args.wavefront_vertices, tuple(args.fidelity_resolutions))}, indent=2))
        return
    if args.only == "walls":
        print(json.dumps({"walls": wall_fidelity(args.fidelity_photons, args.wall_vertices,
                                                 args.fidelity_resolutions[0])}, indent=2))
        return
    if args.only == "mesh_scene":
        print(json.dumps({"mesh_scene": time_mesh_scenes(heights, args.mesh_photons, mesh_fp, args.mesh_supersample)},
                         indent=2))
        return
    if args.only == "scale":
        print(json.dumps({"scale": scale_section(args)}, indent=2))
        return
    if args.device == "cuda":
        if not torch.cuda.is_available():
            parser.error("--device cuda needs a CUDA GPU; none is visible (torch.cuda.is_available() is False)")
        print(json.dumps(cuda_report(heights, args.photons, args.grad_photons, args.footprint_px, args.chunk_size),
                         indent=2))
        return
    op = make_operator(args.photons, args.footprint_px, args.chunk_size)
    jit = make_operator(args.photons, args.footprint_px, args.chunk_size, kernels="numba")
    plain = make_operator(args.photons, args.footprint_px, args.chunk_size, simd=False)
    point = make_operator(args.photons, args.footprint_px, args.chunk_size, pixel_integration=False)
    target = make_operator(args.photons, args.footprint_px, args.chunk_size).render(torch.zeros(128, 128))
    ((forward_s, gradient_s), (jit_forward_s, jit_gradient_s), (plain_forward_s, plain_gradient_s),
     (point_forward_s, point_gradient_s)) = time_side_by_side((op, jit, plain, point), heights, target)
    report = {
        "scene": "print_lines, m=128, n=512, light (0,0,10)",
        "threads": {"torch": torch.get_num_threads(), "numba": numba.get_num_threads()},
        "photons": op.photons, "footprint_px": args.footprint_px, "chunk_size": args.chunk_size,
        "simd": op.fused.simd, "c_kernels": op.fused.compiled,
        "forward_photons_per_s": op.photons / forward_s,
        "forward_backward_photons_per_s": op.photons / gradient_s,
        "numba_kernels": {"forward_photons_per_s": op.photons / jit_forward_s,
                          "forward_backward_photons_per_s": op.photons / jit_gradient_s,
                          "c_speedup": {"forward": jit_forward_s / forward_s,
                                        "forward_backward": jit_gradient_s / gradient_s}},
        "without_avx2_kernels": {"forward_photons_per_s": op.photons / plain_forward_s,
                               "forward_backward_photons_per_s": op.photons / plain_gradient_s,
                               "simd_speedup": {"forward": plain_forward_s / forward_s,
                                                "forward_backward": plain_gradient_s / gradient_s}},
        "point_sampled_pixels": {"forward_photons_per_s": op.photons / point_forward_s,
                                 "forward_backward_photons_per_s": op.photons / point_gradient_s,
                                 "pixel_integration_cost": {"forward": forward_s / point_forward_s,
                                                            "forward_backward": gradient_s / point_gradient_s}},
        "forward_split": time_split(op, heights),
        "jacobian_vector_product": time_jvp(op, heights),
    }
    big = make_operator(args.grad_photons, args.footprint_px, args.chunk_size)
    t0 = time.perf_counter()
    big.loss_and_grad(heights, target)
    report["gradient_paper_photons"] = {"photons": big.photons, "seconds": time.perf_counter() - t0,
                                        "process_peak_rss_mb": peak_rss_mb()}
    report["torch_reference_path"] = time_reference(heights, target, args.reference_photons, args.footprint_px,
                                                    args.chunk_size)
    report["splat_comparison"] = compare_splats(op, heights, args.splat_photons)
    if args.stage_photons > 0:
        report["stage_profile"] = profile_stages(op, heights, target, args.stage_photons)
    if args.stack_photons > 0:
        report["stack"] = time_stack(heights, args.stack_photons, args.footprint_px, args.chunk_size)
    if args.mesh_photons > 0:
        report["mesh_scene"] = time_mesh_scenes(heights, args.mesh_photons, mesh_fp, args.mesh_supersample)
    if args.fidelity_photons > 0:
        report["fidelity"] = fidelity_report(args.fidelity_photons, args.fidelity_bias_photons,
                                             args.fidelity_reference_photons, args.wavefront_vertices,
                                             tuple(args.fidelity_resolutions))
        report["fidelity"]["walls"] = wall_fidelity(args.fidelity_photons, args.wall_vertices,
                                                    args.fidelity_resolutions[0])
    if args.scale_sizes or args.scale_solve_sizes:
        report["scale"] = scale_section(args)
    if args.reconstruction_rounds > 0:
        report["reconstruction"] = reconstruction_report(args.reconstruction_overrides, args.reconstruction_rounds)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
