"""Nesterov momentum in the proximal-gradient solvers (framework/reconstruction/solvers/momentum.py)."""

import math

import pytest
import torch

from framework.core.objective import DataFidelity
from framework.reconstruction.solvers import BacktrackingStep, PixelLandweber
from framework.reconstruction.solvers.momentum import NesterovMomentum, check_momentum_from
from tests.framework.toy import DTYPE, Bounds, LinearOperator


def _blur_problem(m: int = 12):
    """f(d) = 1/2 ||A d - b||^2 / ||b||^2 with A a wide Gaussian blur (ill conditioned: the slow
    modes are the fine ones, as in the caustic problem) and b = A d_true."""
    x = torch.arange(m, dtype=DTYPE)
    k1 = torch.exp(-0.5 * ((x[:, None] - x[None, :]) / 1.5) ** 2)
    A = torch.kron(k1, k1)
    A = A / A.sum(dim=1, keepdim=True)
    d_true = torch.zeros(m, m, dtype=DTYPE)
    d_true[3:9, 4:6] = 0.2
    d_true[6, 2:10] = 0.1
    operator = LinearOperator(A, m, (1, m, m))
    data = DataFidelity(operator, (A @ d_true.reshape(-1)).reshape(1, m, m))
    return data, operator, d_true


def _iterations_to(data, operator, momentum_from, level: float, cap: int = 1500) -> tuple[int, int]:
    """(iterations, operator calls) until the relative discrepancy falls below ``level``."""
    solver = PixelLandweber(data, torch.zeros(12, 12, dtype=DTYPE), BacktrackingStep(1.0, grow=1.25),
                            regularizers=[Bounds(-1.0, 1.0)], momentum_from=momentum_from)
    operator.calls = 0
    while solver.iteration < cap:
        if solver.step().rel_discrepancy <= level:
            return solver.iteration, operator.calls
    raise AssertionError(f"momentum_from={momentum_from}: discrepancy {solver.history[-1].rel_discrepancy} > {level}")


def test_momentum_reaches_a_small_discrepancy_in_a_fraction_of_the_iterations_and_operator_calls():
    data, operator, _ = _blur_problem()
    plain, plain_calls = _iterations_to(data, operator, None, 5e-3)
    fast, fast_calls = _iterations_to(data, operator, 0, 5e-3)
    assert fast < 0.4 * plain  # measured: 258 against 954
    assert fast_calls < 0.4 * plain_calls  # 304 against 1264


def test_extrapolation_follows_fista_and_restarts_when_the_step_turns_against_it():
    momentum = NesterovMomentum()
    zero = torch.zeros(2, 2, dtype=DTYPE)
    assert momentum.extrapolate(zero + 1.0, zero) is None  # no previous point
    momentum.accepted(zero, keep=True)  # t: 1 -> (1 + sqrt 5) / 2
    t1 = (1.0 + math.sqrt(5.0)) / 2.0
    assert momentum.t == pytest.approx(t1)
    beta = (t1 - 1.0) / ((1.0 + math.sqrt(1.0 + 4.0 * t1 * t1)) / 2.0)
    # moving on in the direction of the last step: z+ = x+ + beta (x+ - x)
    z_plus = momentum.extrapolate(zero + 1.0, zero + 0.5)
    torch.testing.assert_close(z_plus, zero + 1.0 + beta)
    # a step back against the last one ((z - x+) . (x+ - x) > 0) restarts: no extrapolation, t = 1
    assert momentum.extrapolate(zero + 1.0, zero + 2.0) is None and momentum.t == 1.0
    momentum.accepted(zero + 1.0, keep=False)
    assert momentum.t == 1.0 and momentum.extrapolate(zero + 2.0, zero + 1.0) is None


def test_momentum_state_survives_a_checkpoint_and_bad_stages_are_refused():
    momentum = NesterovMomentum()
    momentum.accepted(torch.ones(2, 2, dtype=DTYPE), keep=True)
    restored = NesterovMomentum()
    restored.load_state_dict(momentum.state_dict())
    assert restored.t == momentum.t and torch.equal(restored.anchor, momentum.anchor)
    for bad in (-1, 1.5, True, "1"):
        with pytest.raises(ValueError, match="momentum_from"):
            check_momentum_from(bad)
