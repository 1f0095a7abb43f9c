"""L-BFGS directions in the proximal-gradient solvers (framework/optimization/quasi_newton.py)."""

import pytest
import torch

from framework.reconstruction.solvers import BacktrackingStep, PixelLandweber
from framework.optimization.quasi_newton import LbfgsMemory, check_quasi_newton
from framework.optimization.step_size import LineSearchFailed, backtrack
from tests.framework.test_momentum import _blur_problem
from tests.framework.toy import DTYPE, Bounds


def _quadratic(m: int = 6, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """An SPD matrix A (m^2, m^2) with condition number 1e3 and a right-hand side."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(m * m, m * m, generator=g, dtype=DTYPE))
    A = q @ torch.diag(torch.logspace(0, 3, m * m, dtype=DTYPE)) @ q.T
    return A, torch.randn(m * m, generator=g, dtype=DTYPE)


def test_without_pairs_the_direction_is_the_preconditioned_gradient():
    memory = LbfgsMemory(4)
    grad = torch.randn(5, 5, generator=torch.Generator().manual_seed(1), dtype=DTYPE)
    torch.testing.assert_close(memory.direction(grad, lambda x: 3.0 * x), 3.0 * grad)


def test_the_newest_pair_s_secant_equation_holds_and_the_memory_is_bounded():
    A, b = _quadratic()
    grad = lambda x: (A @ x.reshape(-1) - b).reshape(6, 6)  # noqa: E731
    memory, x = LbfgsMemory(3), torch.zeros(6, 6, dtype=DTYPE)
    g = torch.Generator().manual_seed(2)
    for _ in range(5):
        step = 1e-3 * torch.randn(6, 6, generator=g, dtype=DTYPE)
        assert memory.update(step, grad(x + step) - grad(x), lambda v: v)
        x = x + step
    assert len(memory.pairs) == 3
    s, y, _ = memory.pairs[-1]
    # H y = s: the direction of y times gamma is s (to rounding), whatever P is
    torch.testing.assert_close(memory.gamma * memory.direction(y, lambda v: v), s, rtol=1e-9, atol=1e-12)
    assert memory.gamma == pytest.approx(float((s * y).sum() / (y * y).sum()))


def test_a_pair_without_positive_curvature_is_not_stored_and_pinned_samples_get_nothing():
    memory = LbfgsMemory(2)
    s = torch.ones(3, 3, dtype=DTYPE)
    assert not memory.update(s, -s, lambda v: v) and memory.pairs == []
    assert memory.update(s, 2.0 * s, lambda v: v)
    free = torch.ones(3, 3, dtype=torch.bool)
    free[0, 0] = False
    direction = memory.direction(torch.arange(9, dtype=DTYPE).reshape(3, 3) + 1.0, lambda v: v, free)
    assert direction[0, 0] == 0.0 and bool((direction[free] != 0).all())
    memory.reset()
    assert memory.pairs == [] and memory.gamma == 1.0


def test_lbfgs_solves_a_quadratic_in_a_fraction_of_the_gradient_steps():
    """On min 1/2 x^T A x - b^T x (condition 1e3) exact line searches along the L-BFGS direction
    reach a gradient 1e-6 of the first in few iterations, steepest descent not in 300."""
    A, b = _quadratic()

    def iterations(memory_size: int | None) -> int:
        x = torch.zeros(36, dtype=DTYPE)
        memory = LbfgsMemory(memory_size) if memory_size else None
        g0 = A @ x - b
        for k in range(1, 301):
            g = A @ x - b
            p = g if memory is None else memory.direction(g.reshape(6, 6), lambda v: v).reshape(-1)
            t = float(g @ p) / float(p @ A @ p)  # exact line search
            step = -t * p
            if memory is not None:
                memory.update(step.reshape(6, 6), (A @ step).reshape(6, 6), lambda v: v)
            x = x + step
            if float((A @ x - b).norm()) < 1e-6 * float(g0.norm()):
                return k
        return 301

    assert iterations(8) < 100  # measured: 69
    assert iterations(None) > 300


def test_the_solver_reaches_a_small_discrepancy_in_fewer_iterations_than_momentum():
    data, operator, _ = _blur_problem()

    def iterations_to(level: float, **kwargs) -> int:
        solver = PixelLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0, grow=1.25),
                                regularizers=[Bounds(-1.0, 1.0)], **kwargs)
        while solver.iteration < 1500:
            if solver.step().rel_discrepancy <= level:
                return solver.iteration
        raise AssertionError(f"{kwargs}: discrepancy {solver.history[-1].rel_discrepancy} > {level}")

    momentum = iterations_to(5e-3, momentum_from=0)
    quasi_newton = iterations_to(5e-3, momentum_from=0, quasi_newton={"memory": 8, "from_stage": 0})
    assert quasi_newton < 0.6 * momentum  # measured: 61 against 114


def test_the_pairs_survive_a_checkpoint_and_bad_settings_are_named():
    data, _, _ = _blur_problem()
    make = lambda: PixelLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0),  # noqa: E731
                                  regularizers=[Bounds(-1.0, 1.0)], quasi_newton={"memory": 4, "from_stage": 0})
    solver = make()
    for _ in range(6):
        solver.step()
    resumed = make()
    resumed.load_state_dict(solver.state_dict())
    assert len(resumed.lbfgs.pairs) == len(solver.lbfgs.pairs) > 0
    a, b = solver.step(), resumed.step()
    assert a.rel_discrepancy == b.rel_discrepancy
    assert check_quasi_newton({}) == {"memory": 8, "from_stage": 1}
    with pytest.raises(ValueError, match="solver.quasi_newton.memory=0 must be an integer >= 1"):
        check_quasi_newton({"memory": 0})
    with pytest.raises(ValueError, match="keys memory"):
        check_quasi_newton({"size": 3})


def test_the_shared_armijo_search_halves_to_the_first_step_of_sufficient_decrease():
    # f(x) = x^2 from x = 1 along -f'(1) = -2 (slope -4): tau = 1 overshoots to f = 1, which fails
    # 1 - 1e-4 * 4; tau = 0.5 lands on the minimum.
    def evaluate(tau):
        x = 1.0 - 2.0 * tau
        return x * x, x

    tau, x, trials = backtrack(evaluate, lambda tau, _: 1.0 - 1e-4 * tau * 4.0, 1.0, 0.5, 10)
    assert (tau, x, trials) == (0.5, 0.0, 2)
    with pytest.raises(LineSearchFailed, match=r"no sufficient decrease after 3 trials \(last tau=0.25"):
        backtrack(lambda tau: (float("nan"), None), lambda tau, _: 0.0, 1.0, 0.5, 3)


def test_a_pair_of_too_little_curvature_for_the_tolerance_is_not_stored():
    # s^T y = 1e-13: positive, but below the design solver's 1e-12 ||s|| ||y|| = 2e-12.
    s = torch.zeros(4, 4, dtype=DTYPE)
    y = torch.zeros(4, 4, dtype=DTYPE)
    s[0, 0], s[1, 1], y[0, 0], y[1, 1] = 1.0, 1.0, 1.0, -1.0 + 1e-13
    memory = LbfgsMemory(2)
    assert not memory.update(s, y, lambda x: x, tolerance=1e-12) and memory.pairs == []
    assert memory.update(s, 2.0 * s, lambda x: x, tolerance=1e-12) and memory.gamma == pytest.approx(0.5)
