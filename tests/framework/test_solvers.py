import math
from types import SimpleNamespace

import pytest
import torch

from framework.core.registry import available, lookup
from framework.reconstruction.solvers import (BacktrackingStep, ConstantStep, GradientDescent, LineSearchFailed,
                                             PixelLandweber, SobolevPreconditioner, WaveletLandweber)
from framework.core.solver_loop import Callback
from regularizers import PostStepUpdate, Regularizer
from tests.framework.toy import DTYPE, L1, Bounds, OrthogonalTransform, SpyPostStep, WaveletL1, make_problem


def test_all_methods_are_registered():
    assert {"gradient_descent", "landweber_pixel", "landweber_wavelet"} <= set(available("solver"))
    assert lookup("solver", "landweber_wavelet") is WaveletLandweber


def test_m1_converges_to_the_least_squares_solution():
    data, op, A, b, _, L = make_problem()
    solver = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), ConstantStep(1.0 / L))
    result = solver.run(400)
    d_ls = torch.linalg.lstsq(A, b.reshape(-1, 1)).solution.reshape(8, 8)
    torch.testing.assert_close(result.d, d_ls, rtol=0, atol=1e-10)
    assert result.iterations == 400 and result.stopped_by == "max_iter"
    assert len(result.history) == 400 and result.history[-1].iteration == 400
    # one gradient evaluation per iteration plus the initial one; no extra forward passes
    assert op.calls == 401


def test_m2_backtracking_decreases_the_objective_monotonically_and_finds_the_sparse_minimiser():
    data, op, A, b, d_true, L = make_problem()
    d0 = torch.zeros(8, 8, dtype=DTYPE)
    alpha = 2e-3
    policy = BacktrackingStep(tau=20.0 / L, shrink=0.5, grow=1.5)
    solver = PixelLandweber(data, d0, policy, regularizers=[L1(alpha), Bounds(0.0, 0.3)])
    result = solver.run(150)
    objectives = [data.value(d0) + 0.0] + [r.objective for r in result.history]
    assert all(b_ <= a for a, b_ in zip(objectives, objectives[1:]))
    assert any(r.extras["trials"] > 1 for r in result.history)  # it did backtrack
    # reference: ISTA with the safe step 1/L for many iterations
    ref = PixelLandweber(data, d0, ConstantStep(1.0 / L), regularizers=[L1(alpha), Bounds(0.0, 0.3)]).run(3000)
    assert result.history[-1].objective == pytest.approx(ref.history[-1].objective, rel=1e-8)
    torch.testing.assert_close(result.d, ref.d, rtol=0, atol=1e-6)
    assert bool((result.d >= 0).all())
    support_true = d_true > 0
    assert bool((result.d[~support_true].abs() < 0.02).all())


def test_m2_applies_post_steps_after_the_prox():
    data, *_, L = make_problem()
    log: list[str] = []
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L,
                            regularizers=[L1(1e-3, log)], post_steps=[SpyPostStep(log)])
    solver.run(3)
    assert log == ["pixel_prox", "post"] * 3


def test_m3_keeps_the_paper_order_and_keeps_w_equal_to_W_d():
    data, *_, L = make_problem()
    log: list[str] = []
    W = OrthogonalTransform(8, log)
    pixel = L1(1e-4, log)
    solver = WaveletLandweber(
        data, torch.zeros(8, 8, dtype=DTYPE), ConstantStep(0.5 / L), wavelet=W,
        wavelet_regularizer=WaveletL1(W, 1e-3, log), pixel_regularizers=[pixel],
        post_steps=[SpyPostStep(log)], pixel_step_ratio=0.5,
    )
    assert log == ["forward"]  # w = W d0
    log.clear()
    result = solver.run(4)
    one = ["inverse_adjoint", "prox_coefficients", "inverse", "pixel_prox", "post", "forward"]
    assert log == one * 4
    assert pixel.steps == [0.25 / L] * 4
    torch.testing.assert_close(solver.coefficients, W.Q @ solver.d.reshape(-1))
    disc = [r.rel_discrepancy for r in result.history]
    assert disc[-1] < disc[0]


def test_m3_with_backtracking_decreases_the_objective():
    data, *_, L = make_problem()
    log: list[str] = []
    W = OrthogonalTransform(8, log)
    solver = WaveletLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(10.0 / L), wavelet=W,
                              wavelet_regularizer=WaveletL1(W, 1e-3, log), pixel_regularizers=[Bounds()])
    hist = solver.run(30).history
    assert all(b <= a for a, b in zip([r.objective for r in hist], [r.objective for r in hist][1:]))


def _schedule() -> SobolevPreconditioner:
    pre = SobolevPreconditioner(length=[0.5, 0.25])
    pre.setup(SimpleNamespace(pixel_area=0.125 ** 2))
    return pre


def test_refine_restarts_from_the_given_iterate_with_the_finer_preconditioner_and_checkpoints_the_stage():
    data, *_, L = make_problem()
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L),
                            regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    first = solver.run(3)
    best, best_objective = solver.d.clone(), first.history[-1].objective
    assert first.history[-1].extras["preconditioner_length"] == 0.5
    solver.run(5)
    assert solver.refine(best) and torch.equal(solver.d, best)
    record = solver.step()
    assert record.iteration == 6 and record.extras["preconditioner_length"] == 0.25
    assert record.objective <= best_objective  # a descent step from the restored iterate
    after = solver.d.clone()
    assert not solver.refine(best) and torch.equal(solver.d, after)  # no finer stage: nothing changes
    restored = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L),
                              regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    restored.load_state_dict(solver.state_dict())
    assert restored.preconditioner.length == 0.25


def test_a_shaped_start_begins_where_configured_and_every_built_solver_has_its_own_parts():
    data, *_, L = make_problem()
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L),
                            regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule(), shaped_start_from="finest")
    solver.begin_from_shaped_start()
    assert solver.stage() == 1 and solver.step().extras["preconditioner_length"] == 0.25
    whole = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L),
                           regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    whole.begin_from_shaped_start()
    assert whole.stage() == 0 and whole.step().extras["preconditioner_length"] == 0.5
    told = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L),
                          regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    told.begin_from_shaped_start("finest")  # a coarser grid's solution (coarse_to_fine.fine_levels_from)
    assert told.stage() == 1
    with pytest.raises(ValueError, match="solver.shaped_start_from='coarse' must be one of first, finest"):
        PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(1.0), regularizers=[Bounds()],
                       shaped_start_from="coarse")
    build = PixelLandweber.from_config(step_size={"name": "backtracking", "tau": 1e-3},
                                       regularizers={"l1_bounds": {}},
                                       preconditioner={"name": "sobolev", "length": [0.5, 0.25]})
    problem = SimpleNamespace(fidelity=data, context=None)
    first, second = build(problem, torch.zeros(8, 8, dtype=DTYPE)), build(problem, torch.zeros(8, 8, dtype=DTYPE))
    # a later run (initial=auto's next candidate) starts with tau0 and the first length, not where the last ended
    assert first.step_size is not second.step_size and first.preconditioner is not second.preconditioner
    assert first.regularizers[0] is not second.regularizers[0]


def test_refine_starts_the_step_search_afresh_from_tau0():
    data, *_, L = make_problem()
    policy = BacktrackingStep(20.0 / L, shrink=0.5, grow=1.25)
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), policy,
                            regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    solver.run(6)
    assert policy.current_step != pytest.approx(20.0 / L)  # the search has moved on
    assert solver.refine(solver.d.clone())
    assert policy.current_step == pytest.approx(20.0 / L)
    constant = ConstantStep(0.1)
    constant.reset()
    assert constant.current_step == 0.1


class _FailsOnce(BacktrackingStep):
    """Backtracking whose first search finds no decrease (as at the float floor of a render)."""

    failed = False

    def select(self, propose, objective, sq_distance, objective_now):
        if not self.failed:
            self.failed = True
            raise LineSearchFailed("no sufficient decrease (scripted)")
        return super().select(propose, objective, sq_distance, objective_now)


def test_a_failed_line_search_moves_to_the_finer_stage_and_only_then_stops_the_run():
    data, *_, L = make_problem()
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), _FailsOnce(20.0 / L),
                            regularizers=[L1(2e-3), Bounds()], preconditioner=_schedule())
    record = solver.step()
    assert record.iteration == 1 and record.extras["preconditioner_length"] == 0.25
    assert record.objective < data.value(torch.zeros(8, 8, dtype=DTYPE))
    last_stage = PixelLandweber(data, solver.d, _FailsOnce(20.0 / L), regularizers=[L1(2e-3), Bounds()],
                                preconditioner=_schedule())
    last_stage.preconditioner.refine()
    result = last_stage.run(5)
    assert result.stopped_by == "solver" and "scripted" in result.stop_reason and result.iterations == 0


def test_m3_refine_keeps_w_equal_to_W_d():
    data, *_, L = make_problem()
    W = OrthogonalTransform(8, [])
    solver = WaveletLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(10.0 / L), wavelet=W,
                              wavelet_regularizer=WaveletL1(W, 1e-3, []), pixel_regularizers=[Bounds()],
                              preconditioner=_schedule())
    solver.run(2)
    best = solver.d.clone()
    solver.run(4)
    assert solver.refine(best)
    torch.testing.assert_close(solver.coefficients, W.Q @ best.reshape(-1))
    assert solver.step().iteration == 5


class _NoProx(Regularizer):
    has_prox = False

    def value(self, d):
        return 0.0

    def prox(self, d, step):
        raise NotImplementedError


def test_solvers_refuse_what_they_cannot_use():
    data, *_ = make_problem()
    d0 = torch.zeros(8, 8, dtype=DTYPE)
    W = OrthogonalTransform(8, [])
    with pytest.raises(ValueError, match="wavelet transform"):
        WaveletLandweber(data, d0, 0.1, wavelet=None, wavelet_regularizer=WaveletL1(W, 1e-3, []))
    with pytest.raises(ValueError, match="wavelet regulariser"):
        WaveletLandweber(data, d0, 0.1, wavelet=W, wavelet_regularizer=L1(1e-3))
    with pytest.raises(ValueError, match="pixel_step_ratio"):
        WaveletLandweber(data, d0, 0.1, wavelet=W, wavelet_regularizer=WaveletL1(W, 1e-3, []), pixel_step_ratio=0)
    with pytest.raises(ValueError, match="at least one regulariser"):
        PixelLandweber(data, d0, 0.1, regularizers=[])
    with pytest.raises(ValueError, match="has_prox=False"):
        PixelLandweber(data, d0, 0.1, regularizers=[_NoProx()])
    with pytest.raises(ValueError, match="not a PostStepUpdate"):
        PixelLandweber(data, d0, 0.1, regularizers=[L1(1.0)], post_steps=[42])
    with pytest.raises(ValueError, match="d0 must be a square"):
        GradientDescent(data, torch.zeros(8, dtype=DTYPE), 0.1)
    with pytest.raises(ValueError, match="finite"):
        GradientDescent(data, torch.full((8, 8), float("nan"), dtype=DTYPE), 0.1)
    with pytest.raises(ValueError, match="DataFidelity"):
        GradientDescent(object(), d0, 0.1)
    with pytest.raises(ValueError, match="StepSizePolicy"):
        GradientDescent(data, d0, "0.1")
    with pytest.raises(ValueError, match="tau"):
        ConstantStep(-1.0)
    with pytest.raises(ValueError, match="shrink"):
        BacktrackingStep(1.0, shrink=1.5)
    with pytest.raises(ValueError, match="grow"):
        BacktrackingStep(1.0, grow=0.5)
    with pytest.raises(ValueError, match="max_iter"):
        GradientDescent(data, d0, 0.1).run(-1)


def test_context_is_passed_to_setup():
    data, *_ = make_problem()

    class NeedsSetup(L1):
        ctx = None

        def setup(self, ctx):
            self.ctx = ctx

    reg = NeedsSetup(1e-3)
    PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), 0.1, regularizers=[reg], context="CTX")
    assert reg.ctx == "CTX"


def test_divergence_and_failed_line_search_stop_the_run_cleanly():
    data, *_, L = make_problem()
    d0 = torch.zeros(8, 8, dtype=DTYPE)
    result = GradientDescent(data, d0, ConstantStep(1e200)).run(50)
    assert result.stopped_by == "solver" and "failed" in result.stop_reason
    assert bool(torch.isfinite(result.d).all())

    class Increasing(Regularizer):  # each evaluation is worse than the last: no step can give sufficient decrease
        has_prox = True
        calls = 0

        def value(self, d):
            self.calls += 1
            return 1e3 * self.calls

        def prox(self, d, step):
            return d

    solver = PixelLandweber(data, d0 + 0.01, BacktrackingStep(1.0 / L, max_trials=3), regularizers=[Increasing()])
    result = solver.run(5)
    assert result.stopped_by == "solver" and "sufficient decrease" in result.stop_reason


def test_preconditioned_m3_shrinks_in_the_preconditioners_metric_and_descends():
    from regularizers import WaveletL1 as DaubechiesL1, WaveletTransform

    data, *_, L = make_problem(m=16, n=18)
    W = WaveletTransform((16, 16), "haar", 2)
    pre = SobolevPreconditioner(length=0.25)
    pre.setup(SimpleNamespace(pixel_area=(2.0 / 15.0) ** 2))
    solver = WaveletLandweber(data, torch.zeros(16, 16, dtype=DTYPE), BacktrackingStep(10.0 / L), wavelet=W,
                              wavelet_regularizer=DaubechiesL1(5e-3, "haar", 2), pixel_regularizers=[Bounds()],
                              preconditioner=pre)
    metric = solver._shrink_metric()
    # brute force: the diagonal of W P W^* from every basis vector
    exact = torch.stack([W.forward(pre(W.inverse(e)))[i] for i, e in enumerate(torch.eye(256, dtype=DTYPE))])
    for mask, centre in W.subbands():
        assert float(metric[centre]) == pytest.approx(float(exact[centre]), rel=1e-12)
        assert bool((metric[mask] == metric[centre]).all())
    assert float(metric.max()) < 1.0 and float(metric.min()) > 0.0  # P damps, finest scales most
    start = data.value(torch.zeros(16, 16, dtype=DTYPE))
    objectives = [start] + [r.objective for r in solver.run(25).history]
    assert all(b <= a for a, b in zip(objectives, objectives[1:]))
    assert objectives[-1] < 0.5 * start


def _denoising_problem(m: int = 16, offset: float = 1.0):
    """f(d) = 1/2 ||d - b||^2 / ||b||^2 with a smooth b = c + offset, c in [-1, 1]: the minimiser
    over d >= lower is clamp(b, lower), known exactly."""
    from tests.framework.toy import LinearOperator
    from framework.core.objective import DataFidelity
    x = torch.linspace(-1.0, 1.0, m, dtype=DTYPE)
    b = torch.cos(3 * x)[:, None] * torch.sin(2 * x + 0.3)[None, :] + offset
    data = DataFidelity(LinearOperator(torch.eye(m * m, dtype=DTYPE), m, (1, m, m)), b[None])
    return data, b, 1.0 / data.target_norm_sq


def test_two_metric_steps_reach_the_constrained_minimiser_where_projected_smoothed_steps_stall():
    data, b, L = _denoising_problem()
    errors = {}
    for two_metric_from in (None, 0):
        pre = SobolevPreconditioner(length=0.25)
        pre.setup(SimpleNamespace(pixel_area=(2 / 16) ** 2))
        solver = PixelLandweber(data, torch.zeros(16, 16, dtype=DTYPE), BacktrackingStep(1.0 / L),
                                regularizers=[Bounds(1.0, 10.0)], preconditioner=pre, two_metric_from=two_metric_from)
        errors[two_metric_from] = float((solver.run(300).d - b.clamp(min=1.0)).abs().max())
    assert errors[0] < 1e-3  # measured 2.6e-4
    assert errors[None] > 0.1  # measured 0.35: P spreads the active bound's gradient, the clamp cuts it back


class _Raise(PostStepUpdate):
    """Adds a constant to every height (a post step that leaves any upper bound)."""

    def __init__(self, amount: float) -> None:
        self.amount = amount

    def __call__(self, d):
        return d + self.amount


def test_a_post_step_that_leaves_the_bounds_is_projected_back():
    from regularizers.base import RegularizerContext
    from regularizers.bounds import HeightBounds
    data, *_, L = make_problem()
    bounds = HeightBounds(0.0, 0.3)
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), ConstantStep(1.0 / L), regularizers=[bounds],
                            post_steps=[_Raise(1.0)],
                            context=RegularizerContext(mask=torch.ones(8, 8, dtype=torch.bool)))
    record = solver.step()
    assert float(solver.d.max()) == pytest.approx(0.3) and math.isfinite(record.objective)


def test_m1_keeps_every_sample_at_or_above_the_floor_and_leaves_the_rest_unconstrained():
    data, b, L = _denoising_problem(offset=0.8)  # the unconstrained minimiser b dips to -0.2
    solver = GradientDescent(data, torch.zeros(16, 16, dtype=DTYPE), ConstantStep(0.5 / L), floor=-0.1)
    lowest = []

    class Watch(Callback):
        def on_start(self, s): pass
        def on_iteration(self, s, record): lowest.append(float(s.d.min()))
        def on_end(self, s, result): pass

    result = solver.run(60, [Watch()])
    assert min(lowest) >= -0.1
    torch.testing.assert_close(result.d, b.clamp(min=-0.1), rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="negative height"):
        GradientDescent(data, torch.zeros(16, 16, dtype=DTYPE), ConstantStep(1.0), floor=0.05)


class ShrinkingPostStep(SpyPostStep):
    """A post step that moves every iterate: d scaled by 0.99."""

    def __call__(self, d):
        super().__call__(d)
        return 0.99 * d


def test_a_searched_step_moved_by_a_post_step_needs_no_render_of_its_own():
    # the first trial is tested at the finished iterate (prox, then post step), so the gradient
    # there reuses its render: the operator runs once for d0 and once per trial, none per iteration
    data, op, *_, L = make_problem()
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(tau=1.0 / L, grow=1.0),
                            regularizers=[Bounds(0.0, 0.3)], post_steps=[ShrinkingPostStep([])])
    result = solver.run(10)
    trials = sum(r.extras["trials"] for r in result.history)
    assert trials == 10 and op.calls == 1 + trials
    objectives = [r.objective for r in result.history]
    assert all(b < a for a, b in zip(objectives, objectives[1:]))


class Lowering(SpyPostStep):
    """A post step that undoes every step up from flat glass: d - 1, clamped at 0."""

    def __call__(self, d):
        super().__call__(d)
        return torch.clamp(d - 1.0, min=0.0)


def test_a_finished_trial_that_fails_the_test_hands_over_to_the_search_at_the_proximal_points():
    # every step up from flat glass is undone: F at the finished iterate does not decrease, so the
    # search goes on at the proximal point of the same step, which passes; the post step then
    # moves it back, and the gradient there needs a render of its own
    data, op, *_, L = make_problem()
    solver = PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(tau=0.01 / L, grow=1.0),
                            regularizers=[Bounds(0.0, 0.3)], post_steps=[Lowering([])])
    result = solver.run(3)
    assert [r.extras["trials"] for r in result.history] == [2.0, 2.0, 2.0]
    assert op.calls == 1 + 3 * 3
    torch.testing.assert_close(result.d, torch.zeros(8, 8, dtype=DTYPE))
