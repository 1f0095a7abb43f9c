"""Gauss-Newton directions (framework/reconstruction/solvers/gauss_newton.py) and the data term's curvature
product (framework/core/objective.py) on a linear blur problem, where J^T J is known exactly."""

import pytest
import torch

from framework.reconstruction.solvers import BacktrackingStep, PixelLandweber
from framework.reconstruction.solvers.gauss_newton import GaussNewtonLandweber, check_gauss_newton
from tests.framework.test_momentum import _blur_problem
from tests.framework.toy import DTYPE, Bounds


def test_the_curvature_product_is_a_t_a_v_for_a_linear_operator():
    data, operator, _ = _blur_problem()
    g = torch.Generator().manual_seed(3)
    d, v = torch.randn(12, 12, generator=g, dtype=DTYPE), torch.randn(12, 12, generator=g, dtype=DTYPE)
    image = data.evaluate(d, with_grad=False).image
    product = data.curvature_product(d, image, v, fd_step=1e-3)
    A = operator.A
    expected = (A.T @ (A @ v.reshape(-1))).reshape(12, 12) / data.target_norm_sq
    torch.testing.assert_close(product, expected, rtol=1e-7, atol=1e-12)
    assert torch.equal(data.curvature_product(d, image, torch.zeros_like(v), 1e-3), torch.zeros_like(v))


def test_gauss_newton_reaches_a_small_discrepancy_in_a_fraction_of_the_quasi_newton_iterations():
    data, _, _ = _blur_problem()

    def iterations_to(level: float, make) -> int:
        solver = make()
        while solver.iteration < 1500:
            if solver.step().rel_discrepancy <= level:
                return solver.iteration
        raise AssertionError(f"discrepancy {solver.history[-1].rel_discrepancy} > {level}")

    start = lambda: torch.zeros(12, 12, dtype=DTYPE)  # noqa: E731
    quasi_newton = iterations_to(5e-3, lambda: PixelLandweber(
        data, start(), BacktrackingStep(1.0, grow=1.25), regularizers=[Bounds(-1.0, 1.0)],
        quasi_newton={"memory": 8, "from_stage": 0}))
    gauss_newton = iterations_to(5e-3, lambda: GaussNewtonLandweber(
        data, start(), BacktrackingStep(1.0, grow=1.25), regularizers=[Bounds(-1.0, 1.0)],
        gauss_newton={"cg_iterations": 10, "damping": 1e-3, "fd_step": 1e-3}))
    assert gauss_newton < 0.5 * quasi_newton  # measured: 24 against 61


def test_the_damping_survives_a_checkpoint_and_bad_settings_are_named():
    data, _, _ = _blur_problem()
    make = lambda: GaussNewtonLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0),  # noqa: E731
                                        regularizers=[Bounds(-1.0, 1.0)], gauss_newton={"cg_iterations": 4})
    solver = make()
    for _ in range(3):
        solver.step()
    resumed = make()
    resumed.load_state_dict(solver.state_dict())
    assert resumed.mu == solver.mu != 0.1
    a, b = solver.step(), resumed.step()
    assert a.rel_discrepancy == b.rel_discrepancy
    assert a.extras["gauss_newton_cg_steps"] >= 1
    assert check_gauss_newton(None)["cg_iterations"] == 6
    with pytest.raises(ValueError, match="solver.gauss_newton.cg_iterations=0 must be an integer >= 1"):
        check_gauss_newton({"cg_iterations": 0})
    with pytest.raises(ValueError, match=r"solver.gauss_newton.cg_tolerance=1.5 must lie in \(0, 1\)"):
        check_gauss_newton({"cg_tolerance": 1.5})
    with pytest.raises(ValueError, match="keys among"):
        check_gauss_newton({"iterations": 3})
