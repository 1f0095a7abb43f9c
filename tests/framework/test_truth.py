"""The ground truth of synthetic data has one door (framework/core/truth.py): the error measures
for everyone, the heights for the evaluation outputs alone; a problem never carries it, and a
start asks the data for the design, which data without one refuse."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from framework.core.contracts.start import StartRequest
from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid, Problem
from framework.core.truth import READERS, GroundTruth, TruthLeak, height_errors
from framework.reconstruction.run_outputs import save_outputs
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene

M = 16


def _heights(seed: int) -> torch.Tensor:
    return 0.05 * torch.rand(M, M, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _problem(data: ReconstructionData) -> Problem:
    scene = Scene(receiver=Receiver(resolution=M))
    return Problem(CausticOperator(scene, OperatorSettings(photons=4096)), data, HeightGrid(M, 1.0, 0.1), scene)


def _data(truth: GroundTruth | None = None, design: torch.Tensor | None = None) -> ReconstructionData:
    return ReconstructionData(target=torch.ones(1, M, M), mask=torch.ones(M, M, dtype=torch.bool), volume=None,
                              delta=0.05, ground_truth=truth, design=design)


def test_the_errors_are_the_papers_and_need_no_read() -> None:
    d_true, d, h = _heights(0), _heights(1), 0.1
    errors = GroundTruth(d_true).errors(d, h)
    assert errors["rel_error"] == pytest.approx(float(torch.linalg.norm(d - d_true) / torch.linalg.norm(h + d_true)))
    assert errors["rel_error_d"] == pytest.approx(float(torch.linalg.norm(d - d_true) / torch.linalg.norm(d_true)))
    assert errors == height_errors(d, d_true, h)
    assert GroundTruth(d_true).errors(d_true, h) == {"rel_error": 0.0, "rel_error_d": 0.0}


def test_a_module_outside_the_evaluation_outputs_cannot_read_the_heights() -> None:
    assert __name__ not in READERS
    with pytest.raises(TruthLeak, match=f"^{__name__} asked for the ground truth's heights"):
        GroundTruth(_heights(0)).read()


def test_the_evaluation_outputs_read_them(tmp_path: Path) -> None:
    d_true = _heights(0)
    data = _data()
    save_outputs(tmp_path, _heights(1), torch.ones(1, M, M), data, HeightGrid(M, 1.0, 0.1), 25.0, GroundTruth(d_true))
    assert np.array_equal(np.load(tmp_path / "ground_truth.npy"), d_true.numpy())


def test_a_problem_never_carries_the_truth_and_the_data_give_it_up_shot_by_shot() -> None:
    truth = GroundTruth(_heights(0))
    with pytest.raises(ValueError, match="a problem never carries the ground truth"):
        _problem(_data(truth))
    stack = _data(None)
    stack = ReconstructionData(**{**stack.__dict__, "shots": (_data(truth), _data(truth))})
    with pytest.raises(ValueError, match="a problem never carries the ground truth"):
        _problem(stack)  # a shot's truth counts too
    bare = stack.without_truth()
    assert all(shot.ground_truth is None for shot in bare.shots) and stack.shots[0].ground_truth is truth
    _problem(bare)


def test_a_start_gets_the_design_the_data_carry_and_data_without_one_refuse_in_one_line() -> None:
    design = _heights(2)
    request = StartRequest(_problem(_data(design=design)), Path("."))
    given = request.design()
    assert torch.equal(given, design)
    given += 1.0  # a copy: the data's design is not changed by a start
    assert torch.equal(request.problem.data.design, design)
    with pytest.raises(ValueError, match="these data carry no design of the print") as refused:
        StartRequest(_problem(_data()), Path(".")).design()
    assert "\n" not in str(refused.value)
