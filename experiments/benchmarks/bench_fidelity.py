"""sfc-bench's fidelity section: how far each irradiance model is from the exact caustic.

For print_lines on the plain substrate and through the paper's two lenses (receiver at z = -1),
at receivers of 128 and 256 pixels, every model design is compared with the exact reference:

- bias: the relative L2 distance of the mean of two renders with ``bias_photons`` photons each
  (independent photon patterns) to the exact reference; what is left of the render noise in that
  mean is half the noise at those photons squared, reported beside it (``bias_noise``);
- noise: the render noise at the budget, ||F_a - F_b|| / (sqrt(2) ||exact||), two photon patterns
  of ``photons`` photons each;
- seconds per render and per gradient (loss and gradient in one call) at the budget, the best of
  two, one design after the other on the same machine.

The walls: the default model (cell footprints, 4 x supersampled, 128 pixels, the reconstruction's
final budget) on the true heights of every built-in scene at screens 0.05 and 0.2 below the
substrate, with clear walls (the default) and with absorbing walls (light at the walls lost),
against the exact reference of a block with clear walls, over the whole receiver and inside
|x|, |y| < 0.95; and the seconds per gradient with clear and with absorbing walls, side by side.

The exact reference of the height field is the wavefront-triangle renderer
(operators/wavefront/renderer.py, ``wavefront_vertices`` aim points per side); through the lenses
it is the mesh-scene operator's exact variant (cell footprints, 4 x supersampled) with
``reference_photons`` photons.
"""

from __future__ import annotations

import copy
import functools
import math
import time
from typing import Any

import torch

from experiments.benchmarks.timing import best_seconds
from framework.scene.printed_shapes import make_shape

# The designs compared: the paper's splat, photon differentials at their own cells' size, and those
# rendered on a 4 x finer receiver and block-averaged (the default, conf/operator/height_field.yaml).
DESIGNS: dict[str, dict[str, Any]] = {
    "paper_splat_5px": {"footprint_px": 5.0, "min_footprint_px": 1.0, "supersample": 1},
    "cell_footprints": {"footprint_px": "cell", "min_footprint_px": 0.3, "supersample": 1},
    "cell_footprints_supersampled_4x": {"footprint_px": "cell", "min_footprint_px": 0.1, "supersample": 4},
}
SCENES = ("height_field", "two_lenses")  # conf/operator/<name>.yaml


def configured_operator(scene_name: str, resolution: int, photons: int, seed: int, design: dict[str, Any],
                        scene_overrides: tuple[str, ...] = ()) -> Any:
    """The operator of ``conf/operator/<scene_name>.yaml`` with ``design``'s footprint settings and
    ``scene_overrides`` (Hydra overrides of the scene, e.g. ``receiver.z=-0.2``)."""
    from framework.scene.scene_config import build_operator, build_scene

    cfg = copy.deepcopy(_scene_config(scene_name, tuple(scene_overrides)))
    cfg.update(photons=photons, seed=seed)
    cfg["receiver"]["resolution"] = resolution
    cfg["operator"].update(design)
    return build_operator(cfg, build_scene(cfg))


@functools.cache
def _scene_config(scene_name: str, scene_overrides: tuple[str, ...]) -> dict[str, Any]:
    """conf/simulate.yaml with ``operator=<scene_name>`` and ``scene_overrides``, composed once (a
    compose costs a quarter of a second; the section builds some fifty operators of a few scenes).
    The photons, seed, resolution and footprint settings are then plain values set on a copy: the
    configs interpolate none of them."""
    from experiments.apps.configs import app_config

    return app_config("simulate", [f"operator={scene_name}", *scene_overrides])


def relative(a: torch.Tensor, b: torch.Tensor) -> float:
    """||a - b|| / ||b||."""
    return float(torch.linalg.vector_norm(a.double() - b.double()) / torch.linalg.vector_norm(b.double()))


def render_noise(a: torch.Tensor, b: torch.Tensor, exact: torch.Tensor) -> float:
    """||a - b|| / (sqrt(2) ||exact||): the noise of one render from two photon patterns."""
    difference = torch.linalg.vector_norm(a.double() - b.double())
    return float(difference / torch.linalg.vector_norm(exact.double())) / math.sqrt(2.0)


def exact_reference(scene_name: str, resolution: int, heights: torch.Tensor, vertices: int,
                    reference_photons: int) -> tuple[torch.Tensor, float]:
    """The exact caustic (c, n, n) and the seconds it took."""
    t0 = time.perf_counter()
    probe = configured_operator(scene_name, resolution, 1 << 10, 0, DESIGNS["paper_splat_5px"])
    if scene_name == "height_field":
        from operators.wavefront.renderer import WavefrontRenderer
        image = WavefrontRenderer(probe.scene, vertices=vertices).render(heights.double())
    else:
        image = probe.exact_variant(reference_photons, 4242, resolution).render(heights)
    return image.double(), time.perf_counter() - t0


def fidelity_report(photons: int, bias_photons: int, reference_photons: int, vertices: int,
                    resolutions: tuple[int, ...] = (128, 256)) -> dict[str, Any]:
    """The section's JSON: per scene and resolution, the exact reference's seconds and, per design,
    bias, noise and seconds (module docstring)."""
    heights = torch.from_numpy(make_shape("print_lines", 128)).float()
    report: dict[str, Any] = {"photons": photons, "bias_photons": bias_photons,
                              "reference_photons": reference_photons, "wavefront_vertices": vertices}
    for scene_name in SCENES:
        for n in resolutions:
            exact, seconds = exact_reference(scene_name, n, heights, vertices, reference_photons)
            entry: dict[str, Any] = {"exact_seconds": seconds}
            for name, design in DESIGNS.items():
                ops = [configured_operator(scene_name, n, photons, seed, design) for seed in (0, 1)]
                renders = [op.render(heights) for op in ops]
                fine = [configured_operator(scene_name, n, bias_photons, seed, design).render(heights).double()
                        for seed in (0, 1)]
                target = exact.to(ops[0].dtype)
                entry[name] = {
                    "bias": relative(0.5 * (fine[0] + fine[1]), exact),
                    "bias_noise": render_noise(fine[0], fine[1], exact) / math.sqrt(2.0),
                    "error_at_budget": relative(renders[0], exact),
                    "noise_at_budget": render_noise(renders[0], renders[1], exact),
                    "render_seconds": best_seconds(lambda: ops[0].render(heights), repeats=2),
                    "gradient_seconds": best_seconds(lambda: ops[0].loss_and_grad(heights, target), repeats=2),
                }
            report[f"{scene_name}_{n}px"] = entry
    return report


BUILT_IN_SCENES = ("print_lines", "oblique_lines", "bump", "gaussian", "letter_a")  # conf/scene/<name>.yaml
WALL_SCREENS = (0.05, 0.2)  # screen distances below the substrate (scene units) of the walls' comparison
INTERIOR = 0.95  # the part of the receiver |x|, |y| < INTERIOR that the light at the walls does not reach


def wall_fidelity(photons: int, vertices: int, resolution: int = 128) -> dict[str, Any]:
    """The section's walls entry (module docstring): per built-in scene and screen, the relative L2
    distances of the default model with clear and with absorbing walls to the exact caustic of a
    clear-walled block, whole receiver and interior, and the gradient's seconds with either."""
    from operators.wavefront.renderer import WavefrontRenderer

    design = DESIGNS["cell_footprints_supersampled_4x"]
    centres = (torch.arange(resolution, dtype=torch.float64) + 0.5) / resolution * 2.0 - 1.0
    inside = (centres.abs() < INTERIOR)[:, None] & (centres.abs() < INTERIOR)[None, :]
    report: dict[str, Any] = {"photons": photons, "wavefront_vertices": vertices, "resolution": resolution}
    for name in BUILT_IN_SCENES:
        heights = torch.from_numpy(make_shape(name, 128)).float()
        for screen in WALL_SCREENS:
            entry: dict[str, Any] = {}
            for walls in ("clear", "absorbing"):
                model = configured_operator("height_field", resolution, photons, 0, design,
                                            (f"receiver.z={-screen}", f"substrate.walls={walls}"))
                if walls == "clear":
                    exact = WavefrontRenderer(model.scene, vertices=vertices).render(heights.double())
                image = model.render(heights).double()
                target = exact.to(model.dtype)
                entry[walls] = {
                    "whole": relative(image, exact),
                    "interior": relative(image[:, inside], exact[:, inside]),
                    "gradient_seconds": best_seconds(lambda: model.loss_and_grad(heights, target), repeats=2),
                }
            report[f"{name}_screen_{screen}"] = entry
    return report
