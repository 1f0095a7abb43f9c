"""Coarse to fine (framework/reconstruction/coarse_to_fine.py): the levels, the resampling between
them and the coarse problem a level solves."""

from __future__ import annotations

import pytest
import torch

from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid, Problem
from framework.reconstruction.coarse_to_fine import CoarseToFineSettings, coarser_problem, resample_heights
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene


def test_levels_halve_the_grid_down_to_the_coarsest():
    assert CoarseToFineSettings(levels=1).resolutions(256, 256) == []
    assert CoarseToFineSettings(levels=3).resolutions(256, 512) == [(64, 128), (128, 256)]
    assert CoarseToFineSettings(levels=4, coarsest=32).resolutions(128, 128) == [(32, 32), (64, 64)]


@pytest.mark.parametrize("spec, message", [
    ({"levels": 0}, "coarse_to_fine.levels=0"),
    ({"levels": 2.5}, "coarse_to_fine.levels=2.5"),
    ({"coarsest": 4}, "coarse_to_fine.coarsest=4"),
    ({"level": 2}, "unknown key"),
    ({"fine_levels_from": "middle"}, "coarse_to_fine.fine_levels_from='middle' must be one of first, finest"),
])
def test_bad_settings_are_refused_by_name(spec, message):
    with pytest.raises(ValueError, match=message):
        CoarseToFineSettings.parse(spec)


def test_heights_resampled_keep_a_plane_and_the_substrate_edges():
    """Bilinear resampling on the samples' span is exact for a plane, both ways."""
    x = torch.linspace(-1.0, 1.0, 64, dtype=torch.float64)
    plane = 0.02 + 0.01 * x[:, None] - 0.005 * x[None, :]
    coarse = resample_heights(plane, 32)
    xc = torch.linspace(-1.0, 1.0, 32, dtype=torch.float64)
    torch.testing.assert_close(coarse, 0.02 + 0.01 * xc[:, None] - 0.005 * xc[None, :], rtol=0, atol=1e-15)
    torch.testing.assert_close(resample_heights(coarse, 64), plane, rtol=0, atol=1e-15)


def _problem(m: int, n: int) -> Problem:
    scene = Scene(receiver=Receiver(resolution=n, z=-0.05))
    operator = CausticOperator(scene, OperatorSettings(photons=1 << 14))
    target = torch.rand((1, n, n), generator=torch.Generator().manual_seed(0), dtype=torch.float64) + 0.5
    mask = torch.zeros((m, m), dtype=torch.bool)
    mask[:, m // 2] = True  # a stroke one sample wide
    data = ReconstructionData(target=target, mask=mask, volume=0.01, delta=0.05)
    return Problem(operator, data, HeightGrid(m, 1.0, 0.1), scene)


def test_a_coarse_level_sees_the_photo_averaged_and_keeps_a_thin_stroke_printed():
    problem = _problem(64, 64)
    coarse = coarser_problem(problem, 32, 32, photons=1 << 12, seed=3)
    assert tuple(coarse.operator.output_shape) == (1, 32, 32) and coarse.operator.photons == 1 << 12
    assert coarse.grid.shape == (32, 32) and coarse.grid.half_width == 1.0 and coarse.grid.base == 0.1
    # area averaging keeps the irradiance's units: the mean is the photo's, each pixel the mean of its 2 x 2
    torch.testing.assert_close(coarse.data.target.mean(), problem.data.target.mean())
    torch.testing.assert_close(coarse.data.target[0, 0, 0], problem.data.target[0, :2, :2].mean())
    assert bool(coarse.data.mask.any(dim=1).all())  # the stroke is in every row of the coarse mask
    assert int(coarse.data.mask.any(dim=0).sum()) <= 3  # ... and no wider than the dilation
    assert coarse.data.volume == problem.data.volume and coarse.data.delta == problem.data.delta


def test_a_stack_is_refused():
    problem = _problem(32, 32)
    stacked = Problem(problem.operator, ReconstructionData(
        target=problem.data.target, mask=problem.data.mask, volume=None, delta=0.05, shots=(problem.data,)),
        problem.grid, problem.scene)
    with pytest.raises(ValueError, match="coarse_to_fine.levels=1"):
        coarser_problem(stacked, 16, 16, photons=1 << 10, seed=0)
