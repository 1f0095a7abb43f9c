"""sfc-bench runs end to end on a tiny budget and reports every figure it promises."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from experiments.benchmarks.bench import main
from experiments.benchmarks.bench_scale import growth_exponent
from tests.python_subprocess import run_json_script


# Small reconstructions for the scale section's runs to the noise level (their grid set there).
SOLVE_TO_NOISE = ["solver.max_iter=3", "initial=zero", "photons=16384", "photon_budget.start=4096",
                  "photon_budget.photons_resolution=32", "data.reference_photons=65536", "checkpoint_every=100"]

# A small reconstruction for the bench's reconstruction section: 3 iterations from flat glass.
SMALL_RUN = ["solver.max_iter=3", "initial=zero", "photons=16384", "photon_budget.start=4096",
             "data.reference_photons=65536", "data.reference_resolution=64", "receiver.resolution=64",
             "height_field.resolution=32", "checkpoint_every=100"]


@pytest.mark.parametrize("value", ["wide", "0", "-2", "nan"])
def test_a_bad_mesh_footprint_ends_in_one_line_before_any_timing(value, capsys):
    with pytest.raises(SystemExit):
        main(["--mesh-footprint", value])
    assert f"--mesh-footprint={value!r} must be 'cell' or a number of pixels > 0" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_prints_the_promised_figures(capsys):
    main(
        [
            "--photons",
            "200000",
            "--grad-photons",
            "30000",
            "--splat-photons",
            "3000",
            "--chunk-size",
            "8192",
            "--reference-photons",
            "20000",
            "--stage-photons",
            "0",
            "--mesh-photons",  # 0: the mesh-scene section (its own test below) is left out
            "0",
            "--stack-photons",
            "20000",
            "--fidelity-photons",
            "20000",
            "--fidelity-bias-photons",
            "40000",
            "--fidelity-reference-photons",
            "40000",
            "--wavefront-vertices",
            "257",
            "--fidelity-resolutions",
            "48",
            "--wall-vertices",
            "129",
            "--scale-sizes",  # none: the scale section (its own test below) is left out
            "--scale-solve-sizes",
            "--reconstruction-overrides",
            *SMALL_RUN,
        ]
    )
    report = json.loads(capsys.readouterr().out)
    assert report["forward_photons_per_s"] > 0 and report["forward_backward_photons_per_s"] > 0
    plain = report["without_avx2_kernels"]
    assert plain["forward_photons_per_s"] > 0 and plain["forward_backward_photons_per_s"] > 0
    assert plain["simd_speedup"]["forward"] > 0 and isinstance(report["simd"], bool)
    jit = report["numba_kernels"]
    assert jit["forward_photons_per_s"] > 0 and jit["c_speedup"]["forward_backward"] > 0
    assert isinstance(report["c_kernels"], bool)
    point = report["point_sampled_pixels"]
    assert point["forward_photons_per_s"] > 0 and point["pixel_integration_cost"]["forward_backward"] > 0
    assert 0.0 < report["forward_split"]["trace_fraction"] < 1.0
    jvp = report["jacobian_vector_product"]
    assert jvp["seconds"] > 0 and jvp["over_render"] > 0 and jvp["over_gradient_pass"] > 0
    reference = report["torch_reference_path"]
    assert reference["forward_photons_per_s"] > 0 and reference["forward_backward_photons_per_s"] > 0
    comparison = report["splat_comparison"]
    assert comparison["relative_image_difference"] < 1e-5 and comparison["speedup"] > 0
    assert report["gradient_paper_photons"]["photons"] == 30000
    assert "stage_profile" not in report  # --stage-photons 0 leaves it out
    assert "mesh_scene" not in report  # --mesh-photons 0 leaves it out
    assert "scale" not in report  # --scale-sizes and --scale-solve-sizes with no sizes leave the section out
    stack = report["stack"]
    assert stack["photons_per_shot"] == 20000 and stack["render_speedup_shared"] > 0
    assert stack["shared_render_and_gradient_s"] > stack["shared_render_s"] > 0
    fidelity = report["fidelity"]
    assert set(fidelity) >= {"height_field_48px", "two_lenses_48px"}
    for scene in ("height_field", "two_lenses"):
        entry = fidelity[f"{scene}_48px"]
        assert entry["exact_seconds"] > 0
        assert set(entry) - {"exact_seconds"} == {
            "paper_splat_5px",
            "cell_footprints",
            "cell_footprints_supersampled_4x",
        }
        for design in ("paper_splat_5px", "cell_footprints", "cell_footprints_supersampled_4x"):
            figures = entry[design]
            assert 0 < figures["bias"] < 1 and 0 < figures["noise_at_budget"] < 1
            assert figures["render_seconds"] > 0 and figures["gradient_seconds"] > 0
    walls = fidelity["walls"]
    assert walls["resolution"] == 48 and walls["wavefront_vertices"] == 129
    entries = [walls[f"{scene}_screen_{screen}"] for scene in ("print_lines", "oblique_lines", "bump", "gaussian",
                                                                "letter_a") for screen in (0.05, 0.2)]
    for entry in entries:
        for kind in ("clear", "absorbing"):
            assert 0 < entry[kind]["interior"] < 1 and 0 < entry[kind]["whole"] < 1
            assert entry[kind]["gradient_seconds"] > 0
    runs = report["reconstruction"]
    for which in ("now", "earlier"):
        run = runs[which]
        assert run["iterations"] == 3 and run["renders"] >= 3 and run["gradient_passes"] >= 3
        assert run["renders_per_iteration"] == pytest.approx(run["renders"] / 3)
        assert run["passes_per_iteration"] == pytest.approx((run["renders"] + run["gradient_passes"]) / 3)
        assert run["wall_s"] > run["run_time_s"] > 0
    # the earlier solver traces the configured photons at every pass; today's starts with fewer
    assert runs["earlier"]["photon_traces"] == 16384 * (runs["earlier"]["renders"] + runs["earlier"]["gradient_passes"])
    assert runs["now"]["photon_traces"] < runs["earlier"]["photon_traces"]
    assert runs["speedup"]["photon_traces"] > 1.0


@pytest.mark.slow
def test_the_mesh_section_alone_compares_every_operator_at_the_same_photons(capsys):
    main(["--only", "mesh_scene", "--mesh-photons", "6000", "--mesh-footprint", "cell"])
    mesh = json.loads(capsys.readouterr().out)["mesh_scene"]
    assert set(mesh) == {"height_field", "mesh_scene_plain", "mesh_scene_two_lenses", "mesh_scene_two_lenses_numba",
                         "mesh_scene_two_lenses_torch_tracer"}
    assert mesh["height_field"]["iteration_time_over_height_field"] == 1.0
    assert mesh["mesh_scene_plain"]["gradient_time_over_plain_mesh_scene"] == 1.0
    assert mesh["height_field"]["gradient_time_over_height_field"] == 1.0
    assert all(m["forward_photons_per_s"] > 0 and m["forward_backward_photons_per_s"] > 0
               and m["iteration_time_over_height_field"] > 0 for m in mesh.values())
    # a solver's iteration: a render and the gradient from its image, over the height field's run just before it
    for m in mesh.values():
        assert len(m["iteration_ratios"]) == 5 and min(m["iteration_ratios"]) > 0
        assert m["iteration_time_over_height_field"] == pytest.approx(float(np.median(m["iteration_ratios"])))
        assert m["iteration_seconds"] > 0


def test_the_growth_exponent_is_the_log_log_slope():
    assert growth_exponent([128.0 ** 2, 256.0 ** 2, 512.0 ** 2], [1.0, 4.0, 16.0]) == pytest.approx(1.0)
    assert growth_exponent([1.0, 2.0, 3.0], [2.0, 2.0, 2.0]) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.slow
def test_the_scale_section_alone_times_every_size_and_stack_in_its_own_process(capsys):
    main(["--only", "scale", "--scale-sizes", "16", "32", "64", "--scale-per-pixel", "2", "--chunk-size", "8192",
          "--scale-solve-sizes", "32", "64", "--scale-solve-overrides", *SOLVE_TO_NOISE])
    scale = json.loads(capsys.readouterr().out)["scale"]
    assert set(scale["grid"]) == {"16", "32", "64"} and set(scale["stacks"]) == {"1", "2", "3"}
    assert [scale["grid"][m]["photons"] for m in ("16", "32", "64")] == [512, 2048, 8192]  # 2 a pixel
    assert scale["stack_m"] == 32 and scale["stack_photons_per_shot"] == 2048
    for case in [*scale["grid"].values(), *scale["stacks"].values()]:
        assert case["seconds"] > 0 and case["peak_rss_mb"] > 100  # a fresh process with torch loaded
    for key in ("seconds_exponent_in_samples", "memory_exponent_in_samples", "seconds_exponent_in_shots"):
        assert math.isfinite(scale[key])
    solved = scale["to_noise_level"]
    assert solved["scene"] == "print_lines" and set(solved["runs"]) == {"32", "64"}
    for run in solved["runs"].values():
        assert 1 <= run["iterations"] <= 3 and run["run_time_s"] > 0 and run["peak_rss_mb"] > 100
        assert run["photon_traces"] >= 4096 * (run["renders"] + run["gradient_passes"])
    # four times the samples: more photon-traces (the budget's start and cap scale with the receiver)
    assert solved["runs"]["64"]["photon_traces"] > solved["runs"]["32"]["photon_traces"]
    for key in ("run_time_s_exponent_in_samples", "photon_traces_exponent_in_samples"):
        assert math.isfinite(solved[key])


# The stage kernels cost 1.5 min of compiling on a cold cache; as plain Python (JIT off) the
# profile's bookkeeping runs in seconds, and every stage still does real, measurable work.
PROFILE = """
import json, numba, torch
from experiments.benchmarks.bench import make_operator, heights_print_lines, profile_stages
op = make_operator(2000, 3.0, 1000)
heights = heights_print_lines()
print(json.dumps(profile_stages(op, heights, torch.zeros(op.output_shape), 300)))
"""


@pytest.mark.slow
def test_stage_profile_times_every_stage():
    profile = run_json_script(PROFILE, NUMBA_DISABLE_JIT="1", NUMBA_NUM_THREADS="2")
    stages = ("emission_ns", "hit_search_ns", "surface_jet_ns", "optics_and_footprint_ns", "splat_ns")
    # A stage is the difference of two cumulative timings, each the best of a few runs: on a loaded
    # machine one can come out at or below zero, so each is only required to be timed (finite) and the
    # stages to add up to the forward total. How they compare is the benchmark's to print.
    assert all(math.isfinite(profile[name]) for name in stages), profile
    assert sum(profile[name] for name in stages) == pytest.approx(profile["forward_total_ns"], rel=1e-9)
    assert profile["forward_total_ns"] > 0
    assert profile["adjoint_searching_hits_ns"] > 0 and profile["adjoint_replaying_hits_ns"] > 0
    assert profile["forward_backward_total_ns"] == profile["forward_total_ns"] + profile["adjoint_replaying_hits_ns"]
    assert profile["one_surface_evaluation_ns"] > 0
    assert profile["budget_at_targets_ns"] == {"forward": 400.0, "forward_backward": 1000.0}


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without a GPU")
def test_bench_on_cuda_without_a_gpu_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["--device", "cuda"])
    assert "needs a CUDA GPU" in capsys.readouterr().err


def test_a_second_configuration_runs_beside_the_first_at_each_size_with_the_ratios(monkeypatch):
    """The scale section's ``--scale-solve-beside``: at each size the first configuration, then the
    second; iterations over the smallest size's, exponents and ratios from the runs' figures."""
    import experiments.benchmarks.bench_scale as bench_scale

    calls = []

    def fake_run(overrides, workdir, name, target):
        calls.append(name)
        m = int(next(o for o in overrides if o.startswith("receiver.resolution=")).split("=")[1])
        newton = "solver=gauss_newton" in overrides
        iterations = (20 if newton else 60) * (m // 32)
        return {"iterations": iterations, "run_time_s": (0.5 if newton else 0.25) * iterations * m * m,
                "photon_traces": 1000.0 * iterations * m * m}

    monkeypatch.setattr(bench_scale, "_in_fresh_process", fake_run)
    report = bench_scale.noise_level_report((32, 64), "bump", ["photons=4096"], ["solver=gauss_newton"])
    assert calls == ["runs32", "beside32", "runs64", "beside64"]
    assert report["iterations_over_smallest"] == {"32": 1.0, "64": 2.0}
    assert report["beside"]["overrides"] == ["solver=gauss_newton"]
    assert report["beside_over_runs"]["64"] == pytest.approx(
        {"iterations": 1 / 3, "run_time_s": 2 / 3, "photon_traces": 1 / 3})
    # seconds ~ iterations m^2 = (m^2)^1.5 when the iterations double with m
    assert report["run_time_s_exponent_in_samples"] == pytest.approx(1.5)
    assert report["beside"]["photon_traces_exponent_in_samples"] == pytest.approx(1.5)
