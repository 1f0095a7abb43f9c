"""The extended light's size as a calibration parameter (framework/lab/calibration.py,
``calibration.params=[light_size]``): its column against central differences, the size told by two
screens from exact photos, and the refusals."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from framework.scene.printed_shapes import make_shape
from framework.lab.calibration import JointCalibration
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.imaging import ImagingOperator
from operators.scene import Light, Receiver, Scene
from operators.stack import StackOperator
from operators.wavefront.extended import ExtendedLightReference

N = 64
SCREENS = (0.05, 0.2)
TRUE_SIZE = 2.0  # 50 mm at 25 mm per unit, 250 mm above the glass


def _scene(size: float, screen: float = SCREENS[0], resolution: int = N) -> Scene:
    return Scene(light=Light(shape="disc", size=size, points=32), receiver=Receiver(z=-screen, resolution=resolution))


def _stack(size: float) -> StackOperator:
    settings = OperatorSettings(photons=1 << 17, seed=0, dtype="float64")
    return StackOperator([ImagingOperator(lambda scene: CausticOperator(scene, settings), _scene(size, s))
                          for s in SCREENS])


def _photos(truth: torch.Tensor) -> torch.Tensor:
    """Exact caustics of ``truth`` under the true disc on both screens (wavefront triangles with exact
    pixel coverage), with 1% noise."""
    images = [ExtendedLightReference(_scene(TRUE_SIZE, s), vertices=513).render(truth) for s in SCREENS]
    clean = torch.cat(images)
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    return clean + 0.01 * float(clean.norm()) / float(noise.norm()) * noise


def test_the_size_column_matches_central_differences() -> None:
    """The calibration's column (a central difference at 0.1% of the size) against one at twice
    that step, away from the receiver's border (where wall light that the moving emission points
    switch between paths lands): measured 6%."""
    stack = _stack(1.4)
    calibration = JointCalibration(stack, ["light_size"], scene=_scene(1.4))
    d = torch.from_numpy(make_shape("print_lines", N))
    _, jac = calibration.jacobian(d, ["light_size"])
    h = 3e-3
    numeric = (calibration.setup_of.render(d, {"light_size": 1.4 + h})
               - calibration.setup_of.render(d, {"light_size": 1.4 - h})) / (2 * h)
    inner = (slice(None), slice(3, -3), slice(3, -3))
    assert float((jac[0] - numeric)[inner].norm()) < 0.1 * float(jac[0][inner].norm())
    calibration.setup_of.apply({"light_size": 1.6})
    assert [shot.scene.light.size for shot in stack.shots] == [1.6, 1.6]
    assert [shot.scene.receiver.z for shot in stack.shots] == [-0.05, -0.2]  # each screen keeps its distance


def test_two_screens_tell_the_disc_s_size_at_the_true_heights(tmp_path) -> None:
    """From a 30% small start (35 mm for 50 mm), six updates at the true heights: the size within
    10% (measured 0.9%), the standard error below it."""
    truth = torch.from_numpy(make_shape("print_lines", N))
    stack = _stack(1.4)
    calibration = JointCalibration(stack, ["gain", "light_size"], scene=_scene(1.4))
    calibration.setup(_photos(truth), None, 0.01, tmp_path / "calibration.json")
    for _ in range(6):
        values = calibration.update(truth)
    assert values["light_size"] == pytest.approx(TRUE_SIZE, rel=0.1)
    report = calibration.report()
    assert report["calibration_light_size_mm"] == pytest.approx(values["light_size"] * 25.0)
    assert 0 < report["calibration_light_size_std"] < 0.1 * TRUE_SIZE
    assert "calibration_light_size_at_bound" not in report  # no ruler's bound: a weak prior only


def test_a_point_light_s_size_is_refused_in_one_line() -> None:
    settings = OperatorSettings(photons=1 << 12, seed=0, dtype="float64")
    point = dataclasses.replace(_scene(1.0), light=Light())
    op = ImagingOperator(lambda scene: CausticOperator(scene, settings), point)
    with pytest.raises(ValueError, match=r"^calibration.params has light_size but light.shape=point") as error:
        JointCalibration(op, ["light_size"])
    assert "\n" not in str(error.value)


def test_a_size_that_moved_asks_for_a_refit() -> None:
    stack = _stack(1.4)
    calibration = JointCalibration(stack, ["gain", "light_size"], scene=_scene(1.4))
    before = calibration.values()
    calibration.setup_of.apply({"light_size": 1.42})
    assert not calibration.needs_refit(before)  # 1.4%: within REFIT_SHARE
    calibration.setup_of.apply({"light_size": 1.96})
    assert calibration.needs_refit(before)
    assert calibration.describe_move(before) == "light_size 35 -> 49 mm"
    widths = JointCalibration(_stack(1.4), ["gain"], scene=_scene(1.4))
    assert not widths.needs_refit(widths.values())  # the size is not calibrated
