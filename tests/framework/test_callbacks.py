import math
from types import SimpleNamespace

import pytest
import torch

from regularizers.base import RegularizerContext
from regularizers.volume_hold import VolumeHold

from framework.core.solver_loop import Callback
from framework.core.callbacks import Checkpointer, GroundTruthError, MetricsHistory, ProgressBar
from framework.core.truth import GroundTruth
from framework.reconstruction.stopping import MorozovStopping, StagnationStopping
from framework.reconstruction.solvers import GradientDescent, IterationRecord, IterativeSolver
from tests.framework.toy import DTYPE, make_problem


class ScriptedSolver(IterativeSolver):
    """Replays a fixed sequence of relative discrepancies."""

    name = "scripted"

    def __init__(self, discrepancies):
        super().__init__(torch.zeros(2, 2, dtype=DTYPE))
        self.discrepancies = list(discrepancies)

    def step(self):
        k = self.state.iteration
        self.state.iteration += 1
        rec = IterationRecord(k + 1, 0.5 * self.discrepancies[k] ** 2, 0.5 * self.discrepancies[k] ** 2,
                              self.discrepancies[k], 0.1, float(k + 1))
        self.history.append(rec)
        self.state.d = torch.full((2, 2), float(k + 1), dtype=DTYPE)  # the iterate remembers its number
        return rec


class Recorder(Callback):
    def __init__(self):
        self.seen, self.started, self.result = [], 0, None

    def on_start(self, solver):
        self.started += 1

    def on_iteration(self, solver, record):
        self.seen.append(record.iteration)

    def on_end(self, solver, result):
        self.result = result


def test_morozov_stops_at_exactly_the_first_iteration_below_the_threshold():
    stop = MorozovStopping(delta=0.1, tau_dis=1.05)
    rec = Recorder()
    solver = ScriptedSolver([0.5, 0.3, 0.2, 0.106, 0.1049, 0.09, 0.08])
    result = solver.run(100, [stop, rec])
    assert result.iterations == 5 and result.stopped_by == "MorozovStopping"
    assert "discrepancy principle" in result.stop_reason and "iteration 5" in result.stop_reason
    assert rec.seen == [1, 2, 3, 4, 5] and rec.result is result  # later callbacks still see the last record


def test_morozov_threshold_is_inclusive_and_cap_wins_first():
    stop = MorozovStopping(delta=0.1, tau_dis=1.05)
    assert ScriptedSolver([0.2, stop.threshold, 0.0]).run(10, [stop]).iterations == 2
    result = ScriptedSolver([0.5, 0.4, 0.3]).run(2, [MorozovStopping(0.1, 1.05)])
    assert result.iterations == 2 and result.stopped_by == "max_iter"


def test_morozov_with_a_volume_band_waits_for_an_admissible_height_sum():
    # The scripted iterate k is k everywhere: height sum 4 k. The fit is below the threshold from
    # iteration 2 on; the band [14, 30] admits iterations 4 to 7.
    discrepancies = [0.5, 0.09, 0.08, 0.07, 0.06, 0.05, 0.04, 0.03]
    assert ScriptedSolver(discrepancies).run(100, [MorozovStopping(0.1, 1.05)]).iterations == 2
    result = ScriptedSolver(discrepancies).run(100, [MorozovStopping(0.1, 1.05, volume_band=(14.0, 30.0))])
    assert result.iterations == 4 and result.stopped_by == "MorozovStopping"
    assert "height sum 16 in the volume band [14, 30]" in result.stop_reason
    unfit = ScriptedSolver([0.5, 0.4, 0.3, 0.2, 0.15]).run(5, [MorozovStopping(0.1, 1.05, volume_band=(14.0, 30.0))])
    assert unfit.stopped_by == "max_iter"


def test_morozov_admits_a_float32_iterate_the_volume_hold_put_on_the_bands_edge():
    """The hold raises a sum below the band to its lower edge in float64; the float32 iterate's own
    sum lands up to a rounding below it, and a fit at the noise level must still stop there."""
    rng = torch.Generator().manual_seed(4)
    below_edge = 0
    for _ in range(12):
        d = (0.1 * torch.rand(256, 256, generator=rng)).float()
        hold = VolumeHold(tolerance=0.02)  # known volume: 3% above the sum, so the hold raises d by 1%
        hold.setup(RegularizerContext(mask=torch.ones(256, 256, dtype=torch.bool),
                                      volume=1.03 * float(d.double().sum()), pixel_area=1.0))
        held = hold(d)
        below_edge += float(held.sum()) < hold.band[0]
        solver = ScriptedSolver([0.01])
        record = solver.step()
        solver.state.d = held
        assert MorozovStopping(0.1, 1.05, volume_band=hold.band).on_iteration(solver, record)
    assert below_edge > 0  # the case the rule must admit occurs



@pytest.mark.parametrize("delta, tau_dis, match", [(0.05, 1.0, "tau_dis"), (0.05, 0.9, "tau_dis"),
                                                   (0.0, 1.1, "delta"), (1.5, 1.1, "delta"),
                                                   (float("nan"), 1.1, "delta")])
def test_morozov_refuses_bad_parameters(delta, tau_dis, match):
    with pytest.raises(ValueError, match=match):
        MorozovStopping(delta, tau_dis)


def test_ground_truth_error_uses_the_papers_definition_and_runs_before_other_callbacks():
    data, op, A, b, d_true, L = make_problem()
    h = 0.1
    gt = GroundTruthError(GroundTruth(d_true), substrate_thickness=h)
    hist = MetricsHistory()
    bar = ProgressBar(disable=True)
    solver = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L)
    solver.run(5, [hist, bar, gt])  # gt listed last but runs first (order -100)
    d = solver.d
    expected = float(torch.linalg.norm((h + d) - (h + d_true))) / float(torch.linalg.norm(h + d_true))
    assert hist.records[-1].extras["rel_error"] == pytest.approx(expected, rel=1e-12)
    assert hist.records[-1].extras["rel_error_d"] == pytest.approx(
        float(torch.linalg.norm(d - d_true)) / float(torch.linalg.norm(d_true)), rel=1e-12)
    cols = hist.columns()
    assert len(cols["rel_discrepancy"]) == 5 and len(cols["rel_error"]) == 5
    assert hist["iteration"] == [1.0, 2.0, 3.0, 4.0, 5.0]
    with pytest.raises(ValueError, match="substrate_thickness"):
        GroundTruthError(GroundTruth(d_true), -1.0)
    with pytest.raises(ValueError, match="GroundTruth"):
        GroundTruthError(d_true, h)  # the bare heights: the truth reaches the metrics sealed


def test_progress_bar_runs_with_postfix(capsys):
    data, *_, L = make_problem()
    solver = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L)
    result = solver.run(3, [ProgressBar(desc="M1", disable=False)])
    assert result.iterations == 3
    assert "M1" in capsys.readouterr().err


def test_checkpointer_validates_every(tmp_path):
    with pytest.raises(ValueError, match="every"):
        Checkpointer(tmp_path / "c.pt", every=0)


def test_non_callbacks_are_refused():
    with pytest.raises(ValueError, match="not a Callback"):
        ScriptedSolver([0.1]).run(1, [object()])


def test_stagnation_stops_after_patience_iterations_without_improvement_and_keeps_the_best_iterate():
    # progress until iteration 4 (0.2); 0.1999 is not a 0.1% improvement, so iterations 5..7 make
    # 3 without, but it is the lowest discrepancy and so the best iterate.
    stagnation = StagnationStopping(patience=3, min_improvement=1e-3)
    result = ScriptedSolver([0.5, 0.4, 0.3, 0.2, 0.25, 0.1999, 0.3, 0.1, 0.05]).run(9, [stagnation])
    assert result.iterations == 7 and result.stopped_by == "StagnationStopping"
    assert stagnation.best_iteration == 6 and math.isclose(stagnation.best_discrepancy, 0.1999)
    torch.testing.assert_close(stagnation.best_d, torch.full((2, 2), 6.0, dtype=DTYPE))
    assert "iteration 6" in result.stop_reason


def test_stagnation_does_not_stop_a_run_that_keeps_improving():
    stagnation = StagnationStopping(patience=2)
    result = ScriptedSolver([0.5, 0.4, 0.3, 0.2, 0.1]).run(5, [stagnation])
    assert result.stopped_by == "max_iter" and stagnation.best_iteration == 5


class RefiningSolver(ScriptedSolver):
    """A scripted solver with ``stages`` finer stages: refine(d) records d and continues."""

    def __init__(self, discrepancies, stages):
        super().__init__(discrepancies)
        self.stages, self.refined_from = stages, []

    def refine(self, d):
        if len(self.refined_from) >= self.stages:
            return False
        self.refined_from.append(float(d[0, 0]))
        return True

    def stage(self):
        return len(self.refined_from)


def test_stagnation_refines_from_the_best_iterate_before_it_stops():
    # best 0.3 at iteration 3, no progress on 4..6 -> refine from iterate 3 after iteration 6;
    # 0.2 at 7, no progress on 8..10 -> no finer stage left: stop after 10, best iterate 7.
    stagnation = StagnationStopping(patience=3)
    solver = RefiningSolver([0.5, 0.4, 0.3, 0.3, 0.31, 0.3, 0.2, 0.2, 0.25, 0.2, 0.1], stages=1)
    result = solver.run(11, [stagnation])
    assert solver.refined_from == [3.0] and stagnation.refined_at == [6]
    assert result.iterations == 10 and result.stopped_by == "StagnationStopping"
    assert stagnation.best_iteration == 7
    torch.testing.assert_close(stagnation.best_d, torch.full((2, 2), 7.0, dtype=DTYPE))


CREEPING = [0.5, 0.3, 0.2, 0.15, 0.149, 0.148, 0.147, 0.12, 0.11, 0.109, 0.1085, 0.108, 0.1075, 0.107]


def test_stagnation_refines_early_when_a_stage_removes_too_little_of_the_misfit_above_the_noise():
    # delta 0.1: r^2 - delta^2 is 0.0125 at iteration 4 and 0.011609 at 7, which keeps more than
    # 75% of it, so refine_share 0.25 (patience 3) refines after iteration 7 from its best iterate
    # although every iteration improves by more than 0.1%; the last stage creeps on to the end.
    stagnation = StagnationStopping(patience=3, refine_share=0.25)
    stagnation.setup(SimpleNamespace(data=SimpleNamespace(delta=0.1)))
    solver = RefiningSolver(CREEPING, stages=1)
    result = solver.run(len(CREEPING), [stagnation])
    assert solver.refined_from == [7.0] and stagnation.refined_at == [7]
    assert result.stopped_by == "max_iter" and stagnation.best_iteration == len(CREEPING)


@pytest.mark.parametrize("share, delta", [(None, 0.1), (0.25, None), (0.01, 0.1)])
def test_stagnation_does_not_refine_early_without_a_share_a_noise_level_or_with_a_small_share(share, delta):
    stagnation = StagnationStopping(patience=3, refine_share=share)
    stagnation.setup(SimpleNamespace(data=SimpleNamespace(delta=delta)))
    solver = RefiningSolver(CREEPING, stages=1)
    assert solver.run(len(CREEPING), [stagnation]).stopped_by == "max_iter" and solver.refined_from == []


def test_stagnation_keeps_the_lowest_discrepancy_even_below_the_improvement_threshold():
    stagnation = StagnationStopping(patience=2, min_improvement=0.1)
    result = ScriptedSolver([0.5, 0.3, 0.29, 0.28, 0.27]).run(5, [stagnation])
    assert result.iterations == 4 and stagnation.best_iteration == 4  # 0.28: lowest, though < 10% better


@pytest.mark.parametrize("kwargs", [{"patience": 0}, {"patience": 2.5}, {"min_improvement": 1.0},
                                    {"refine_share": 1.0}, {"refine_share": 0.0}, {"refine_share": "a"}])
def test_stagnation_refuses_bad_settings(kwargs):
    with pytest.raises(ValueError, match="patience|min_improvement|refine_share"):
        StagnationStopping(**kwargs)


class Unsettled(Callback):
    """Marks the first ``rounds`` iterations' calibrated geometry as still moving."""

    order = -40

    def __init__(self, rounds):
        self.rounds = rounds

    def on_iteration(self, solver, record):
        record.extras["calibration_settled"] = float(record.iteration > self.rounds)
        return False


def test_morozov_and_stagnation_wait_while_a_calibrated_geometry_still_moves():
    flat = [0.5] + [0.1] * 20  # at the noise level from iteration 2 on, never better
    assert ScriptedSolver(flat).run(30, [MorozovStopping(0.1, 1.05)]).iterations == 2
    result = ScriptedSolver(flat).run(30, [Unsettled(9), MorozovStopping(0.1, 1.05)])
    assert result.iterations == 10 and result.stopped_by == "MorozovStopping"
    # stagnation (patience 3) counts no iteration whose geometry still moved; the first settled one
    # (10) improves on the discrepancy before the geometry moved, so it stops three later
    result = ScriptedSolver(flat).run(30, [Unsettled(9), StagnationStopping(patience=3)])
    assert result.iterations == 13 and result.stopped_by == "StagnationStopping"
