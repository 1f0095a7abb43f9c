"""sfc-export on a fake run directory: the files, the printed deviation metrics, the design picked
from the run, and one-line errors with exit status 2."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from omegaconf import OmegaConf

from experiments.apps.export import main
from framework.scene.printed_shapes import make_shape
from tests.python_subprocess import ROOT

M, H, W, MM = 16, 0.1, 1.0, 20.0


def fake_run(run_dir: Path, d: np.ndarray, truth: np.ndarray | None, units: bool = True,
             data: dict | None = None) -> Path:
    """A run directory as sfc-reconstruct leaves it: heights, ground truth, the resolved config."""
    (run_dir / ".hydra").mkdir(parents=True)
    np.save(run_dir / "height_field.npy", d)
    if truth is not None:
        np.save(run_dir / "ground_truth.npy", truth)
    cfg = {"substrate": {"thickness": H, "half_width": W}, "data": data or {"name": "synthetic"},
           "height_field": {"shape": "bump", "resolution": M, "path": None, "scale": 1.0, "params": {}},
           **({"units": {"mm_per_unit": MM}} if units else {})}
    OmegaConf.save(OmegaConf.create(cfg), run_dir / ".hydra" / "config.yaml")
    return run_dir


def box(value: float) -> np.ndarray:
    d = np.zeros((M, M))
    d[5:11, 4:12] = value
    return d


@pytest.mark.slow
def test_export_of_a_synthetic_run_in_a_subprocess(tmp_path):
    run = fake_run(tmp_path / "run", box(0.04), box(0.05))
    proc = subprocess.run([sys.executable, "-m", "experiments.apps.export", str(run), "--format", "stl", "ply"],
                          cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = run / "export"
    names = ["height_field_mm.npy", "height_field_mm.png", "glass.stl", "glass.ply", "deviation.json",
             "deviation.png"]
    assert re.findall(r"^wrote (.+)$", proc.stdout, flags=re.M) == [str(out / name) for name in names]
    assert f"design: {run / 'ground_truth.npy'}" in proc.stdout
    np.testing.assert_array_equal(np.load(out / "height_field_mm.npy"), box(0.04) * MM)
    # 48 printed samples, 0.01 scene units = 0.2 mm too low each; cell (2 / 15)^2 scene units^2.
    printed = {key: float(value) for key, value in re.findall(r"^deviation (\w+) = (\S+)$", proc.stdout, flags=re.M)}
    assert printed["max_abs_mm"] == pytest.approx(0.2, rel=1e-5)
    assert printed["mean_mm"] == pytest.approx(-0.2 * 48 / 256, rel=1e-5)
    assert printed["rms_printed_mm"] == pytest.approx(0.2, rel=1e-5)
    assert printed["planned_volume_mm3"] == pytest.approx(48 * 0.05 * (2 / 15) ** 2 * MM ** 3, rel=1e-5)
    assert printed["volume_ratio"] == pytest.approx(0.8, rel=1e-5)
    assert json.loads((out / "deviation.json").read_text())["max_abs_mm"] == pytest.approx(0.2)
    mesh = trimesh.load(out / "glass.stl")
    assert mesh.is_watertight
    assert mesh.bounds[1] == pytest.approx([W * MM, W * MM, (H + 0.04) * MM])


def test_design_from_the_config_a_file_or_none(tmp_path, capsys):
    d = box(0.04)
    run = fake_run(tmp_path / "run", d, None, units=False)  # no units: 25 mm per scene unit
    main([str(run)])
    design = make_shape("bump", M)
    cell_mm3 = (2 / 15) ** 2 * 25.0 ** 3
    report = json.loads((run / "export" / "deviation.json").read_text())
    assert report["planned_volume_mm3"] == pytest.approx(design.sum() * cell_mm3)
    assert report["max_abs_mm"] == pytest.approx(np.abs(d - design).max() * 25.0)
    assert "25 mm per scene unit; design: the run's height_field" in capsys.readouterr().out

    np.save(tmp_path / "design.npy", box(0.05))
    main([str(run), "--design", str(tmp_path / "design.npy"), "--out", str(tmp_path / "file"), "--mm-per-unit", "10"])
    report = json.loads((tmp_path / "file" / "deviation.json").read_text())
    assert report["max_abs_mm"] == pytest.approx(0.1) and report["volume_ratio"] == pytest.approx(0.8)

    main([str(run), "--design", "none", "--out", str(tmp_path / "none"), "--format", "obj"])
    assert sorted(p.name for p in (tmp_path / "none").iterdir()) == ["glass.obj", "height_field_mm.npy",
                                                                     "height_field_mm.png"]


def test_a_measured_run_has_a_design_only_when_it_gave_one(tmp_path, capsys):
    photo = {"name": "photo", "mask": None}
    main([str(fake_run(tmp_path / "plain", box(0.04), None, data=photo))])  # the default scene's shape only
    assert "design: none (the run has no ground truth" in capsys.readouterr().out
    assert not (tmp_path / "plain" / "export" / "deviation.json").exists()
    main([str(fake_run(tmp_path / "declared", box(0.04), None, data={**photo, "mask": "design"}))])
    assert "design: the run's height_field" in capsys.readouterr().out


@pytest.mark.parametrize(("remove", "words"), [
    (None, "run directory"), ("height_field.npy", "heights"), (".hydra/config.yaml", "run config")])
def test_missing_run_dir_or_file_is_one_line_and_exit_status_2(tmp_path, capsys, monkeypatch, remove, words):
    monkeypatch.delenv("SFC_TRACEBACK", raising=False)
    run = tmp_path / "run"
    if remove is not None:
        fake_run(run, box(0.04), None)
        (run / remove).unlink()
    with pytest.raises(SystemExit) as stop:
        main([str(run)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    missing = run if remove is None else run / remove
    assert err.count("\n") == 1 and err.startswith(f"error: {words} {str(missing)!r} does not exist")


def test_a_missing_design_file_is_one_line_and_exit_status_2(tmp_path, capsys):
    run = fake_run(tmp_path / "run", box(0.04), None)
    with pytest.raises(SystemExit) as stop:
        main([str(run), "--design", str(tmp_path / "nope.png")])
    assert stop.value.code == 2
    assert "--design" in capsys.readouterr().err and not (run / "export").exists()


def _truncated(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _object_array(path: Path) -> None:
    np.save(path, np.array([{"heights": 1}], dtype=object), allow_pickle=True)


@pytest.mark.parametrize(("spoil", "words"), [
    (_truncated, " is corrupt or truncated (not a complete .npy array of numbers)"),
    (lambda path: path.write_bytes(b"not an npy file"), " is corrupt or truncated"),
    (lambda path: path.write_bytes(b""), " is corrupt or truncated"),
    (_object_array, " is corrupt or truncated"),
    (lambda path: np.save(path, np.full((M, M), "a")), " holds <U1 values, not an array of numbers"),
    (lambda path: np.save(path, np.where(box(1.0) > 0, np.nan, 0.0)),
     ": height field contains 48 NaN or infinite values (the first at [5, 4]: nan)"),
    (lambda path: np.save(path, np.zeros((2, M, M))),
     ": height field must be a square 2-D array, got shape (2, 16, 16)"),
    (lambda path: np.save(path, np.zeros((M, M - 1))), ": height field must be a square 2-D array, got shape (16, 15)"),
])
@pytest.mark.parametrize("name", ["height_field.npy", "ground_truth.npy"])
def test_bad_heights_files_are_one_line_naming_the_file_and_exit_status_2(tmp_path, capsys, monkeypatch, spoil,
                                                                         words, name):
    monkeypatch.delenv("SFC_TRACEBACK", raising=False)
    run = fake_run(tmp_path / "run", box(0.04), box(0.05))
    spoil(run / name)
    with pytest.raises(SystemExit) as stop:
        main([str(run)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {run / name}{words}")
    assert "re-run the reconstruction or pass another run directory" in err and "allow_pickle" not in err
    assert not (run / "export").exists()


@pytest.mark.parametrize(("out", "words"), [
    ("notes.txt/sub", "error: --out '{dir}/notes.txt/sub' cannot be made a directory ('{dir}/notes.txt' is a file)"),
    ("notes.txt", "error: --out '{dir}/notes.txt' cannot be made a directory ('{dir}/notes.txt' is a file)"),
])
def test_an_out_under_a_regular_file_is_one_line_and_exit_status_2(tmp_path, capsys, monkeypatch, out, words):
    monkeypatch.delenv("SFC_TRACEBACK", raising=False)
    run = fake_run(tmp_path / "run", box(0.04), None)
    (tmp_path / "notes.txt").write_text("a file, not a directory\n")
    with pytest.raises(SystemExit) as stop:
        main([str(run), "--out", str(tmp_path / out)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(words.format(dir=tmp_path))
    assert "pass --out a directory path that is not a file or under one" in err


def test_a_run_config_that_is_not_yaml_is_one_line_and_exit_status_2(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SFC_TRACEBACK", raising=False)
    run = fake_run(tmp_path / "run", box(0.04), None)
    (run / ".hydra" / "config.yaml").write_text("substrate: [\n")
    with pytest.raises(SystemExit) as stop:
        main([str(run)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"error: run config {str(run / '.hydra' / 'config.yaml')!r} is not readable YAML at line 2")


def test_a_run_with_a_defect_report_has_it_exported_and_said(tmp_path, capsys):
    run = fake_run(tmp_path / "run", box(0.04), box(0.03), data={"name": "synthetic", "printed": "print.npy"})
    defect = {"kind": "interruption", "x_mm": 1.5, "y_mm": -2.0, "length_mm": 1.2, "size": 0.95, "peak_mm": -0.8,
              "volume_mm3": -0.4, "evidence": 900.0, "confidence": 1.0, "model": "modulation", "params": [0, 3, 0.95]}
    (run / "defects.json").write_text(json.dumps({"settings": {"min_evidence": 50.0}, "defects": [defect]}))
    (run / "defects.csv").write_text("number,kind\n1,interruption\n")
    main([str(run)])
    out = capsys.readouterr().out
    assert "design: the run's height_field (data.printed's design)" in out  # not the print's ground truth
    assert "verdict: 1 defect: 1. interruption at (1.5, -2.0) mm, 1.2 mm long, 95% of the glass missing" in out
    assert json.loads((run / "export" / "defects.json").read_text())["defects"][0]["kind"] == "interruption"
    assert (run / "export" / "defects.csv").is_file()
