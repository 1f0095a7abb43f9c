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
    assert gauss_newton < 0.25 * quasi_newton  # measured: 9 against 61


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


def test_the_curvature_of_a_photon_operator_is_one_symmetric_matrix_exact_or_by_differences():
    """Through the height-field operator: the exact product (its JVP, then its adjoint) is symmetric,
    <u, H v> = <H u, v>, as the Gauss-Newton matrix of one photon pattern must be; the forward
    difference agrees with it; a cheaper operator of fewer photons gives a matrix of its own."""
    from tests.operators.conftest import make_operator
    from tests.operators.test_fused import smooth_random_heights
    from framework.core.objective import DataFidelity

    op = make_operator(photons=40_000, resolution=24)
    d = smooth_random_heights(16, 3)
    data = DataFidelity(op, op.render(smooth_random_heights(16, 4)))
    u = smooth_random_heights(16, 5) - smooth_random_heights(16, 6)
    v = smooth_random_heights(16, 7) - smooth_random_heights(16, 8)
    hu, hv = (data.curvature_product(d, None, x, 1e-6, exact=True) for x in (u, v))
    assert float((u * hv).sum()) == pytest.approx(float((hu * v).sum()), rel=1e-10)
    image = op.render(d)
    by_difference = data.curvature_product(d, image, v, 1e-6)
    assert float(torch.linalg.vector_norm(by_difference - hv) / torch.linalg.vector_norm(hv)) < 1e-4
    fewer = op.with_photons(10_000, seed=9)
    passes = data.photon_traces
    cheap = data.curvature_product(d, fewer.render(d), v, 1e-6, operator=fewer)
    assert data.photon_traces - passes == 2 * 10_000
    assert 0.5 < float((cheap * v).sum()) / float((hv * v).sum()) < 2.0  # the same curvature, sampled
    with pytest.raises(ValueError, match="needs the operator's render at d"):
        data.curvature_product(d, None, v, 1e-6)


def test_the_curvature_settings_are_checked_in_one_line_each():
    with pytest.raises(ValueError, match="solver.gauss_newton.product='adjoint' must be one of difference, exact"):
        check_gauss_newton({"product": "adjoint"})
    with pytest.raises(ValueError, match=r"solver.gauss_newton.curvature_share=1.5 must lie in \(0, 1\]"):
        check_gauss_newton({"curvature_share": 1.5})
    with pytest.raises(ValueError, match="solver.gauss_newton.seed=-1"):
        check_gauss_newton({"seed": -1})
    with pytest.raises(ValueError, match=r"solver.gauss_newton.misfit_share=1.0 must lie in \(0, 1\) or be null"):
        check_gauss_newton({"misfit_share": 1.0})
    data, _, _ = _blur_problem()
    with pytest.raises(ValueError, match="product=exact needs an operator with a Jacobian-vector product"):
        GaussNewtonLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0),
                             regularizers=[Bounds(-1.0, 1.0)], gauss_newton={"product": "exact"})


def test_the_inexact_newton_rule_leaves_the_share_of_the_misfit_it_is_told():
    """On a linear operator the step's linear model is exact: a step whose conjugate gradients stop
    at misfit_share rho leaves a relative discrepancy of at most rho times the old one, and not far
    below (the solve is cut short there; solved out, the misfit would fall to a few per cent)."""
    data, _, _ = _blur_problem()

    def first_step(share):
        solver = GaussNewtonLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0),
                                      regularizers=[Bounds(-1.0, 1.0)],
                                      gauss_newton={"cg_iterations": 40, "cg_tolerance": 1e-9, "damping": 1e-8,
                                                    "misfit_share": share})
        before = data.evaluate(torch.zeros(12, 12, dtype=DTYPE), with_grad=False).rel_discrepancy
        record = solver.step()
        return record.rel_discrepancy / before, record.extras["gauss_newton_cg_steps"], record.extras["trials"]

    ratio, steps, trials = first_step(0.5)
    solved, all_steps, _ = first_step(None)
    assert trials == 1.0  # the full step
    assert 0.3 < ratio <= 0.5 + 1e-9
    assert solved < 0.1 and steps < all_steps


def test_the_damping_starts_again_at_a_finer_metric_and_survives_a_new_photon_count():
    from types import SimpleNamespace

    from framework.optimization.preconditioner import SobolevPreconditioner

    data, _, _ = _blur_problem()
    metric = SobolevPreconditioner(length=[0.5, 0.25], order=2.0)
    metric.setup(SimpleNamespace(pixel_area=0.25 ** 2))
    solver = GaussNewtonLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0),
                                  regularizers=[Bounds(-1.0, 1.0)], preconditioner=metric,
                                  gauss_newton={"damping": 0.3})
    solver.step()
    solver.mu = 40.0
    solver.setup_changed()  # e.g. the photon budget's next photon count: the same metric
    assert solver.mu == 40.0
    assert solver.refine(solver.state.d) and metric.stage == 1
    assert solver.mu == 0.3
    assert not solver.refine(solver.state.d) and solver.mu == 0.3  # no finer stage: nothing changes
