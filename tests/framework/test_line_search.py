"""The per-line search across basins (framework/stack/line_search.py): a line's
cross-section remade at the volume it had, the lines of a height field found with their axes and
widths, a thin line found from two screens where the start holds it wide and low, and a stack
run whose starts end short of its noise level searching its near fit's lines last."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid, Problem
from framework.stack.line_search import FeatureSearch, collapsed, line_features
from framework.reconstruction.reconstruction import run_reconstruction
from tests.experiments.conftest import SMALL, compose_reconstruct
from operators.stack import StackOperator
from tests.framework.test_stack import _at
from tests.operators.conftest import make_operator

M = 32


def _line(row: float, width: float, height: float, along: str = "x") -> np.ndarray:
    """A straight line (M, M) from cell 3 to cell 28, its ends ramped over 3 cells, Gaussian
    cross-section of standard deviation ``width`` cells about ``row`` (a row for along='x', a
    column for 'y')."""
    index = np.arange(M, dtype=float)
    rows, cols = np.meshgrid(index, index, indexing="ij")
    across, length = (rows, cols) if along == "x" else (cols, rows)
    ends = np.clip(np.minimum(length - 3.0, 28.0 - length) / 3.0, 0.0, 1.0)
    return height * np.exp(-0.5 * ((across - row) / width) ** 2) * ends


def _cross_section(d: np.ndarray) -> tuple[float, float]:
    """Centre and standard deviation (rows) of the column sums of a line along x."""
    profile = d[:, 10:22].sum(axis=1)
    rows = np.arange(M)
    centre = float((profile * rows).sum() / profile.sum())
    return centre, float(np.sqrt((profile * (rows - centre) ** 2).sum() / profile.sum()))


def test_a_collapsed_line_keeps_its_volume_and_takes_the_width_and_offset_asked() -> None:
    d = _line(15.0, 3.0, 0.03)
    feature = line_features(d)[0]
    assert abs(abs(feature.axis[0]) - 1.0) < 1e-6 and feature.width == pytest.approx(3.0, rel=0.12)
    thin = collapsed(d, feature, 1.2, 2.0)
    assert thin.sum() == pytest.approx(d.sum(), rel=1e-12)
    centre, width = _cross_section(thin)
    assert centre == pytest.approx(17.0, abs=0.05) and width == pytest.approx(1.2, rel=0.05)
    assert thin.max() == pytest.approx(0.03 * 3.0 / 1.2, rel=0.05)  # the same volume, 2.5 x higher


def test_the_lines_of_an_l_shape_are_found_apart_with_their_axes() -> None:
    d = np.maximum(_line(20.0, 1.5, 0.03), _line(8.0, 1.5, 0.03, along="y"))
    features = line_features(d)
    axes = sorted(round(abs(float(f.axis[0]))) for f in features[:2])
    assert len(features) >= 2 and axes == [0, 1]
    assert all(f.width == pytest.approx(1.5, rel=0.25) for f in features[:2])
    assert not (features[0].region & features[1].region).any()


def test_a_thin_line_held_wide_and_low_is_found_from_two_screens() -> None:
    truth = _line(15.3, 1.0, 0.045)
    grid = HeightGrid(M, 1.0, 0.1)
    shots = [_at(make_operator(photons=60_000, resolution=64, seed=0), z) for z in (0.05, 0.2)]
    references = [_at(make_operator(photons=400_000, resolution=64, seed=7), z) for z in (0.05, 0.2)]
    stack = StackOperator(shots)
    target = stack.stack([r.render(torch.from_numpy(truth)) for r in references])
    data = ReconstructionData(target=target, mask=torch.ones(M, M, dtype=torch.bool), volume=None, delta=0.05)
    problem = Problem(stack, data, grid, shots[0].scene)
    wide = collapsed(truth, line_features(truth)[0], 2.5, -1.0)  # the wide, low basin, a cell off
    found, metrics = FeatureSearch(problem, 60_000, seed=0)(wide)
    centre, width = _cross_section(found)
    assert metrics["feature_search_changed"] == 1.0
    assert metrics["feature_search_misfit_after"] < 0.5 * metrics["feature_search_misfit_before"]
    assert width == pytest.approx(1.0, rel=0.15) and centre == pytest.approx(15.3, abs=0.3)
    assert found.max() == pytest.approx(truth.max(), rel=0.15)


def test_a_stack_run_short_of_its_noise_level_searches_the_near_fit_s_lines_last(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "scene=print_lines", "data=stack", "data.first_fit=lines", "solver.max_iter=2",
                               "+data.common.reference_photons=200000", "+data.common.reference_resolution=128"],
                              tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    # zero (two iterations: short of the noise level), then zero_lines: the near shot's fit, its lines searched
    assert metrics["start_zero_first_fit_shot"] == 0 and "start_zero_feature_search_renders" not in metrics
    assert metrics["start_zero_lines_first_fit_iterations"] == 2
    assert metrics["start_zero_lines_feature_search_lines"] >= 1
    assert metrics["start_zero_lines_feature_search_misfit_after"] <= metrics[
        "start_zero_lines_feature_search_misfit_before"]
