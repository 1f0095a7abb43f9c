"""Several photos: the screens study and the lab study with two photos run end to end as MLflow
runs on a tiny budget, and their tables are written."""

from __future__ import annotations

import csv

import pytest

from experiments.paper.reproduce_stack import main

TINY = ["receiver.resolution=32", "height_field.resolution=16", "solver.max_iter=2",
        "checkpoint_every=10", "calibration.every=1", "initial=zero"]


@pytest.mark.slow
def test_screens_and_lab_studies_are_run_and_tabulated(tmp_path):
    out = tmp_path / "out"
    main(
        [
            "--part",
            "screens",
            "--scenes",
            "bump",
            "--screen-sets",
            "0.05",
            "0.05,0.2",
            "--total-photons",
            "32768",
            "--store",
            str(tmp_path / "mlruns"),
            "--work",
            str(tmp_path / "work"),
            "--out",
            str(out),
            "--overrides",
            *TINY,
            "+data.common.reference_photons=32768",
            "+data.common.reference_resolution=32",
        ]
    )
    rows = list(csv.DictReader(open(out / "stack_screens.csv")))
    assert [(r["screens"], int(r["photons_per_shot"])) for r in rows] == [("0.05", 32768), ("0.05 + 0.2", 16384)]
    assert rows[1]["first_fit_iterations"] == "2" and len(rows[1]["shot_discrepancies"].split(" / ")) == 2
    assert all(0.0 < float(r["rel_error"]) < 0.5 and float(r["photon_traces"]) > 0 for r in rows)
    main(["--part", "lab", "--lab-scenes", "bump", "--reference-photons", "32768", "--store", str(tmp_path / "mlruns"),
          "--work", str(tmp_path / "work"), "--out", str(out), "--overrides", *TINY, "photons=16384"])
    table = (out / "stack_lab.md").read_text()
    assert table.startswith("| scene | true distance | told |") and "| bump | 0.0500 | 0.0550 |" in table
