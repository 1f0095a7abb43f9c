"""The Jacobian-vector product J v of the height-field operator (operators/heightfield/tangent_native.py)
against central differences of its renders and against its own gradient (the dot test
<J v, w> = <v, J^T w>), through walls, Fresnel weights, several wavelengths, an extended light,
a finer receiver, a camera and a stack; and the operators that have none say so."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from operators.heightfield.operator import CausticOperator
from operators.imaging import ImagingOperator
from operators.scene import Light
from operators.stack import StackOperator
from operators.supersample import SupersampledOperator
from tests.operators.conftest import make_operator
from tests.operators.test_fused import smooth_random_heights


def _direction(m: int, seed: int) -> torch.Tensor:
    """A smooth random direction (m, m) float64."""
    return smooth_random_heights(m, seed) - smooth_random_heights(m, seed + 1)


def _central_difference(operator, d: torch.Tensor, v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    return (operator.render(d + eps * v).double() - operator.render(d - eps * v).double()) / (2.0 * eps)


def _relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(torch.linalg.vector_norm(a - b) / torch.linalg.vector_norm(b))


@pytest.mark.parametrize("fresnel, wavelengths, walls", [(False, (0.633,), "clear"), (True, (0.45, 0.65), "clear"),
                                                          (True, (0.633,), "absorbing")])
def test_the_jvp_is_the_renders_derivative_and_the_gradients_transpose(fresnel, wavelengths, walls):
    op = make_operator(photons=60_000, resolution=32, wavelengths=wavelengths, fresnel=fresnel, walls=walls,
                       chunk_size=25_000)
    d, v = smooth_random_heights(16, 3), _direction(16, 5)
    pushed = op.jvp(d, v)
    assert pushed.shape == op.output_shape and pushed.dtype == torch.float64
    numeric = _central_difference(op, d, v)
    assert float(torch.linalg.vector_norm(numeric)) > 0
    assert _relative(pushed, numeric) < 1e-5
    w = torch.rand(op.output_shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    left, right = float((pushed * w).sum()), float((op.vjp(d, w) * v).sum())
    assert left == pytest.approx(right, rel=1e-11)


def test_the_jvp_is_linear_in_the_direction():
    op = make_operator(photons=30_000, resolution=24)
    d, v, u = smooth_random_heights(16, 1), _direction(16, 2), _direction(16, 8)
    together = op.jvp(d, 2.0 * v - 0.5 * u)
    assert torch.allclose(together, 2.0 * op.jvp(d, v) - 0.5 * op.jvp(d, u), rtol=0, atol=1e-12 * float(
        together.abs().max()))
    assert float(op.jvp(d, torch.zeros_like(v)).abs().max()) == 0.0


def test_the_jvp_of_an_extended_light_goes_through_its_blur():
    point = make_operator(photons=60_000, resolution=32, chunk_size=20_000)
    scene = replace(point.scene, light=Light(shape="disc", size=0.4, points=4))
    disc = CausticOperator(scene, point.settings)
    d, v = smooth_random_heights(16, 4), _direction(16, 9)
    pushed = disc.jvp(d, v)
    assert _relative(pushed, _central_difference(disc, d, v)) < 1e-5
    assert _relative(pushed, point.jvp(d, v)) > 1e-3  # not the point light's


def test_the_jvp_passes_through_a_finer_receiver_a_camera_and_a_stack():
    fine = make_operator(photons=60_000, resolution=64, chunk_size=30_000)
    coarse = make_operator(photons=60_000, resolution=32, chunk_size=30_000)
    d, v = smooth_random_heights(16, 6), _direction(16, 11)
    supersampled = SupersampledOperator(fine, coarse.scene, 2)
    camera = ImagingOperator(lambda scene: make_operator(photons=60_000, resolution=32, chunk_size=30_000),
                             coarse.scene, psf_sigma=0.05, gain=1.7)
    stack = StackOperator([coarse, camera], [1.0, 4.0])
    for operator in (supersampled, camera, stack):
        assert operator.has_jvp
        pushed = operator.jvp(d, v)
        assert pushed.shape == operator.output_shape
        assert _relative(pushed, _central_difference(operator, d, v)) < 1e-5
        w = torch.rand(operator.output_shape, generator=torch.Generator().manual_seed(12), dtype=torch.float64)
        assert float((pushed * w).sum()) == pytest.approx(float((operator.vjp(d, w) * v).sum()), rel=1e-11)


def test_an_operator_without_forward_derivatives_says_so():
    from framework.core.contracts.checks import _Identity  # the stopping checks' operator: F(d) = 1 + d

    identity = _Identity(4)
    assert not identity.has_jvp
    with pytest.raises(NotImplementedError, match="_Identity has no Jacobian-vector product"):
        identity.jvp(torch.zeros(4, 4), torch.ones(4, 4))
