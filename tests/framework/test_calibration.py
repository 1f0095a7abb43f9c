"""Joint calibration of the setup (framework/lab/calibration.py) on real renders."""

from __future__ import annotations

import json

import pytest
import torch

from framework.lab.calibration import JointCalibration, with_setup
from operators.heightfield.operator import CausticOperator
from operators.imaging import ImagingOperator
from tests.operators.conftest import bump, make_operator

TRUE_DISTANCE, TRUE_GAIN = 0.05, 1.3


def _case(seed: int = 0):
    """Data of a bump rendered with the true setup (other photons), and a model whose screen
    distance is 10% off and whose gain is unknown."""
    truth_op = make_operator(photons=1 << 17, resolution=64, seed=seed + 1)
    truth = bump(64, sigma=0.25, height=0.06)
    target = TRUE_GAIN * truth_op.render(truth)
    model = make_operator(photons=1 << 17, resolution=64, seed=seed)
    wrong = with_setup(model.scene, {"screen_distance": 1.1 * TRUE_DISTANCE})
    op = ImagingOperator(lambda scene: CausticOperator(scene, model.settings), wrong)
    return op, truth, target


def test_distance_and_gain_are_recovered_at_the_true_heights(tmp_path) -> None:
    op, truth, target = _case()
    calibration = JointCalibration(op, ["gain", "screen_distance"])
    calibration.setup(target, None, 0.05, tmp_path / "calibration.json")
    assert calibration.never_updated() == ["gain", "screen_distance"]
    calibration.update(truth, ["gain"])
    assert calibration.never_updated() == ["screen_distance"]  # a gain-only update leaves the geometry as told
    for _ in range(4):
        values = calibration.update(truth)
    assert abs(values["screen_distance"] - TRUE_DISTANCE) < 0.01 * TRUE_DISTANCE  # from 10% off
    assert abs(values["gain"] - TRUE_GAIN) < 0.01 * TRUE_GAIN
    assert 0 < calibration.std["screen_distance"] < 0.01 * TRUE_DISTANCE
    saved = json.loads((tmp_path / "calibration.json").read_text())
    assert saved["values"] == pytest.approx(values) and saved["updates"] == 5 and calibration.never_updated() == []
    assert saved["initial"]["screen_distance"] == pytest.approx(1.1 * TRUE_DISTANCE)


def test_a_resumed_calibration_starts_where_the_state_file_ends(tmp_path) -> None:
    op, truth, target = _case()
    first = JointCalibration(op, ["gain", "screen_distance"])
    first.setup(target, None, 0.05, tmp_path / "a.json")
    first.settle_rounds = 3  # updates at the noise level that still moved the geometry
    values = first.update(truth)
    fresh, _, _ = _case()
    resumed = JointCalibration(fresh, ["gain", "screen_distance"])
    resumed.setup(target, None, 0.05, tmp_path / "b.json", resume_from=tmp_path / "a.json")
    assert resumed.values() == pytest.approx(values)
    assert resumed.settle_rounds == 3  # the limit on settling rounds counts on from where it was
    assert fresh.scene.receiver.z == pytest.approx(-values["screen_distance"])
    with pytest.raises(FileNotFoundError, match="missing.json"):
        JointCalibration(fresh, ["gain"]).setup(target, None, 0.05, tmp_path / "c.json", tmp_path / "missing.json")


def test_weighted_out_pixels_do_not_pull_the_gain(tmp_path) -> None:
    op, truth, target = _case()
    weights = torch.ones_like(target)
    weights[:, 20:30, 20:30] = 0.0
    spoiled = target.clone()
    spoiled[:, 20:30, 20:30] *= 50.0  # saturated or wrong pixels, left out of the fit
    calibration = JointCalibration(op, ["gain"])
    calibration.setup(spoiled, weights, 0.05, tmp_path / "calibration.json")
    op.set_setup(with_setup(op.scene, {"screen_distance": TRUE_DISTANCE}), 1.0)
    for _ in range(2):
        values = calibration.update(truth)
    assert abs(values["gain"] - TRUE_GAIN) < 0.01 * TRUE_GAIN


@pytest.mark.parametrize("params, match", [(["focus"], "focus"), ([], r"\[\]"), (["gain", "gain"], "gain")])
def test_bad_parameters_are_refused(params, match) -> None:
    op, _, _ = _case()
    with pytest.raises(ValueError, match=match):
        JointCalibration(op, params)


def test_a_plain_operator_is_refused() -> None:
    with pytest.raises(ValueError, match="imaging=True"):
        JointCalibration(make_operator(), ["gain"])
