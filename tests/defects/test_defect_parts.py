"""The parts of the defect report against independent truths: the design prior's proximal map, the
defect models' volumes, the candidate regions, the uncertainty map (where the caustic sees less, and
with the noise), a glass mesh read back as heights, the benchmark's defects and its matching."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from experiments.paper.defect_prints import apply_defect, feature_sites
from experiments.paper.reproduce_defects import match, size_error, write_outputs
from framework.core.contracts.checks import check_regularizer
from framework.scene.design_mesh import heights_from_mesh
from framework.scene.printed_shapes import make_shape
from framework.core.pixel_noise import pixel_noise
from framework.defects.information import column_norms, height_uncertainty
from framework.defects.models import DROP_ASPECT, Frame, apply_model, drop_volume
from framework.defects.regions import candidate_regions
from framework.files.mm_outputs import glass_mesh
from regularizers import RegularizerContext
from regularizers.l1_design import PixelL1DesignBounds

M = 64
CELL_MM = 50.0 / (M - 1)


def test_the_design_prior_is_an_exact_prox_and_keeps_the_design() -> None:
    check_regularizer(PixelL1DesignBounds(alpha=0.05))
    mask = torch.ones(8, 8, dtype=torch.bool)
    design = torch.linspace(0.0, 0.2, 64, dtype=torch.float64).reshape(8, 8)
    prior = PixelL1DesignBounds(alpha=1.0, p1=0.0, p2=0.3)
    prior.setup(RegularizerContext(mask=mask, design=design))
    assert torch.equal(prior.prox(design + 0.01, 0.02), design)  # deviations below step * alpha vanish
    moved = prior.prox(design + 0.05, 0.02)
    assert torch.allclose(moved, torch.clamp(design + 0.03, 0.0, 0.3))
    assert prior.value(design) == 0.0
    prior.setup(RegularizerContext(mask=mask))
    with pytest.raises(ValueError, match="needs the print's design"):
        prior.prox(design, 0.1)


def test_the_defect_models_change_the_design_by_their_volume() -> None:
    design = torch.from_numpy(make_shape("print_lines", M))
    frame = Frame(row=32.0, col=32.0, along=(1.0, 0.0), across=(0.0, 1.0), ridge=0.0, low=-10.0, high=10.0)
    area = (2.0 / (M - 1)) ** 2
    assert torch.equal(apply_model(design, frame, "modulation", (0.0, 6.0, 0.0), area), design)
    blob = apply_model(design, frame, "blob", (20.0, 20.0, 1e-4, 2.0), area) - design
    assert float(blob.sum()) * area == pytest.approx(1e-4, rel=1e-3)  # a drop well inside the grid
    removed = design - apply_model(design, frame, "modulation", (0.0, 6.0, 1.0), area)
    assert float(removed.min()) >= 0.0 and float(removed[25:40, 32].max()) == pytest.approx(
        float(design[25:40, 32].max()), rel=0.05
    )
    shifted = apply_model(design, frame, "shift", (0.0, 100.0, 2.0), area)  # the whole band moved 2 samples
    assert torch.allclose(shifted[:, 34], design[:, 32], atol=1e-12)


def test_a_drop_is_no_steeper_than_its_aspect_allows() -> None:
    design = torch.zeros(M, M, dtype=torch.float64)
    frame = Frame(row=32.0, col=32.0, along=(1.0, 0.0), across=(0.0, 1.0), ridge=0.0, low=-10.0, high=10.0)
    cell = 2.0 / (M - 1)
    radius = 2.0  # samples
    # the volume of a Gaussian drop of this radius whose peak is DROP_ASPECT radii high
    steepest = DROP_ASPECT * radius * cell * 2.0 * np.pi * (radius * cell) ** 2
    assert drop_volume(0.5 * steepest, radius, cell ** 2) == pytest.approx(0.5 * steepest)
    assert drop_volume(10.0 * steepest, radius, cell ** 2) == pytest.approx(steepest)
    spike = apply_model(design, frame, "blob", (32.0, 32.0, 10.0 * steepest, radius), cell ** 2)
    assert float(spike.max()) == pytest.approx(DROP_ASPECT * radius * cell, rel=1e-9)


def test_candidates_keep_peaks_and_merge_near_parts() -> None:
    e = np.zeros((40, 40))
    e[10, 10:14] = 5.0  # a strong region
    e[10, 16:18] = -4.0  # another of the other sign beside it: one candidate with the first
    e[30, 30:32] = 2.5  # weak alone: no peak above z_min
    sigma = np.ones_like(e)
    found = candidate_regions(e, sigma, np.ones_like(e, dtype=bool), 1.0, 3.0, 2.0, 3.0)
    assert len(found) == 1 and found[0].rows.size == 6 and found[0].centre == (10.0, 10.0)
    assert candidate_regions(e, sigma, np.zeros_like(e, dtype=bool), 1.0, 3.0, 2.0, 3.0) == []
    with pytest.raises(ValueError, match="sigma > 0"):
        candidate_regions(e, 0 * sigma, np.ones_like(e, dtype=bool), 1.0, 3.0, 2.0, 3.0)


def test_the_uncertainty_is_larger_where_the_caustic_sees_less_and_shrinks_with_the_noise(tmp_path) -> None:
    from experiments.apps.configs import reconstruct_config
    from framework.reconstruction.parts import Reconstruction

    cfg = reconstruct_config([f"height_field.resolution={M}", "receiver.resolution=64", "photons=262144"])
    parts = Reconstruction.from_config(cfg, tmp_path)
    design = parts.design(tmp_path).to(parts.operator.dtype)
    target = parts.operator.render(design).double()
    norms = column_norms(parts.operator, design, None, probes=16, seed=1)
    sigma = {delta: height_uncertainty(norms, pixel_noise(target, delta, None), 1.0) for delta in (0.02, 0.05)}
    line = design >= 0.8 * float(design.max())
    flat = design <= 1e-4
    assert float(sigma[0.05][flat].median()) > 1.2 * float(sigma[0.05][line].median())  # focused light tells more
    assert torch.allclose(sigma[0.02], 0.4 * sigma[0.05])
    pixel = pixel_noise(target, 0.05, None)
    assert pixel == pytest.approx(0.05 * float(target.norm()) / target.numel() ** 0.5)


def test_a_glass_mesh_reads_back_as_its_heights(tmp_path) -> None:
    d = make_shape("letter_a", M)
    glass_mesh(d, 1.0, 0.1, 25.0).export(tmp_path / "glass.stl")
    back = heights_from_mesh(tmp_path / "glass.stl", M, 1.0, 0.1, 25.0)
    assert np.abs(back - d).max() <= 0.01 * d.max()


def test_the_benchmark_defects_have_their_planned_size() -> None:
    design = make_shape("print_lines", 128)
    cell = 50.0 / 127
    sites = feature_sites(design, cell, 3, 14.0, np.random.default_rng(0))
    assert len(sites) == 3 and all(design[s] >= 0.9 * design.max() * 0.3 for s in sites)
    drop, planned = apply_defect(design, design, sites[0], "excess", 0.5, 0.0, cell, 25.0)
    assert float((drop - design).sum()) * cell ** 2 * 25.0 == pytest.approx(0.5, rel=1e-6)
    gap, _ = apply_defect(design, design, sites[1], "interruption", 1.0, 3.0, cell, 25.0)
    assert float(gap[sites[1]]) < 0.01 * float(design[sites[1]])
    assert planned.kind == "excess" and planned.size == 0.5


def test_the_benchmark_matches_defects_by_place_and_kind() -> None:
    planned = [{"kind": "interruption", "x_mm": 0.0, "y_mm": 0.0, "length_mm": 2.0, "size": 1.0},
               {"kind": "excess", "x_mm": 10.0, "y_mm": 0.0, "length_mm": 1.0, "size": 0.5}]
    found = [{"kind": "interruption", "x_mm": 0.3, "y_mm": 0.0, "length_mm": 2.4, "size": 0.9},
             {"kind": "too_low", "x_mm": -10.0, "y_mm": 0.0, "length_mm": 3.0, "size": 0.2}]
    rows, false_alarms = match({"planned": planned, "report": {"defects": found}})
    assert rows[0]["found"] and rows[0]["kind_found"] == "interruption"
    assert rows[0]["size_error"] == pytest.approx(0.2) and rows[0]["position_error_mm"] == pytest.approx(0.3)
    assert not rows[1]["found"] and false_alarms == 1
    assert size_error(planned[1], {"size": 0.6, "length_mm": 1.0}) == pytest.approx(0.2)


def test_the_benchmark_table_of_a_method_counts_its_finds_alarms_and_heights(tmp_path) -> None:
    planned = [{"kind": "excess", "x_mm": 10.0, "y_mm": 0.0, "length_mm": 0.0, "size": 0.5}]
    cases = {("bump", "bump_1.npy", 0.05): {"planned": planned, "metrics": {"rel_error_d": 0.25},
                                            "report": {"defects": [{"kind": "excess", "x_mm": 10.5, "y_mm": 0.0,
                                                                    "length_mm": 0.0, "size": 0.4}]}},
             ("bump", "bump_2.npy", 0.05): {"planned": [], "metrics": {"rel_error_d": 0.05},
                                            "report": {"defects": [{"kind": "too_low", "x_mm": 0.0, "y_mm": 0.0,
                                                                    "length_mm": 3.0, "size": 0.2}]}}}
    write_outputs(cases, tmp_path, "tracks")
    table = (tmp_path / "defects_tracks.md").read_text()
    assert "2 prints, 1 false alarm(s) (0.50 per print)" in table
    assert "| excess | 0.5 mm3 | 1 | 1 | 0 | 0.50 | 0.20 |" in table
    assert "median 0.150, largest 0.250" in table and "experiment=tracks" in table
    assert (tmp_path / "defects_tracks.csv").is_file() and (tmp_path / "defects_tracks.png").is_file()
