"""The defect report against the design, end to end on a small print_lines problem (64 x 64 heights):
a print equal to its design reports no defect; one interruption of known size is found with its kind,
place and length; a drop that focuses before the screen found from the photo where the
reconstruction shows nothing; the files and metrics of the report; bad inputs refused before a run
opens."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from experiments.paper.defect_prints import apply_defect, feature_sites
from framework.core.problem import Problem
from framework.scene.scene_config import build_heights
from framework.defects.defect_stage import DefectSettings, report_defects
from framework.reconstruction.reconstruction import run_reconstruction
from framework.reconstruction.parts import Reconstruction
from tests.experiments.conftest import compose_reconstruct

M = 64
CELL_MM = 50.0 / (M - 1)
SMALL = ["experiment=design", f"height_field.resolution={M}", "receiver.resolution=64", "photons=131072",
         "data.reference_photons=1048576", "data.reference_resolution=128", "defects.photons=65536",
         "defects.probes=4", "defects.max_candidates=3", "defects.evaluations=30", "checkpoint_every=50"]


def _design() -> np.ndarray:
    return build_heights({"height_field": {"shape": "print_lines", "resolution": M}}).numpy()


def _run(tmp_path: Path, printed: np.ndarray, *extra: str) -> tuple[dict, dict]:
    np.save(tmp_path / "printed.npy", printed)
    cfg = compose_reconstruct([*SMALL, f"data.printed={tmp_path / 'printed.npy'}", *extra], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    return metrics, json.loads((tmp_path / "run" / "defects.json").read_text())


@pytest.mark.slow
def test_a_print_equal_to_its_design_reports_no_defect(tmp_path) -> None:
    metrics, report = _run(tmp_path, _design())
    assert metrics["defects_count"] == 0 and report["defects"] == []
    assert "No defect" in metrics["verdict"]
    sigma = np.load(tmp_path / "run" / "defect_sigma_mm.npy")
    assert sigma.shape == (M, M) and np.all(sigma > 0)
    assert (tmp_path / "run" / "defects.png").stat().st_size > 0


@pytest.mark.slow
def test_an_interruption_is_found_with_its_kind_place_and_length(tmp_path) -> None:
    design = _design()
    site = feature_sites(design, CELL_MM, 1, 10.0, np.random.default_rng(3))[0]
    printed, planned = apply_defect(design, design, site, "interruption", 1.0, 3.0, CELL_MM, 25.0)
    metrics, report = _run(tmp_path, printed)
    assert metrics["defects_count"] >= 1
    found = report["defects"][0]
    assert found["kind"] == "interruption"
    assert np.hypot(found["x_mm"] - planned.x_mm, found["y_mm"] - planned.y_mm) <= CELL_MM
    assert found["length_mm"] == pytest.approx(planned.length_mm, rel=0.4)
    assert found["confidence"] > 0.99 and metrics["defects_interruption"] >= 1
    with open(tmp_path / "run" / "defects.csv") as handle:
        assert handle.readline().startswith("number,kind,x_mm,y_mm")
    assert "1. interruption at" in metrics["verdict"] or "defects: 1. interruption at" in metrics["verdict"]


def _check(cfg: dict, tmp_path: Path) -> None:
    parts = Reconstruction.from_config(cfg, tmp_path)
    parts.check(tmp_path, tmp_path / "run")


def test_a_print_on_another_grid_is_refused_in_one_line(tmp_path) -> None:
    np.save(tmp_path / "printed.npy", np.zeros((32, 32)))
    cfg = compose_reconstruct([*SMALL, f"data.printed={tmp_path / 'printed.npy'}"], tmp_path)
    with pytest.raises(ValueError, match=r"has 32 x 32 samples, the design 64 x 64") as error:
        _check(cfg, tmp_path)
    assert "\n" not in str(error.value)


def test_a_missing_print_or_design_file_is_refused_in_one_line(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, f"data.printed={tmp_path / 'nowhere.npy'}"], tmp_path)
    with pytest.raises(FileNotFoundError, match="data.printed=.*does not exist"):
        _check(cfg, tmp_path)
    cfg = compose_reconstruct(["data=file", f"data.image={tmp_path / 'photo.npy'}", "data.mask=design",
                               f"height_field.path={tmp_path / 'design.stl'}", f"height_field.resolution={M}",
                               "receiver.resolution=64"], tmp_path)
    np.save(tmp_path / "photo.npy", np.ones((1, 64, 64)))
    with pytest.raises(FileNotFoundError, match="design.stl' does not exist"):
        _check(cfg, tmp_path)


def test_a_mesh_that_is_no_height_field_is_refused_in_one_line(tmp_path) -> None:
    import trimesh

    boxes = trimesh.creation.box((10.0, 10.0, 1.0))
    upper = boxes.copy()
    upper.apply_translation((0.0, 0.0, 5.0))
    (boxes + upper).export(tmp_path / "design.stl")
    np.save(tmp_path / "photo.npy", np.ones((1, 64, 64)))
    cfg = compose_reconstruct(["data=file", f"data.image={tmp_path / 'photo.npy'}", "data.mask=design",
                               f"height_field.path={tmp_path / 'design.stl'}", f"height_field.resolution={M}",
                               "receiver.resolution=64"], tmp_path)
    with pytest.raises(ValueError, match="is not a height field over the substrate") as error:
        _check(cfg, tmp_path)
    assert "\n" not in str(error.value)


def test_defects_on_without_a_design_and_bad_settings_are_refused(tmp_path) -> None:
    with pytest.raises(ValueError, match="l1_design .experiment=design. needs the print's design"):
        Reconstruction.from_config(compose_reconstruct(SMALL, tmp_path), tmp_path)
    with pytest.raises(ValueError, match="defects.enabled=on needs the print's design"):
        Reconstruction.from_config(compose_reconstruct([*SMALL, "defects.enabled=on", "initial=zero",
                                                        "experiment=m2v1"], tmp_path), tmp_path)
    with pytest.raises(ValueError, match="defects.enabled='sometimes'"):
        Reconstruction.from_config(compose_reconstruct([*SMALL, "experiment=m2v1", "defects.enabled=sometimes"],
                                                        tmp_path), tmp_path)
    with pytest.raises(ValueError, match="defects.grow=5.0 exceeds defects.z_min=3.0"):
        Reconstruction.from_config(
            compose_reconstruct([*SMALL, "experiment=m2v1", "defects.grow=5.0"], tmp_path), tmp_path
        )


def test_a_drop_that_focuses_before_the_screen_is_found_from_the_photo(tmp_path) -> None:
    """A 1 mm^3 drop (0.7 mm high) is a lens that focuses between the top and the screen; with the
    reconstruction held at the design (it shows nothing there), the report finds it from the photo."""
    design = _design()
    site = feature_sites(design, CELL_MM, 1, 10.0, np.random.default_rng(4))[0]
    printed, planned = apply_defect(design, design, site, "excess", 1.0, 0.0, CELL_MM, 25.0)
    np.save(tmp_path / "printed.npy", printed)
    cfg = compose_reconstruct([*SMALL, f"data.printed={tmp_path / 'printed.npy'}"], tmp_path)
    parts = Reconstruction.from_config(cfg, tmp_path)
    data = parts.data_source.load(parts.data_request(tmp_path, tmp_path / "data")).without_truth()
    problem = Problem(parts.operator, data, parts.grid, parts.scene)
    report = report_defects(problem, data.design, DefectSettings.parse(cfg.get("defects")), 0, 25.0, tmp_path)
    assert [defect.kind for defect in report.defects] == ["excess"]
    found = report.defects[0]
    assert np.hypot(found.x_mm - planned.x_mm, found.y_mm - planned.y_mm) <= CELL_MM
