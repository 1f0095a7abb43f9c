"""The photon budget of a run (framework/reconstruction/photon_budget.py)."""

import math

import pytest
import torch

from framework.core.objective import DataFidelity
from framework.scene.run_settings import PhotonBudgetSettings
from framework.core.solver_loop import IterationRecord
from framework.reconstruction.photon_budget import PhotonBudget, photons_needed, receiver_scale
from tests.framework.toy import DTYPE, LinearOperator

M = 8


class NoisyRenders(LinearOperator):
    """F(d) = d plus a render noise of relative size ``scale`` / sqrt(photons), a fixed pattern per seed
    (common random numbers), as a photon operator's."""

    def __init__(self, photons: int, seed: int, scale: float, target_norm: float) -> None:
        super().__init__(torch.eye(M * M, dtype=DTYPE), M, (1, M, M))
        self.photons, self.seed, self.scale, self.target_norm = photons, seed, scale, target_norm
        pattern = torch.randn(1, M, M, generator=torch.Generator().manual_seed(seed), dtype=DTYPE)
        self.pattern = pattern / pattern.norm()

    def __call__(self, d):
        return super().__call__(d) + self.scale / math.sqrt(self.photons) * self.target_norm * self.pattern

    def variant(self, photons: int, seed: int, resolution: int) -> "NoisyRenders":
        return NoisyRenders(photons, seed, self.scale, self.target_norm)


class StagedSolver:
    """The parts of a solver the budget looks at: heights, history, stage, setup_changed."""

    def __init__(self) -> None:
        self.d = torch.full((M, M), 0.5, dtype=DTYPE)
        self.history: list[IterationRecord] = []
        self.current_stage, self.changes = 0, 0

    def stage(self) -> int:
        return self.current_stage

    def setup_changed(self) -> None:
        self.changes += 1


def _record(iteration: int, discrepancy: float) -> IterationRecord:
    return IterationRecord(iteration, 0.0, 0.0, discrepancy, 1.0, 0.0)


def _budget(cap: int = 256_000):
    target = torch.full((1, M, M), 0.5, dtype=DTYPE)
    operator = NoisyRenders(cap, seed=0, scale=0.02 * math.sqrt(1000), target_norm=float(target.norm()))
    fidelity = DataFidelity(operator, target)
    budget = PhotonBudget(fidelity, operator, start=1000, noise_share=0.1, delta=0.05, tau_dis=1.01, seed=0)
    return budget, fidelity, operator


def test_photons_needed_doubles_until_the_noise_is_allowed_and_stops_at_the_cap():
    assert photons_needed(1000, 0.02, 0.0101, 10**6) == 4000  # 0.02 / sqrt(4) = 0.01
    assert photons_needed(1000, 0.005, 0.01, 10**6) == 1000
    assert photons_needed(1000, 1.0, 1e-6, 6000) == 6000


def test_the_budget_starts_low_and_grows_as_the_misfit_falls_to_what_the_noise_level_needs():
    budget, fidelity, operator = _budget()
    solver = StagedSolver()
    budget.on_start(solver)
    assert fidelity.operator.photons == 1000 and solver.changes == 1
    record = _record(1, 0.3)
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 1000 and "render_noise" not in record.extras  # far from delta, same stage
    solver.current_stage = 1
    record = _record(2, 0.3)
    budget.on_iteration(solver, record)
    # measured at the stage change: noise 0.02 at 1000 photons; allowed sqrt(0.1 (0.3^2 - 0.05^2)) = 0.0935
    assert record.extras["render_noise"] == pytest.approx(0.02, rel=0.05)
    assert record.extras["photons"] == 1000 and solver.changes == 1
    # within 1.5 tau delta: allowed sqrt(0.1 (0.06^2 - 0.05^2)) = 0.0105, 0.02 / sqrt(4) = 0.01 -> 4000 photons
    record = _record(3, 0.06)
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 4000 and fidelity.operator.photons == 4000 and solver.changes == 2
    # the same allowance: nothing measured, nothing changes
    record = _record(4, 0.0595)
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 4000 and "render_noise" not in record.extras
    # the misfit falls: allowed sqrt(0.1 (0.052^2 - 0.05^2)) = 0.00452 < 0.01, measured again:
    # 0.02 / sqrt(32) = 0.0035 -> 32 x 1000 photons
    record = _record(5, 0.052)
    budget.on_iteration(solver, record)
    assert record.extras["render_noise"] == pytest.approx(0.02 / 2, rel=0.05)
    assert record.extras["photons"] == 32_000 and solver.changes == 3


def test_the_budget_stops_at_the_configured_photons_and_a_resumed_run_goes_on_with_its_last_budget():
    budget, fidelity, operator = _budget(cap=64_000)
    solver = StagedSolver()
    budget.on_start(solver)
    record = _record(1, 0.0505)  # at tau delta: checked against Morozov's allowance, which needs 128 k
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 64_000 and fidelity.operator is operator  # the configured operator itself
    solver.history.append(record)
    resumed, fidelity2, _ = _budget(cap=64_000)
    resumed.on_start(solver)
    assert resumed.photons == 64_000


class _Receiver:
    def __init__(self, n: int) -> None:
        self.output_shape = (1, n, n)


def test_a_finer_receiver_scales_the_photons_in_proportion_to_its_pixels_in_doublings():
    assert receiver_scale(_Receiver(128), 128) == 1  # the configured photons: nothing changes
    assert receiver_scale(_Receiver(64), 128) == 1  # a coarser receiver keeps the photons it is given
    assert receiver_scale(_Receiver(256), 128) == 4
    assert receiver_scale(_Receiver(512), 128) == 16
    assert receiver_scale(_Receiver(200), 128) == 4  # 2.44 x the pixels: the next doubling
    assert receiver_scale(_Receiver(512), None) == 1


def test_a_cap_above_the_configured_photons_lets_the_noise_level_have_what_it_needs():
    target = torch.full((1, M, M), 0.5, dtype=DTYPE)
    operator = NoisyRenders(64_000, seed=0, scale=0.02 * math.sqrt(1000), target_norm=float(target.norm()))
    fidelity = DataFidelity(operator, target)
    budget = PhotonBudget(fidelity, operator, start=1000, noise_share=0.1, delta=0.05, tau_dis=1.01, seed=0,
                          cap=256_000)
    solver = StagedSolver()
    budget.on_start(solver)
    record = _record(1, 0.0505)  # Morozov's allowance needs 128 k (the test above: stopped at 64 k)
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 128_000 and fidelity.operator.photons == 128_000
    assert budget.noise <= budget.allowance(0.0505)


def test_bad_budget_settings_are_refused_with_the_key():
    assert PhotonBudgetSettings.parse(None) == PhotonBudgetSettings(None, 0.5)
    assert PhotonBudgetSettings.parse({"start": 1000, "photons_resolution": 128}).photons_resolution == 128
    with pytest.raises(ValueError, match=r"photon_budget.photons_resolution=0 must be a receiver resolution >= 1"):
        PhotonBudgetSettings.parse({"start": 1000, "photons_resolution": 0})
    with pytest.raises(ValueError, match="photon_budget.start=0"):
        PhotonBudgetSettings.parse({"start": 0})
    with pytest.raises(ValueError, match="photon_budget.noise_share=2"):
        PhotonBudgetSettings.parse({"start": 1000, "noise_share": 2})
    with pytest.raises(ValueError, match="unknown key"):
        PhotonBudgetSettings.parse({"begin": 1000})


def test_before_morozov_may_accept_the_budget_is_checked_and_the_discrepancy_measured_again():
    budget, fidelity, _ = _budget()
    solver = StagedSolver()
    budget.on_start(solver)
    record = _record(1, 0.04)  # below tau delta = 0.0505 at 1000 photons: the rule would accept it
    budget.on_iteration(solver, record)
    assert record.extras["photons"] == 128_000
    # d equals the target here, so the discrepancy is the render noise of 128 k photons: 0.02 / sqrt(128)
    assert record.rel_discrepancy == pytest.approx(0.02 / math.sqrt(128), rel=1e-6)
    assert record.data_fidelity == pytest.approx(0.5 * record.rel_discrepancy ** 2)
    # two renders for the noise estimate (1000 photons each), one for the new discrepancy
    assert fidelity.renders == 3 and fidelity.photon_traces == 2 * 1000 + 128_000
