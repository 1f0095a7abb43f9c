"""The mesh-scene operator against independent truths: the plain scene equals the height-field
operator, the light at the substrate's side walls included; a plano-convex lens
focuses at its paraxial thick-lens focus; energy is conserved up to the counted losses; gradients
through a lens below the print match finite differences."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numba
import numpy as np
import pytest
import torch

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from framework.scene.scene_config import build_heights, build_operator, build_scene
from framework.scene.printed_shapes import make_shape
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.materials import FUSED_SILICA, refractive_indices
from operators.mesh import events_compiled
from operators.mesh.operator import MeshSceneOperator
from operators.mesh.settings import MeshSceneSettings
from operators.mesh.elements import make_element
from operators.scene import Light, Receiver, Scene


CONF = str(Path(__file__).resolve().parents[2] / "conf")


def lens_spec(z: float, radius: float, thickness: float, front: float, back: float = math.inf) -> dict:
    return {"name": f"lens{z}", "shape": "lens", "position": [0.0, 0.0, z],
            "params": {"radius": radius, "thickness": thickness, "front_radius": front, "back_radius": back}}


def test_the_plain_scene_is_the_height_field_operator_with_its_side_walls_light():
    """The mesh scene traces the substrate as a closed solid (Embree, its own event loop); the
    height-field operator folds the walls' total reflections into mirrored landings
    (operators/heightfield/side_walls.py). Without elements they render the same photons to
    rounding, the rim of wall light included; with absorbing walls the height-field operator
    loses that light (0.32% of it)."""
    scene = Scene(receiver=Receiver(resolution=64))
    heights = torch.from_numpy(make_shape("print_lines", 64))
    plain = CausticOperator(scene, OperatorSettings(photons=200_000, dtype="float64")).render(heights)
    mesh = MeshSceneOperator(scene, [], MeshSceneSettings(photons=200_000, dtype="float64"))
    image = mesh.render(heights)
    assert float((image - plain).norm() / plain.norm()) < 1e-9  # the same photons, same paths
    absorbing = dataclasses.replace(scene, substrate=dataclasses.replace(scene.substrate, walls="absorbing"))
    blackened = CausticOperator(absorbing, OperatorSettings(photons=200_000, dtype="float64")).render(heights)
    emitted = float(mesh.emitter.batch(0, mesh.photons).flux.sum())
    extra = float(image.sum() - blackened.sum()) * mesh.pixel_area
    assert extra > 0.002 * emitted  # measured: 0.32% of the light, all of it in the rim
    # measured 0.95%: the slab's shadow is wider than the receiver
    assert mesh.losses["missed_receiver"] > 0.005 * emitted


def test_the_plain_scene_under_a_disc_is_the_height_field_operator_s_and_elements_refuse_it():
    """An extended light: the same emission points, stretches of photons and patches' blur."""
    scene = Scene(light=Light(shape="disc", size=2.0, points=16), receiver=Receiver(z=-0.2, resolution=64))
    heights = torch.from_numpy(make_shape("print_lines", 64))
    plain = CausticOperator(scene, OperatorSettings(photons=200_000, dtype="float64")).render(heights)
    image = MeshSceneOperator(scene, [], MeshSceneSettings(photons=200_000, dtype="float64")).render(heights)
    assert float((image - plain).norm() / plain.norm()) < 1e-9
    with pytest.raises(ValueError, match=r"^light.shape=disc is traced by operator=mesh_scene without optical "):
        MeshSceneOperator(scene, [make_element(lens_spec(1.0, 0.5, 0.1, 2.0))], MeshSceneSettings(photons=1000))


def test_a_plano_convex_lens_focuses_at_its_thick_lens_focus():
    n = refractive_indices(FUSED_SILICA, [0.633])[0]
    focal, thickness, light_z = 1.5, 0.15, 1000.0
    radius = focal * (n - 1)  # lensmaker, one face flat
    back = 1.0  # the lens's flat face; its curved face toward the light
    element = make_element(lens_spec(back + thickness / 2, 0.3, thickness, radius))
    # Paraxial: the rear principal plane lies t / n above the flat face; the object at the light.
    s = light_z - (back + thickness)
    image_distance = 1.0 / (1.0 / focal - 1.0 / s)
    h = 0.1
    focus = back + thickness / n - image_distance - h * (1.0 - 1.0 / n)  # the flat slab shifts it down

    def landing(receiver_z: float) -> np.ndarray:
        scene = Scene(light=Light((0.0, 0.0, light_z)), receiver=Receiver(z=receiver_z, resolution=64))
        op = MeshSceneOperator(scene, [element], MeshSceneSettings(photons=4000, dtype="float64",
                                                                   aperture_half_width=0.01))
        pos, _, flux, _, _ = op.trace(torch.zeros(16, 16, dtype=torch.float64), 0, op.photons)
        assert bool((flux > 0).all())
        return ((pos + 0.5) / op._to_pixels - scene.receiver.half_width).numpy()

    # Straight rays between two planes; the plane of the smallest RMS spot in closed form.
    upper, lower = landing(-0.3), landing(-0.5)
    slope = (lower - upper) / -0.2
    best = -0.3 - float((upper * slope).sum() / (slope * slope).sum())
    assert abs(best - focus) < 2e-4, (best, focus)  # measured: 1e-4
    spot = np.sqrt(((upper + slope * (best + 0.3)) ** 2).sum(0).mean())
    assert spot < 1e-3 * np.sqrt((upper ** 2).sum(0).mean())  # a point, not a blur


def test_energy_is_conserved_up_to_the_counted_losses():
    scene = Scene(receiver=Receiver(z=-1.0, resolution=128, half_width=3.0))
    elements = [make_element(lens_spec(1.15, 1.0, 0.3, 4.0, 4.0)), make_element(lens_spec(-0.6, 1.0, 0.2, -3.0, 2.0))]
    op = MeshSceneOperator(scene, elements, MeshSceneSettings(photons=100_000, dtype="float64", fresnel=True,
                                                              aperture_half_width=1.0))
    image = op.render(torch.from_numpy(make_shape("bump", 32)))
    emitted = float(op.emitter.batch(0, op.photons).flux.sum())
    received = float(image.sum()) * op.pixel_area
    lost = sum(op.losses.values())
    assert op.losses["fresnel_reflected"] > 0.02 * emitted  # four air-glass interfaces, ~3.5% each
    assert abs(received + lost - emitted) < 1e-6 * emitted, (received, lost, emitted)


def test_gradients_through_lenses_above_and_below_the_print_match_finite_differences():
    # A lens wider than the light below the print: no photon comes near its rim, where the image
    # is not differentiable (a photon that moves across the rim changes its path).
    scene = Scene(receiver=Receiver(z=-1.6, resolution=32, half_width=2.0))
    lenses = [make_element(lens_spec(1.15, 1.6, 0.5, 6.0, 6.0)), make_element(lens_spec(-0.75, 1.4, 0.8, 3.0, 3.0))]
    op = MeshSceneOperator(scene, lenses, MeshSceneSettings(photons=20_000, dtype="float64", footprint_px=2.0,
                                                            chunk_size=7_000, aperture_half_width=0.9))
    heights = torch.from_numpy(make_shape("bump", 16, sigma=0.35, height=0.06)) + 0.01
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    grad = op.vjp(heights, weights)
    for seed in range(3):
        direction = torch.randn(heights.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
        # The shading normal's derivative is constant on each face: where a photon's hit crosses an
        # edge its footprint steps (measured: 0.2% of one photon's metric for a 1e-7 move), so the
        # image is only piecewise smooth; steps of 1e-9 cross no edge here.
        eps = 1e-9
        numeric = float(((op.render(heights + eps * direction) - op.render(heights - eps * direction))
                         * weights).sum()) / (2 * eps)
        analytic = float((grad * direction).sum())
        assert abs(numeric - analytic) <= 1e-5 * abs(analytic), (numeric, analytic)


def paper_scene(operator_config: str, *overrides: str) -> tuple[Scene, torch.Tensor, MeshSceneOperator]:
    """One of the paper's mesh scenes at a test size, Fresnel weighting on: scene, heights, operator."""
    with initialize_config_dir(config_dir=CONF, version_base=None):
        cfg = OmegaConf.to_container(compose("simulate", overrides=[
            f"operator={operator_config}", "photons=12000", "receiver.resolution=32", "height_field.resolution=24",
            "operator.dtype=float64", "operator.fresnel=true", "operator.supersample=1", *overrides]), resolve=True)
    scene = build_scene(cfg)
    return scene, build_heights(cfg).double(), build_operator(cfg, scene)


@pytest.mark.parametrize("kernels", ["c", "numba"])
@pytest.mark.parametrize("operator_config", ["two_lenses", "prism_lens_array"])
@pytest.mark.slow
def test_the_native_path_equals_the_torch_tracer(operator_config, kernels):
    """Two independent implementations of the same photon paths: the event kernels (in C, the
    default, or numba) with Embree on their threads and a cached prefix before the print against
    the event-by-event torch tracer with autograd (operator.native=false), with Fresnel weighting,
    on the paper's scenes (the prism + lens-array plate guides light by total internal reflection)."""
    if kernels == "c" and not events_compiled.AVAILABLE:
        pytest.fail("the compiled extension is missing: pip install -e . builds it")
    scene, heights, native = paper_scene(operator_config, f"operator.kernels={kernels}")
    assert native.native.compiled == (kernels == "c")
    torch_path = MeshSceneOperator(scene, native.elements, dataclasses.replace(native.settings, native=False))
    image, reference = native.render(heights), torch_path.render(heights)
    assert float((image - reference).norm() / reference.norm()) < 1e-12
    for kind, lost in torch_path.losses.items():
        assert native.losses[kind] == pytest.approx(lost, rel=1e-12, abs=1e-15), kind
    weights = torch.randn(native.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    grad, grad_reference = native.vjp(heights, weights), torch_path.vjp(heights, weights)
    assert float((grad - grad_reference).norm() / grad_reference.norm()) < 1e-8


def test_the_baseline_build_of_the_c_event_kernels_equals_the_build_that_runs(monkeypatch):
    """The C event kernels are built twice, for any x86-64 CPU and for AVX2 + FMA (run where the
    CPU has them, tested against the torch tracer above); the baseline build traces the same
    paths: images and gradients equal to rounding (fused multiply-adds)."""
    if not events_compiled.AVAILABLE:
        pytest.fail("the compiled extension is missing: pip install -e . builds it")
    _, heights, op = paper_scene("two_lenses")
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    image, grad = op.render(heights), op.vjp(heights, weights)
    monkeypatch.setattr(events_compiled._KERNELS, "suffix", "")
    _, _, baseline = paper_scene("two_lenses")
    baseline_image, baseline_grad = baseline.render(heights), baseline.vjp(heights, weights)
    assert float(image.sum()) > 0 and float(grad.abs().max()) > 0
    assert float((baseline_image - image).norm() / image.norm()) < 1e-12
    assert float((baseline_grad - grad).norm() / grad.norm()) < 1e-9


def test_the_c_event_kernels_repeat_a_render_and_a_gradient_to_the_last_bit(monkeypatch):
    """Each thread of the C kernels takes a fixed share of the photons and sums the heights'
    gradient in its own array, so repeats agree bit for bit, whatever the threads' timing (four
    threads, whatever share of the cores this process has)."""
    monkeypatch.setattr(numba, "get_num_threads", lambda: 4)
    _, heights, op = paper_scene("prism_lens_array")
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    first_image, first_grad = op.render(heights), op.vjp(heights, weights)
    for _ in range(2):
        assert torch.equal(op.render(heights), first_image)
        assert torch.equal(op.vjp(heights, weights), first_grad)


def test_a_gradient_replays_the_renders_events_and_equals_one_that_searches_them_again():
    """With the C kernels a render keeps each photon's events and a gradient at the same heights
    replays them; with event_log_mb=0 the gradient searches them again: the same bits."""
    scene, heights, op = paper_scene("two_lenses")
    searching = MeshSceneOperator(scene, op.elements, dataclasses.replace(op.settings, event_log_mb=0))
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    assert torch.equal(op.render(heights), searching.render(heights))
    assert op.native._events_seen is not None and searching.native._events_seen is None
    assert torch.equal(op.vjp(heights, weights), searching.vjp(heights, weights))


def test_a_gradient_from_the_renders_splat_arguments_equals_one_that_replays_to_them():
    """Within event_log_mb a render keeps its photons' splat arguments beside their events and the
    gradient gathers at them; with a budget for the events only it replays them: the same bits."""
    scene, heights, op = paper_scene("two_lenses")
    waiting = len(op.native.prefix().state)
    events_only = (waiting * op.settings.max_depth * events_compiled.BYTES_PER_EVENT + waiting) / 2 ** 20
    replaying = MeshSceneOperator(scene, op.elements, dataclasses.replace(op.settings, event_log_mb=events_only))
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    assert torch.equal(op.render(heights), replaying.render(heights))
    assert op.native._events_seen[2] is not None
    assert replaying.native._events_seen is not None and replaying.native._events_seen[2] is None
    assert torch.equal(op.vjp(heights, weights), replaying.vjp(heights, weights))
    assert torch.equal(op.render(heights), replaying.render(heights))  # the prefix's states were not changed


@pytest.mark.parametrize("elements, message", [
    ([lens_spec(0.05, 0.5, 0.1, 4.0)], "overlaps the substrate"),
    ([lens_spec(-1.2, 0.5, 0.1, 4.0)], "at or below the receiver"),
])
def test_impossible_layouts_are_refused(elements, message):
    with pytest.raises(ValueError, match=message):
        MeshSceneOperator.from_config(Scene(receiver=Receiver(z=-1.0, resolution=32)), 1000, 0, elements=elements)


def test_unknown_settings_are_refused():
    with pytest.raises(ValueError, match="unknown key operator.depth"):
        MeshSceneOperator.from_config(Scene(), 1000, 0, depth=3)
    with pytest.raises(ValueError, match="max_depth"):
        MeshSceneOperator.from_config(Scene(), 1000, 0, max_depth=0)
