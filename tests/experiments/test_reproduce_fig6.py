"""The Fig. 6 table and figure are built from the runs' artefacts, with the paper's numbers beside."""

from __future__ import annotations

import csv

import numpy as np

from experiments.paper.reproduce_fig6 import METHODS, SCENES, paper_numbers, write_figure, write_table


def fake_case(rng: np.random.Generator, error: float) -> dict:
    truth = rng.random((16, 16))
    return {"metrics": {"rel_discrepancy": 0.06, "rel_error": error, "rel_error_d": 4 * error, "iterations": 3,
                        "run_time_s": 2.0},
            "height_field": truth + error, "ground_truth": truth, "caustic_target": rng.random((1, 32, 32)),
            "caustic_predicted": rng.random((1, 32, 32))}


def test_table_and_figure_from_the_cases(tmp_path):
    rng = np.random.default_rng(0)
    cases = {(method, label): fake_case(rng, 0.1 * (k + 1))
             for k, method in enumerate(METHODS.values()) for label in SCENES.values()}
    del cases[("Schwartzburg (light on glass)", "A")]  # a missing run leaves a gap, not an error
    write_table(cases, tmp_path)
    write_figure(cases, tmp_path)
    rows = list(csv.DictReader(open(tmp_path / "fig6.csv")))
    assert len(rows) == 5 and (tmp_path / "fig6.png").stat().st_size > 10_000
    lines = {(r["method"], r["scene"]): r for r in rows}
    assert float(lines[("Schwartzburg", "Lines")]["paper_rel_err"]) == 1.0217
    assert float(lines[("M2V1", "A")]["paper_rel_dis"]) == 0.0548
    assert float(lines[("Schwartzburg", "A")]["rel_err"]) == 0.2
    assert paper_numbers("Schwartzburg (light on glass)", "A") == paper_numbers("Schwartzburg", "A")
    assert "| M2V1 | Lines | 0.0600 | 0.1000 |" in (tmp_path / "fig6.md").read_text()
