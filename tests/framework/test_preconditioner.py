"""The Sobolev gradient preconditioner against dense linear algebra, and its effect in a solver."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from framework.core.objective import DataFidelity
from framework.reconstruction.solvers import BacktrackingStep, GradientDescent, SobolevPreconditioner
from tests.framework.toy import DTYPE, LinearOperator


def neumann_laplacian_2d(m: int) -> torch.Tensor:
    """Dense negative Laplacian (m^2, m^2) on an m x m grid with reflecting borders (unit spacing)."""
    one = torch.diag(torch.full((m,), 2.0, dtype=DTYPE)) - torch.diag(torch.ones(m - 1, dtype=DTYPE), 1) \
        - torch.diag(torch.ones(m - 1, dtype=DTYPE), -1)
    one[0, 0] = one[-1, -1] = 1.0
    eye = torch.eye(m, dtype=DTYPE)
    return torch.kron(eye, one) + torch.kron(one, eye)


class LaplacianCaustic(LinearOperator):
    """F(d) = 1 - Laplace d: a flat irradiance plus the transport-of-intensity term (positive images)."""

    def __init__(self, lap: torch.Tensor, m: int) -> None:
        super().__init__(lap, m, (1, m, m))

    def __call__(self, d: torch.Tensor) -> torch.Tensor:
        return 1.0 + super().__call__(d)


def preconditioner(length: float, order: float, spacing: float = 0.25) -> SobolevPreconditioner:
    p = SobolevPreconditioner(length=length, order=order)
    p.setup(SimpleNamespace(pixel_area=spacing ** 2))
    return p


@pytest.mark.parametrize("order", [1.0, 2.0])
def test_matches_the_dense_inverse_of_the_sobolev_operator(order):
    m, spacing, length = 9, 0.25, 0.4  # l = 1.6 cells
    g = torch.randn(m, m, generator=torch.Generator().manual_seed(3), dtype=DTYPE)
    cells = length / spacing
    op = torch.eye(m * m, dtype=DTYPE) + cells ** 2 * neumann_laplacian_2d(m)
    expected = torch.linalg.solve(torch.linalg.matrix_power(op, int(order)), g.reshape(-1)).reshape(m, m)
    torch.testing.assert_close(preconditioner(length, order, spacing)(g), expected, rtol=1e-10, atol=1e-12)


def test_is_symmetric_positive_definite_and_keeps_constants():
    p = preconditioner(0.5, 2.0)
    gen = torch.Generator().manual_seed(4)
    u, v = (torch.randn(16, 16, generator=gen, dtype=DTYPE) for _ in range(2))
    assert math.isclose(float((p(u) * v).sum()), float((u * p(v)).sum()), rel_tol=1e-12)
    assert float((p(u) * u).sum()) > 0.0
    torch.testing.assert_close(p(torch.full((16, 16), 3.0, dtype=DTYPE)), torch.full((16, 16), 3.0, dtype=DTYPE))
    # The finest (alternating) mode is damped by far more than a broad one.
    assert float(p(u).norm()) < 0.2 * float(u.norm())


def test_lengths_meant_for_a_grid_keep_their_cells_on_a_finer_one():
    """With grid=8, an m = 16 grid (spacing 2 / 15) smooths over the cells an m = 8 grid would: the
    dense inverse with l = 0.5 x 8 / 16 = 0.25; on m = 8 and m = 4 the lengths hold in scene units."""
    g = torch.randn(16, 16, generator=torch.Generator().manual_seed(5), dtype=DTYPE)
    for m, expected_length in ((16, 0.25), (8, 0.5), (4, 0.5)):
        spacing = 2.0 / (m - 1)
        p = SobolevPreconditioner(length=[0.5], order=1.0, grid=8)
        p.setup(SimpleNamespace(pixel_area=spacing ** 2, mask=torch.ones(m, m, dtype=torch.bool)))
        assert math.isclose(p.length, expected_length, rel_tol=1e-15)
        cells = expected_length / spacing
        op = torch.eye(m * m, dtype=DTYPE) + cells ** 2 * neumann_laplacian_2d(m)
        part = g[:m, :m]
        torch.testing.assert_close(p(part), torch.linalg.solve(op, part.reshape(-1)).reshape(m, m),
                                   rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="preconditioner grid=0"):
        SobolevPreconditioner(grid=0)


def test_bad_settings_and_missing_setup_are_refused():
    with pytest.raises(ValueError, match="length"):
        SobolevPreconditioner(length=0.0)
    with pytest.raises(ValueError, match="order"):
        SobolevPreconditioner(order=-1.0)
    with pytest.raises(RuntimeError, match="setup"):
        SobolevPreconditioner()(torch.zeros(4, 4))
    with pytest.raises(ValueError, match="square"):
        preconditioner(0.5, 2.0)(torch.zeros(4, 5))


def test_preconditioned_descent_recovers_a_broad_shape_far_faster_on_a_laplacian_operator():
    """F = -Laplace (the small-height linearisation of a caustic): its Hessian grows like |k|^4, so
    plain gradient descent barely moves broad components; the Sobolev metric of order 2 fixes that."""
    m = 16
    lap = neumann_laplacian_2d(m)
    y, x = torch.meshgrid(torch.linspace(-1, 1, m, dtype=DTYPE), torch.linspace(-1, 1, m, dtype=DTYPE), indexing="ij")
    d_true = torch.exp(-(x ** 2 + y ** 2) / 0.3)
    d_true -= d_true.mean()  # the Laplacian does not see a constant offset
    op = LaplacianCaustic(lap, m)
    target = op(d_true)

    def error_after(precond: SobolevPreconditioner | None, iterations: int = 40) -> float:
        solver = GradientDescent(DataFidelity(op, target), torch.zeros(m, m, dtype=DTYPE),
                                 BacktrackingStep(1.0, grow=2.0), preconditioner=precond)
        d = solver.run(iterations).d
        return float((d - d.mean() - d_true).norm() / d_true.norm())

    plain, sobolev = error_after(None), error_after(preconditioner(4 * 2.0 / (m - 1), 2.0, spacing=2.0 / (m - 1)))
    assert sobolev < 0.05
    assert plain > 5 * sobolev


def test_a_length_schedule_refines_coarse_to_fine_and_checkpoints_its_stage():
    g = torch.randn(12, 12, dtype=DTYPE, generator=torch.Generator().manual_seed(3))
    schedule = preconditioner([0.5, 0.25], 2.0)
    assert schedule.length == 0.5
    torch.testing.assert_close(schedule(g), preconditioner(0.5, 2.0)(g), rtol=0, atol=0)
    assert schedule.refine() and schedule.length == 0.25
    torch.testing.assert_close(schedule(g), preconditioner(0.25, 2.0)(g), rtol=0, atol=0)
    assert not schedule.refine() and schedule.length == 0.25  # the last stage stays
    restored = preconditioner([0.5, 0.25], 2.0)
    restored.load_state_dict(schedule.state_dict())
    torch.testing.assert_close(restored(g), schedule(g), rtol=0, atol=0)
    with pytest.raises(ValueError, match="stage 5"):
        restored.load_state_dict({"stage": 5})


@pytest.mark.parametrize("length, match", [([0.1, 0.2], "decrease"), ([0.1, 0.1], "decrease"), ([], "positive"),
                                           ([0.1, -0.05], "positive"), ([0.1, float("nan")], "positive")])
def test_bad_length_schedules_are_refused(length, match):
    with pytest.raises(ValueError, match=match):
        SobolevPreconditioner(length=length)
