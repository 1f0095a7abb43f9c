"""Several shots of one print (operators/stack.py, framework/stack/stack_data.py): the stacked
data term against its shots, a stack of one against a run of one image, calibration across the
stack, and bad stacks refused."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from framework.core.objective import DataFidelity
from framework.lab.calibration import JointCalibration
from framework.reconstruction.reconstruction import run_reconstruction
from framework.reconstruction.parts import Reconstruction
from framework.stack.stack_stage import unexplained_shots
from operators.heightfield.operator import CausticOperator
from operators.imaging import ImagingOperator
from operators.stack import StackOperator
from tests.experiments.conftest import SMALL, compose_reconstruct
from tests.operators.conftest import bump, make_operator

DISTANCES = (0.05, 0.2)
WEIGHTS = (1.0, 2.5)


def _at(operator: CausticOperator, distance: float, seed: int | None = None) -> CausticOperator:
    scene = dataclasses.replace(operator.scene, receiver=dataclasses.replace(operator.scene.receiver, z=-distance))
    settings = operator.settings if seed is None else dataclasses.replace(operator.settings, seed=seed)
    return CausticOperator(scene, settings)


def _shots(photons: int = 20_000, seed: int = 0) -> list[CausticOperator]:
    base = make_operator(photons=photons, resolution=32, seed=seed)
    return [_at(base, z) for z in DISTANCES]


def test_the_stacked_loss_and_gradient_are_the_weighted_sums_of_the_shots() -> None:
    shots = _shots()
    stack = StackOperator(shots, WEIGHTS)
    heights = bump(16, (0.1, -0.15), 0.35, 0.06) + 0.01
    targets = [_at(make_operator(photons=20_000, resolution=32, seed=5), z).render(bump(16, height=0.04))
               for z in DISTANCES]
    loss, grad, image = stack.loss_and_grad(heights, stack.stack(targets))
    singles = [shot.loss_and_grad(heights, target) for shot, target in zip(shots, targets)]
    expected_loss = sum(w * single[0] for w, single in zip(WEIGHTS, singles))
    expected_grad = sum(w * single[1] for w, single in zip(WEIGHTS, singles))
    assert abs(loss - expected_loss) <= 1e-10 * expected_loss
    assert float((grad - expected_grad).abs().max()) <= 1e-10 * float(expected_grad.abs().max())
    assert torch.allclose(image, stack.render(heights), rtol=0, atol=0)
    # The same through the data term a solver sees, and against central differences of it.
    fidelity = DataFidelity(stack, stack.stack(targets))
    evaluation = fidelity.evaluate(heights)
    direction = torch.randn(heights.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    eps = 1e-6
    numeric = (fidelity.value(heights + eps * direction) - fidelity.value(heights - eps * direction)) / (2 * eps)
    analytic = float((evaluation.grad * direction).sum())
    assert abs(numeric - analytic) <= 2e-5 * abs(analytic), (numeric, analytic)
    # Four passes (a render and a gradient pass, two value renders), each tracing every shot.
    assert fidelity.photon_traces == 4 * 2 * stack.photons


@pytest.mark.slow
def test_a_stack_of_one_runs_exactly_as_the_one_image(tmp_path) -> None:
    base = [*SMALL, "scene=bump", "height_field.params.sigma=0.15", "height_field.params.height=0.05",
            "solver.step_size.tau=1e-3", "solver.max_iter=6"]
    single = run_reconstruction(compose_reconstruct([*base, "data.delta=0.01"], tmp_path), tmp_path / "single",
                                tmp_path)
    stacked = run_reconstruction(compose_reconstruct(
        [*base, "data=stack", "data.shots=[{offset: 0}]", "data.common.delta=0.01",
         "+data.common.reference_photons=200000", "+data.common.reference_resolution=128"], tmp_path),
        tmp_path / "stack", tmp_path)
    for name in ("height_field.npy", "caustic_target.npy", "caustic_predicted.npy"):
        assert np.array_equal(np.load(tmp_path / "single" / name), np.load(tmp_path / "stack" / name)), name
    for key in ("iterations", "rel_discrepancy", "rel_error", "delta", "intrinsic_noise", "renders",
                "gradient_passes", "photon_traces"):
        assert stacked[key] == single[key], key


@pytest.mark.slow
def test_two_screens_report_each_shot(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "scene=bump", "data=stack", "solver.max_iter=2",
                               "+data.common.reference_photons=200000", "+data.common.reference_resolution=128"],
                              tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    # From flat glass the nearest shot is fitted alone first (at most max_iter = 2 iterations).
    assert metrics["start_zero_first_fit_shot"] == 0 and metrics["start_zero_first_fit_iterations"] == 2
    shares = [metrics[f"shot{i}_misfit_share"] for i in range(2)]
    assert sum(shares) == pytest.approx(1.0) and min(shares) > 0
    assert [metrics[f"shot{i}_screen_distance"] for i in range(2)] == pytest.approx(list(DISTANCES))
    # The stacked discrepancy is the misfit-weighted mean of the shots' (equal weights, equal norms ~).
    record = json.loads((tmp_path / "run" / "shots.json").read_text())
    assert [r["screen_distance"] for r in record] == pytest.approx(list(DISTANCES))
    assert np.load(tmp_path / "run" / "caustic_target.npy").shape == (2, 64, 64)


def test_calibration_recovers_the_distance_and_every_gain_from_a_stack_with_known_offsets(tmp_path) -> None:
    true_gains, truth = (1.3, 0.8), bump(32, sigma=0.25, height=0.06)
    truth_base = make_operator(photons=1 << 17, resolution=48, seed=11)
    target = torch.cat([g * _at(truth_base, z).render(truth) for g, z in zip(true_gains, DISTANCES)])
    model = make_operator(photons=1 << 17, resolution=48)
    told = 1.1 * DISTANCES[0]  # the configured distance 10% off; the second shot is 0.15 farther
    shots = [
        ImagingOperator(lambda scene: CausticOperator(scene, model.settings), _at(model, told + z - DISTANCES[0]).scene)
        for z in DISTANCES
    ]
    calibration = JointCalibration(StackOperator(shots), ["gain", "screen_distance"], scene=_at(model, told).scene)
    assert calibration.params == ["gain_0", "gain_1", "screen_distance"]
    calibration.setup(target, None, 0.05, tmp_path / "calibration.json")
    for _ in range(4):
        values = calibration.update(truth)
    assert values["screen_distance"] == pytest.approx(DISTANCES[0], rel=5e-3)
    assert [values["gain_0"], values["gain_1"]] == pytest.approx(list(true_gains), rel=5e-3)
    assert shots[1].scene.receiver.z == pytest.approx(-(values["screen_distance"] + DISTANCES[1] - DISTANCES[0]))
    assert 0 < calibration.std["screen_distance"] < 0.01 * DISTANCES[0]


@pytest.mark.parametrize("overrides, message", [
    (["data.shots=[]"], r"data.shots=\[\]: a stack needs a list of one or more shots"),
    (["data.shots=[{offset: -0.06}]"], r"data.shots\[0\]: the screen would lie -0.01 below the substrate"),
    (["data.shots=[{screen_distance: 0.1, offset: 0.1}]"], r"data.shots\[0\] gives both screen_distance and offset"),
    (["data.shots=[{source: stack}]"], r"data.shots\[0\].source='stack'; use one of"),
    (["data.start_shot=2"], r"data.start_shot=2 must be 'farthest' or a shot index in \[0, 2\)"),
    (["data.shots=[{weight: 0}]"], r"data.shots\[0\]: gain=1.0 and weight=0.0 must both be > 0"),
    (["data.weighting=loud"], r"data.weighting='loud'; use equal, distance, noise"),
    (["data.first_fit=farthest"], r"data.first_fit='farthest'; use one of nearest, lines, none"),
    (["data.shots=[{light_offset: [0, 0, -9.95]}]"], r"data.shots\[0\]: the light would sit at z = 0.05"),
    (["coarse_to_fine.levels=2", "coarse_to_fine.coarsest=8"], r"coarse_to_fine.levels=2 reads one photo"),
])
def test_bad_stacks_are_refused_in_one_line(tmp_path, overrides, message) -> None:
    cfg = compose_reconstruct([*SMALL, "data=stack", *overrides], tmp_path)
    with pytest.raises(ValueError, match=message) as error:
        Reconstruction.from_config(cfg, tmp_path).check(tmp_path, tmp_path / "run")
    assert "\n" not in str(error.value)


def test_a_stack_takes_coarse_to_fine_settings_that_run_no_coarser_level(tmp_path) -> None:
    """A preset's grid continuation (experiment=m2v1_newton: coarsest 128) runs no coarser level on a
    smaller grid, so a stack is not refused for it."""
    cfg = compose_reconstruct([*SMALL, "data=stack", "experiment=m2v1_newton"], tmp_path)
    assert cfg["coarse_to_fine"]["levels"] > 1
    Reconstruction.from_config(cfg, tmp_path).check(tmp_path, tmp_path / "run")


def test_image_files_of_different_sizes_are_refused(tmp_path) -> None:
    for name, n in (("near.npy", 64), ("far.npy", 48)):
        np.save(tmp_path / name, np.ones((1, n, n), dtype=np.float32))
    cfg = compose_reconstruct([*SMALL, "data=stack", "data.common.source=file",
                               f"data.shots=[{{image: {tmp_path / 'near.npy'}}}, {{image: {tmp_path / 'far.npy'}, "
                               "offset: 0.15}]"], tmp_path)
    with pytest.raises(ValueError, match=r"data.shots\[1\].image is 48x48 px but data.shots\[0\].image is 64x64; "
                                         r".*use source: photo with each photo's corners"):
        Reconstruction.from_config(cfg, tmp_path).check(tmp_path, tmp_path / "run")


def test_shots_at_several_screens_share_the_hit_search_and_render_as_alone() -> None:
    heights = bump(16, (0.1, -0.15), 0.35, 0.06) + 0.01
    alone = _shots()
    shared = _shots()
    stack = StackOperator(shared)
    assert shared[1].hit_cache is shared[0].hit_cache and alone[1].hit_cache is not alone[0].hit_cache
    image = stack.render(heights)
    assert shared[1].hit_cache.recorded_by is shared[0]  # the second shot replayed the first one's hits
    assert torch.equal(image, torch.cat([op.render(heights) for op in alone]))
    grad_image = torch.randn(stack.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    expected = sum(op.vjp(heights, g) for op, g in zip(alone, stack.blocks(grad_image)))
    assert torch.allclose(stack.vjp(heights, grad_image), expected, rtol=1e-12, atol=0)
    # A shot whose light moved meets the print elsewhere: it keeps its own hits.
    near = shared[0].scene
    moved = CausticOperator(dataclasses.replace(near, light=dataclasses.replace(near.light, position=(0.1, 0.0, 10.0))),
                            shared[0].settings)
    assert StackOperator([shared[0], moved]).shots[1].hit_cache is not shared[0].hit_cache


def test_the_verdict_names_a_shot_its_heights_do_not_explain() -> None:
    metrics = {"shot0_rel_discrepancy": 0.049, "shot0_delta": 0.05, "shot0_screen_distance": 0.05,
               "shot1_rel_discrepancy": 0.26, "shot1_delta": 0.05, "shot1_screen_distance": 1.0}
    (line,) = unexplained_shots(metrics, 2)
    assert line.startswith("Shot 1 (screen 1) is not explained: its own discrepancy 0.26 = 5.20 x its noise level")


def test_a_shot_s_missing_file_is_named(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "data=stack", "data.common.source=file",
                               f"data.shots=[{{image: {tmp_path / 'missing.npy'}}}]"], tmp_path)
    with pytest.raises(FileNotFoundError, match=r"^data.shots\[0\]: .*missing.npy"):
        Reconstruction.from_config(cfg, tmp_path).check(tmp_path, tmp_path / "run")


def _distance_told_too_far(tmp_path, volume_held: bool) -> tuple[torch.Tensor, JointCalibration]:
    """A bump's caustics at DISTANCES and the stack's distance calibration told 10% too far."""
    truth = bump(32, sigma=0.25, height=0.06)
    truth_base = make_operator(photons=1 << 17, resolution=48, seed=11)
    target = torch.cat([_at(truth_base, z).render(truth) for z in DISTANCES])
    model = make_operator(photons=1 << 17, resolution=48)
    told = 1.1 * DISTANCES[0]
    shots = [
        ImagingOperator(lambda scene: CausticOperator(scene, model.settings), _at(model, told + z - DISTANCES[0]).scene)
        for z in DISTANCES
    ]
    calibration = JointCalibration(StackOperator(shots), ["screen_distance"], scene=_at(model, told).scene,
                                   volume_held=volume_held)
    calibration.setup(target, None, 0.05, tmp_path / "calibration.json")
    return truth, calibration


def test_the_stack_moves_the_heights_with_the_distance_it_calibrates(tmp_path) -> None:
    # Heights fitted to the near shot with the distance told 10% too far are 1/1.1 of the truth;
    # a step on the distance alone would move it farther still. With the heights' factor in the
    # step, distance and heights come back together.
    truth, calibration = _distance_told_too_far(tmp_path, volume_held=False)
    heights = truth / 1.1
    for _ in range(4):
        values = calibration.update(heights)
        heights = heights * calibration.height_scale
    assert values["screen_distance"] == pytest.approx(DISTANCES[0], rel=1e-2)
    assert float((heights - truth).abs().max()) <= 0.01 * float(truth.max())


def test_with_the_volume_held_the_distance_moves_alone_and_is_found(tmp_path) -> None:
    # Heights that hold the known volume have the truth's strength: the distance told 10% too far
    # comes back from the stack's offsets without a factor on the heights.
    truth, calibration = _distance_told_too_far(tmp_path, volume_held=True)
    for _ in range(4):
        values = calibration.update(truth)
        assert calibration.height_scale == 1.0
    assert values["screen_distance"] == pytest.approx(DISTANCES[0], rel=1e-2)


def test_noise_weighting_counts_every_shot_in_units_of_its_own_noise(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "scene=bump", "data=stack", "data.weighting=noise", "solver.max_iter=1",
                               "data.shots=[{screen_distance: 0.2, delta: 0.1}, {screen_distance: 0.05}]",
                               "+data.common.reference_photons=200000", "+data.common.reference_resolution=128"],
                              tmp_path)
    parts = Reconstruction.from_config(cfg, tmp_path)
    data = parts.data_source.load(parts.data_request(tmp_path, tmp_path / "run"))
    weights = parts.operator.weights
    # The nearest screen (shot 1) keeps weight 1; w_i delta_i^2 ||b_i||^2 is the same for every shot.
    assert weights[1] == 1.0
    noise = [w * s.delta ** 2 * float(torch.sum(s.target.double() ** 2)) for w, s in zip(weights, data.shots)]
    assert noise[0] == pytest.approx(noise[1], rel=1e-12)
    # The stacked target is [sqrt(w_i) b_i]; its noise level sqrt(sum w_i delta_i^2 ||b_i||^2 /
    # sum w_i ||b_i||^2) is then sqrt(N / sum 1 / delta_i^2).
    assert torch.equal(data.target[:1], data.shots[0].target * weights[0] ** 0.5)
    assert data.delta == pytest.approx((2 / (1 / 0.1 ** 2 + 1 / 0.05 ** 2)) ** 0.5, rel=1e-12)
