"""Fig. 7: the reconstructions with and without the lenses, of two prints, run as MLflow runs, and
the table and figure are rebuilt from their artefacts."""

from __future__ import annotations

import csv

import pytest

from experiments.paper.reproduce_fig7 import main


@pytest.mark.slow
def test_both_reconstructions_are_logged_and_tabulated(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the sweep's Hydra directory (multirun/) goes to the working directory
    main(["--store", str(tmp_path / "mlruns"), "--out", str(tmp_path / "out"), "--overrides", "photons=20000",
          "receiver.resolution=32", "height_field.resolution=16", "data.reference_photons=60000",
          "data.reference_resolution=64", "solver.max_iter=3", "checkpoint_every=10", "initial=zero"])
    rows = {(r["case"], r["scene"]): r for r in csv.DictReader(open(tmp_path / "out" / "fig7.csv"))}
    assert set(rows) == {(optics, scene) for optics in ("two lenses", "no lenses") for scene in ("print_lines", "bump")}
    for row in rows.values():
        assert int(row["iterations"]) >= 1 and int(float(row["photons"])) == 20000
        # Three small steps from flat glass leave most of the print to find.
        assert 0.0 < float(row["rel_err"]) < 0.3 and 0.0 < float(row["rel_dis"]) < 1.0
        assert float(row["s_per_iteration"]) > 0.0
    assert (tmp_path / "out" / "fig7.png").stat().st_size > 10_000
    assert "| two lenses | print_lines | 20,000 |" in (tmp_path / "out" / "fig7.md").read_text()
