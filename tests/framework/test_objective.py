import math

import pytest
import torch

from framework.core.objective import DataFidelity
from tests.framework.toy import DTYPE, LinearOperator, make_problem


def test_value_gradient_and_discrepancy_match_the_normalised_formula():
    data, op, A, b, d_true, _ = make_problem()
    d = torch.rand(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(3))
    ev = data.evaluate(d)
    r = A @ d.reshape(-1) - b.reshape(-1)
    nb2 = float(b.reshape(-1) @ b.reshape(-1))
    assert ev.value == pytest.approx(0.5 * float(r @ r) / nb2, rel=1e-12)
    assert ev.rel_discrepancy == pytest.approx(math.sqrt(float(r @ r) / nb2), rel=1e-12)
    torch.testing.assert_close(ev.grad, (A.T @ r).reshape(8, 8) / nb2)
    assert data.evaluate(d, with_grad=False).grad is None
    assert data.value(d) == pytest.approx(ev.value, rel=1e-14)


def test_gradient_matches_finite_differences_and_autograd_helper():
    data, op, A, b, _, _ = make_problem()
    d = torch.rand(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(4))
    grad = data.evaluate(d).grad
    direction = torch.randn(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(5))
    eps = 1e-6
    fd = (data.value(d + eps * direction) - data.value(d - eps * direction)) / (2 * eps)
    assert fd == pytest.approx(float((grad * direction).sum()), rel=1e-7)
    x = d.clone().requires_grad_(True)
    loss = 0.5 * ((op(x) - b) ** 2).sum()
    (g_auto,) = torch.autograd.grad(loss, x)
    loss_ref, g_ref, _ = op.loss_and_grad(d, b)
    assert float(loss) == pytest.approx(loss_ref, rel=1e-12)
    torch.testing.assert_close(g_auto, g_ref)


def test_a_gradient_evaluation_reuses_the_image_of_a_value_evaluation_at_the_same_heights():
    data, op, A, b, _, _ = make_problem()
    d = torch.rand(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(6))
    value_only = data.evaluate(d, with_grad=False)
    calls = op.calls
    reused = data.evaluate(d.clone())
    assert op.calls == calls  # the operator got the image instead of rendering it again
    fresh = DataFidelity(op, b).evaluate(d)
    assert op.calls == calls + 1
    assert reused.value == pytest.approx(fresh.value, rel=1e-14) == pytest.approx(value_only.value, rel=1e-14)
    torch.testing.assert_close(reused.grad, fresh.grad, rtol=1e-14, atol=0)
    data.evaluate(d + 1e-3)  # other heights: rendered afresh
    assert op.calls == calls + 2


def test_step_unit_does_not_depend_on_brightness():
    data, op, A, b, _, _ = make_problem()
    bright = DataFidelity(LinearOperator(1000.0 * A, 8, (1, 10, 10)), 1000.0 * b)
    d = torch.full((8, 8), 0.01, dtype=DTYPE)
    assert bright.evaluate(d).value == pytest.approx(data.evaluate(d).value, rel=1e-10)
    # grad w.r.t. d scales with A / ||b||^2 * A^T A ... the relative step effect is invariant:
    step = 0.1
    d1 = d - step * data.evaluate(d).grad
    d2 = d - step * bright.evaluate(d).grad
    torch.testing.assert_close(d1, d2)


@pytest.mark.parametrize(
    "target, match",
    [
        (torch.ones(10, 10, dtype=DTYPE), "shape"),
        (torch.ones(1, 10, 9, dtype=DTYPE), "shape"),
        (torch.ones(1, 10, 10, dtype=torch.int64), "dtype"),
        (torch.full((1, 10, 10), float("nan"), dtype=DTYPE), "non-finite"),
        (torch.zeros(1, 10, 10, dtype=DTYPE), "no positive energy"),
        (-torch.ones(1, 10, 10, dtype=DTYPE) + 1.5 * torch.eye(10, dtype=DTYPE), "negative mass"),
        (torch.ones(1, 12, 12, dtype=DTYPE), "output_shape"),
    ],
)
def test_bad_targets_are_refused(target, match):
    _, op, *_ = make_problem()
    with pytest.raises(ValueError, match=match):
        DataFidelity(op, target)


def test_bad_operator_and_height_field_are_refused():
    _, op, _, b, _, _ = make_problem()
    with pytest.raises(ValueError, match=r"^operator function does not keep the operator contract: derive it from "
                                         r"operators.image_operator.ImageOperator$"):
        DataFidelity(lambda d: d, b)
    data = DataFidelity(op, b)
    with pytest.raises(ValueError, match="square"):
        data.evaluate(torch.zeros(8, 7, dtype=DTYPE))


def test_weighted_value_gradient_and_discrepancy():
    _, op, A, b, _, _ = make_problem()
    w = (torch.rand(b.shape, generator=torch.Generator().manual_seed(7), dtype=DTYPE) > 0.3).to(DTYPE)
    data = DataFidelity(op, b, weights=w)
    d = torch.rand(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(8))
    r = A @ d.reshape(-1) - b.reshape(-1)
    wr, wb = w.reshape(-1) * r, w.reshape(-1) * b.reshape(-1)
    nb2 = float(wb @ b.reshape(-1))
    ev = data.evaluate(d)
    assert ev.value == pytest.approx(0.5 * float(wr @ r) / nb2, rel=1e-12)
    assert ev.rel_discrepancy == pytest.approx(math.sqrt(float(wr @ r) / nb2), rel=1e-12)
    torch.testing.assert_close(ev.grad, (A.T @ wr).reshape(8, 8) / nb2)
    # a pixel of weight 0 may hold anything: the fit does not see it
    b_changed = b.clone().reshape(-1)
    b_changed[torch.nonzero(w.reshape(-1) == 0)[0]] += 1e3
    other = DataFidelity(op, b_changed.reshape(b.shape), weights=w).evaluate(d)
    assert other.value == pytest.approx(ev.value, rel=1e-12)


def test_a_new_operator_revision_renders_again():
    _, op, A, b, _, _ = make_problem()
    data = DataFidelity(op, b)
    d = torch.rand(8, 8, dtype=DTYPE, generator=torch.Generator().manual_seed(9))
    data.evaluate(d, with_grad=False)
    calls = op.calls
    op.revision = 1  # the setup changed (joint calibration): the cached image is stale
    data.evaluate(d)
    assert op.calls == calls + 1


@pytest.mark.parametrize("weights, match", [
    (torch.ones(1, 3, 3, dtype=DTYPE), "must match the target"),
    (torch.full((1, 10, 10), 2.0, dtype=DTYPE), r"lie in \[0, 1\]"),
    (torch.zeros(1, 10, 10, dtype=DTYPE), "zero wherever the weights"),
])
def test_bad_weights_are_refused(weights, match):
    _, op, _, b, _, _ = make_problem()
    with pytest.raises(ValueError, match=match):
        DataFidelity(op, b, weights=weights)
