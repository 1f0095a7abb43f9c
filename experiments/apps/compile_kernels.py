"""``sfc-compile-kernels`` (``python -m experiments.apps.compile_kernels``): compile the numba kernels into
numba's on-disk cache ahead of their first use.

The operators trace with the compiled extension's C kernels (operators/kernels/, built at
install); numba's kernels trace where it is missing or where ``operator.kernels: numba`` asks for
them (the exact wavefront renderer's tracer too, operators/wavefront/renderer.py), and the test
suite compares every numba kernel with its C twin. Each compiles on its first call in a
fresh environment, one function at a time (about 2.5 minutes on one core for all of them): this
command makes those calls once on tiny problems, each group in its own process on its own core,
and every later process loads the kernels from the cache. Run it after the install (README.md).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

import torch

__all__ = ["GROUPS", "main"]


def _small_operators() -> Iterator[tuple[Any, torch.Tensor]]:
    """The height-field operator traced by the numba kernels in each precision, with flat heights
    of its dtype: their calls compile the kernels with every operator's argument types."""
    from operators.heightfield.compile_kernels import small_numba_operator

    for dtype in ("float32", "float64"):
        op = small_numba_operator(dtype)
        yield op, torch.zeros(4, 4, dtype=op.dtype)


def _heightfield() -> None:
    """The height-field operator's fused numba kernels (render and gradient, both dtypes)."""
    for op, d in _small_operators():
        op.render(d)
        op.vjp(d, torch.ones(op.output_shape, dtype=op.dtype))


def _tangent() -> None:
    """The height-field operator's forward pass, J v (operators/heightfield/tangent_native.py; numba
    on every machine: the C kernels have none), both dtypes."""
    for op, d in _small_operators():
        op.jvp(d, torch.ones_like(d))


def _mesh() -> None:
    """The mesh-scene operator's numba event kernels (render and gradient through the paper's lenses)."""
    from experiments.apps.configs import app_config
    from framework.scene.scene_config import build_heights, build_operator, build_scene

    cfg = app_config("simulate", ["operator=two_lenses", "operator.kernels=numba", "photons=256",
                                  "receiver.resolution=8", "height_field.resolution=8", "operator.dtype=float64"])
    op = build_operator(cfg, build_scene(cfg))
    d = build_heights(cfg).double()
    op.render(d)
    op.vjp(d, torch.ones(op.output_shape, dtype=torch.float64))


def _wavefront() -> None:
    """The exact wavefront renderer's numba tracer and rasterisers: its kernels where the compiled
    extension is missing, and the reference the C kernels are held to (the test suite compares
    them); on another core they compile while the mesh group does."""
    import numpy as np

    from operators.heightfield.operator import CausticOperator, OperatorSettings
    from operators.scene import Receiver, Scene
    from operators.wavefront import coverage
    from operators.wavefront.renderer import WavefrontRenderer, _trace_native

    op = CausticOperator(Scene(receiver=Receiver(resolution=8)), OperatorSettings(photons=64, dtype="float64"))
    bump = 0.01 * torch.exp(-torch.linspace(-1.0, 1.0, 4, dtype=torch.float64) ** 2)  # not flat glass's shortcut
    d = (bump[:, None] * bump[None, :]).numpy()
    op.exact_variant(256, 0, 8).render(torch.from_numpy(d))
    sc = WavefrontRenderer(op.scene, vertices=5).fused.constants(d)
    aim = np.zeros((2, 2))
    _trace_native(d, sc, 1.46, aim, np.empty((2, 2)), np.empty(2), np.empty(2))
    axis = np.linspace(0.0, 4.0, 3)
    vertices = np.ascontiguousarray(np.stack(np.meshgrid(axis, axis), axis=-1))
    coverage._rasterize_grid(vertices, np.ones((1, 2, 2)), np.zeros((1, 4, 4)))
    coverage._rasterize_list(np.array([[[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]]]), np.ones(1), np.zeros((1, 4, 4)))


GROUPS: dict[str, Callable[[], None]] = {"heightfield": _heightfield, "mesh": _mesh, "wavefront": _wavefront,
                                         "tangent": _tangent}


def _compile_in_process(name: str) -> tuple[str, int, float]:
    """Run group ``name`` in a process of its own: (name, exit code, seconds)."""
    began = time.perf_counter()
    code = subprocess.run([sys.executable, "-m", "experiments.apps.compile_kernels", name]).returncode
    return name, code, time.perf_counter() - began


def main(argv: list[str] | None = None) -> int:
    """Without arguments: every group in its own process, as many at once as there are cores,
    printing each group's seconds; with group names: those groups in this process."""
    names = sys.argv[1:] if argv is None else argv
    unknown = [name for name in names if name not in GROUPS]
    if unknown:
        print(f"unknown kernel group(s) {', '.join(unknown)}: choose from {', '.join(GROUPS)}", file=sys.stderr)
        return 2
    if names:
        for name in names:
            GROUPS[name]()
        return 0
    began, failed = time.perf_counter(), []
    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
        for done in as_completed([pool.submit(_compile_in_process, name) for name in GROUPS]):
            name, code, seconds = done.result()
            print(f"{name}: {'compiled' if code == 0 else 'FAILED'} in {seconds:.0f} s", flush=True)
            if code != 0:
                failed.append(name)
    print(f"numba kernels compiled into numba's cache in {time.perf_counter() - began:.0f} s"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
