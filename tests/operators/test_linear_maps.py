"""The image chain's linear pieces (operators/linear/): composition in the order ``@`` writes it,
the block mean's values, bad pieces refused, a wrong adjoint caught by the dot test, and a stage of
one's own (examples/plugins/vignetting_stage.py) in a camera's chain."""

from __future__ import annotations

import math

import pytest
import torch

from examples.plugins.vignetting_stage import Vignetting
from framework.core.contracts.linear_checks import check_linear_map
from operators.heightfield.operator import CausticOperator
from operators.imaging import ImagingOperator
from operators.linear import BlockMean, Composition, Gain, GaussianBlur, LinearMap, ShotWeights, dot_test
from tests.operators.conftest import bump, make_operator


def _random(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def test_composition_applies_the_last_first_and_flattens() -> None:
    blur, mean, gain = GaussianBlur(0.1, 0.05), BlockMean(2), Gain(3.0)
    chain = gain @ (mean @ blur)
    assert chain.maps == (gain, mean, blur)
    x = _random(2, 8, 8)
    assert torch.equal(chain.apply(x), 3.0 * mean.apply(blur.apply(x)))
    y = _random(2, 4, 4, seed=1)
    assert torch.equal(chain.adjoint(y), blur.adjoint(mean.adjoint(3.0 * y)))
    assert chain.output_shape((2, 8, 8)) == (2, 4, 4)
    scaled = 2.0 * blur
    assert isinstance(scaled.maps[0], Gain) and torch.equal(scaled.apply(x), 2.0 * blur.apply(x))


def test_the_block_mean_averages_each_block() -> None:
    fine = _random(2, 12, 12)
    assert float(BlockMean(4).apply(fine)[1, 2, 0]) == pytest.approx(float(fine[1, 8:12, 0:4].mean()), rel=1e-14)
    assert torch.equal(BlockMean(4).adjoint(torch.ones(1, 3, 3)), torch.full((1, 12, 12), 1.0 / 16.0))
    with pytest.raises(ValueError, match="no 5 x 5 blocks"):
        BlockMean(5).output_shape((1, 12, 12))


@pytest.mark.parametrize("make, message", [
    (lambda: Gain(0.0), r"^gain=0.0 must be a positive number \(image units per W per scene unit\^2\)$"),
    (lambda: Gain(math.nan), r"^gain=nan must be"),
    (lambda: BlockMean(0), r"^operator.supersample=0"),
    (lambda: ShotWeights([1.0, -2.0], 1), r"^stack weights \[1.0, -2.0\] must be one positive number per shot$"),
    (lambda: Composition([]), r"^a composition needs at least one linear map$"),
])
def test_bad_pieces_are_refused_in_one_line(make, message) -> None:
    with pytest.raises(ValueError, match=message) as error:
        make()
    assert "\n" not in str(error.value)


class _ShiftWithoutAdjoint(LinearMap):
    """A shift by one pixel whose adjoint is (wrongly) the same shift."""

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.pad(x[..., 1:], (0, 1))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.apply(y)

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(), (1, 6, 6)


def test_a_wrong_adjoint_fails_the_dot_test() -> None:
    assert dot_test(*_ShiftWithoutAdjoint.example()) > 0.01
    with pytest.raises(AssertionError, match="_ShiftWithoutAdjoint: <L x, y> and <x, L.T y> differ by"):
        check_linear_map(_ShiftWithoutAdjoint)


def test_the_stacked_weights_scale_each_shot() -> None:
    weights = ShotWeights([4.0, 0.25], 1)
    stacked = weights.apply(torch.ones(2, 3, 3))
    assert torch.equal(stacked[0], torch.full((3, 3), 2.0)) and torch.equal(stacked[1], torch.full((3, 3), 0.5))
    with pytest.raises(ValueError, match="a stack of 2 shots of 1 channels has 2 channels, got 3"):
        weights.apply(torch.ones(3, 3, 3))


def test_a_stage_of_ones_own_joins_the_cameras_chain() -> None:
    """gain V K F(d) rendered, and the camera's gradient of <G(d), w> equal to F's of K V gain w."""
    inner = make_operator(photons=20_000, resolution=32)
    stage = Vignetting(32, inner.scene.receiver.half_width, 1.5)
    camera = ImagingOperator(lambda scene: CausticOperator(scene, inner.settings), inner.scene, 0.04, 1.7, [stage])
    assert [type(piece) for piece in camera.chain.maps] == [Gain, Vignetting, BlockMean, GaussianBlur]
    d, w = bump(32), _random(1, 32, 32)
    caustic = camera.inner.render(d)
    assert torch.allclose(camera.render(d), 1.7 * stage.apply(camera.blur.apply(caustic)), rtol=1e-12, atol=0.0)
    assert float(stage.falloff[0, 0]) < 0.5 < float(stage.falloff[16, 16])  # the corners are dimmer
    expected = camera.inner.vjp(d, camera.blur.adjoint(stage.adjoint(1.7 * w)))
    assert torch.allclose(camera.vjp(d, w), expected, rtol=1e-12, atol=0.0)
