"""The shared contract suite: every installed plugin of every kind (built-ins and those other
packages register through entry points) passes its kind's checks
(framework/core/contracts/checks.py); so do the test suite's own operator and solver; a
deliberately broken operator, regulariser, solver and stopping rule fail them."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from framework.core.contracts.checks import (
    BASES,
    ContractViolation,
    check_base,
    check_data_source,
    check_post_step,
    check_regularizer,
    check_solver,
    check_start,
    check_stopping,
    example_settings,
)
from framework.core.contracts.data_source import DataRequest, ShotStack
from framework.core.contracts.operator_checks import check_operator, smooth_bump
from framework.core.contracts.linear_checks import check_linear_map
from framework.core.contracts.representation_checks import check_representation
from framework.core.contracts.start import StartRequest, StartResult
from framework.core.data import ReconstructionData
from operators.stack import StackOperator
from framework.core.masks import mask_from_height_field
from framework.core.problem import HeightGrid, Problem
from framework.reconstruction.stopping import StagnationStopping
from framework.core.plugin_config import build_plugin
from framework.core.plugin_config import plugin_class
from framework.core.solver_loop import IterationRecord, IterativeSolver
from framework.core.registry import KINDS, available, register
from framework.stack.line_search import SearchedLines
from operators.scene import Receiver, Scene, Substrate
from regularizers import PixelL1
from examples.plugins.exact_step_solver import ExactStepSolver
from examples.plugins.l2_regularizer import PixelL2
from examples.plugins.mask_mean_start import MaskMeanStart
from examples.plugins.npz_data import NpzData
from examples.plugins.shadow_operator import ShadowOperator
from examples.plugins.small_change_stopping import SmallChangeStopping
from examples.plugins.vignetting_stage import Vignetting
from operators.linear import LinearMap, all_linear_maps
from framework.optimization.preconditioner import GradientPreconditioner
from framework.optimization.step_size import StepSizePolicy

# The rim of a top raised up to 0.05 along the square's edge is lit (the contract's raised-edge checks).
SCENE = Scene(substrate=Substrate(edge_height=0.05), receiver=Receiver(resolution=32))
M = 32  # height samples per side of the known problem


@pytest.fixture(scope="module")
def known_problem() -> Problem:
    """A Gaussian bump 0.05 high seen by the height-field operator (64 x 64 receiver 0.5 below), exact data."""
    scene = Scene(receiver=Receiver(resolution=64, z=-0.5))
    operator = build_plugin("operator", "height_field", {}, "operator", scene=scene, photons=1 << 16, seed=0)
    truth = smooth_bump(M, 0.05).to(operator.dtype)
    grid = HeightGrid(M, scene.substrate.half_width, scene.substrate.thickness)
    mask = mask_from_height_field(truth.double(), 1e-3, 0.05)
    data = ReconstructionData(
        target=operator.render(truth),
        mask=mask,
        volume=float(truth.double().sum()) * grid.cell_area,
        delta=0.01,
    )
    return Problem(operator, data, grid, scene)


def _truth() -> torch.Tensor:
    """The known problem's heights (m, m), float64: what its data were rendered from."""
    return smooth_bump(M, 0.05).double()


def _start_request(problem: Problem, directory: Path) -> StartRequest:
    """A start's request on the known problem, whose data carry a design (the truth 10% lower)."""
    return StartRequest(replace(problem, data=replace(problem.data, design=0.9 * _truth())), directory)


def _operator_maker(name: str, photons: int = 20_000):
    settings = example_settings("operator", name)
    return lambda seed: build_plugin("operator", name, settings, "operator", scene=SCENE, photons=photons, seed=seed)


OWN_BASES = {**BASES, "step_size": StepSizePolicy, "preconditioner": GradientPreconditioner}


def test_caustic_design_has_its_own_kind() -> None:
    assert set(available("design")) == {"schwartzburg", "design_lbfgs", "design_adam"}
    assert "design_lbfgs" not in available("solver") and "schwartzburg" in available("solver")  # also a reconstruction


def _bead_design(m: int) -> torch.Tensor:
    """Two crossing beads 0.03 high and about 0.15 wide (scene units) on the m x m grid over [-1, 1]^2."""
    axis = torch.linspace(-1.0, 1.0, m, dtype=torch.float64)
    y, x = torch.meshgrid(axis, axis, indexing="ij")
    along_x = torch.exp(-(y - 0.2) ** 2 / (2 * 0.06**2)) * (x.abs() < 0.7)
    along_y = torch.exp(-(x + 0.1) ** 2 / (2 * 0.06**2)) * (y.abs() < 0.7)
    return 0.03 * (along_x + along_y).double()


@pytest.mark.parametrize("name", available("representation"))
def test_every_representation_keeps_the_contract(name, known_problem) -> None:
    problem = replace(known_problem, data=replace(known_problem.data, design=_bead_design(M)))
    make = build_plugin("representation", name, example_settings("representation", name), "representation")
    check_representation(make, problem, who=f"representation/{name}")


@pytest.mark.parametrize("kind", KINDS)
def test_every_plugin_derives_from_its_kinds_base(kind) -> None:
    assert available(kind), kind
    for name in available(kind):
        check_base(kind, name, OWN_BASES[kind])


def test_a_plugin_without_its_base_fails(own_registrations) -> None:
    class DuckData:  # check and load, but not a DataSource
        def check(self, request):
            return None

        def load(self, request):
            return None

    register("data", "duck")(DuckData)
    with pytest.raises(
        ContractViolation, match="data/duck: .*not a subclass of framework.core.contracts.data_source.DataSource"
    ):
        check_base("data", "duck")


def test_a_plugin_that_is_no_class_is_refused_in_one_line(own_registrations) -> None:
    register("data", "function")(lambda **settings: None)
    with pytest.raises(ValueError, match=r"^plugin data/function is <function .*>, not a plugin class: derive it from "
                                         r"its kind's base \(docs/plugins.md, Kinds\)$"):
        build_plugin("data", "function", {}, "data")


@pytest.mark.parametrize("name", available("operator"))
def test_every_operator_keeps_the_contract(name) -> None:
    check_operator(_operator_maker(name), who=f"operator/{name}")


@pytest.mark.parametrize("name", available("regularizer"))
def test_every_regularizer_keeps_the_contract(name) -> None:
    check_regularizer(build_plugin("regularizer", name, example_settings("regularizer", name), "regularizer"),
                      who=f"regularizer/{name}")


@pytest.mark.parametrize("name", available("post_step"))
def test_every_post_step_keeps_the_contract(name) -> None:
    check_post_step(
        build_plugin("post_step", name, example_settings("post_step", name), "post_step"), who=f"post_step/{name}"
    )


def test_the_test_suites_operator_keeps_the_contract() -> None:
    check_operator(lambda seed: ShadowOperator.from_config(SCENE, 1, seed), who="operator/shadow")


SOLVERS = [("solver", name) for name in available("solver")] + [("design", name) for name in available("design")]


@pytest.mark.parametrize("kind, name", SOLVERS, ids=[f"{k}/{n}" for k, n in SOLVERS])
def test_every_solver_solves_a_known_problem(kind, name, known_problem) -> None:
    settings = example_settings(kind, name)
    check_solver(lambda: build_plugin(kind, name, settings, kind), known_problem, who=f"{kind}/{name}",
                 iterations=plugin_class(kind, name, IterativeSolver).contract_iterations)


def test_the_test_suites_solver_keeps_the_contract(known_problem) -> None:
    shadow = ShadowOperator(1, 32, 1.0, 1, 1.0)
    truth = 0.1 * smooth_bump(16, 1.0)
    data = ReconstructionData(target=shadow.render(truth), mask=torch.ones(16, 16, dtype=torch.bool), volume=None,
                              delta=0.01)
    problem = Problem(shadow, data, HeightGrid(16, 1.0, 0.1), SCENE)
    check_solver(ExactStepSolver.from_config, problem, iterations=1, reduction=1e-6, who="solver/exact_step")


class _Jittery(ExactStepSolver):
    """The exact step plus a draw from torch's global generator: no two runs alike."""

    def step(self) -> IterationRecord:
        record = super().step()
        self.state.d = self.state.d + 1e-9 * torch.rand_like(self.state.d)
        return record


def test_a_solver_whose_runs_differ_fails_the_contract() -> None:
    shadow = ShadowOperator(1, 32, 1.0, 1, 1.0)
    truth = 0.1 * smooth_bump(16, 1.0)
    data = ReconstructionData(target=shadow.render(truth), mask=torch.ones(16, 16, dtype=torch.bool), volume=None,
                              delta=0.01)
    problem = Problem(shadow, data, HeightGrid(16, 1.0, 0.1), SCENE)
    with pytest.raises(ContractViolation, match="two runs on the same problem end differently"):
        check_solver(_Jittery.from_config, problem, iterations=1, who="solver/jittery")


def test_the_test_suites_start_and_stopping_rule_keep_the_contract(known_problem, tmp_path) -> None:
    request = _start_request(known_problem, tmp_path)
    check_start(MaskMeanStart(), request, who="initial/mask_mean")
    check_stopping(lambda: SmallChangeStopping(1e-9), who="stopping/small_change")


def test_the_example_regularizer_keeps_the_contract_and_its_prox_is_the_closed_form() -> None:
    l2 = PixelL2(**PixelL2.example_settings())
    check_regularizer(l2, who="regularizer/l2_pixel")
    d = smooth_bump(8, 1.0)
    # the prox's optimality condition: step * alpha * x + (x - d) = 0
    x = l2.prox(d, 0.3)
    assert torch.allclose(0.3 * 0.5 * x + (x - d), torch.zeros_like(d), atol=1e-15)
    assert l2.value(d) == pytest.approx(0.25 * float((d ** 2).sum()))
    for bad in (-1.0, float("nan"), True, "0.1"):
        with pytest.raises(ValueError, match="alpha=.* must be a number >= 0, e.g. 1e-3"):
            PixelL2(bad)


def test_the_example_data_source_keeps_the_contract_and_refuses_bad_archives(known_problem, tmp_path) -> None:
    target, mask = known_problem.data.target.double().numpy(), known_problem.data.mask.numpy()
    np.savez(tmp_path / "caustic.npz", caustic=target[0], mask=mask)
    request = DataRequest(known_problem.operator, known_problem.grid, _truth, 0, tmp_path)
    source = NpzData("caustic.npz", delta=0.02, volume=known_problem.data.volume)
    check_data_source(source, request, who="data/npz")
    assert torch.equal(source.load(request).target.double(), known_problem.data.target.double())
    np.savez(tmp_path / "no_mask.npz", caustic=target[0])
    np.savez(tmp_path / "small.npz", caustic=target[0, :10, :10], mask=mask)
    for path, message in (("missing.npz", "does not exist"), ("no_mask.npz", "lacks the array.* mask"),
                          ("small.npz", r"caustic has shape \(1, 10, 10\), the operator renders")):
        with pytest.raises((ValueError, FileNotFoundError), match=message):
            NpzData(path).check(request)
    with pytest.raises(ValueError, match=r"data.delta=1.5 must be a number in \(0, 1\)"):
        NpzData("caustic.npz", delta=1.5)


@pytest.mark.parametrize("name", available("stopping"))
def test_every_stopping_rule_keeps_the_contract(name) -> None:
    settings = example_settings("stopping", name)
    check_stopping(lambda: build_plugin("stopping", name, settings, f"stopping.{name}"), who=f"stopping/{name}")


def _start_settings(name: str, directory: Path) -> dict:
    """Settings of a start: a height-field file for ``file`` (written here), else its own example."""
    if name == "file":
        np.save(directory / "start.npy", 0.5 * smooth_bump(M).numpy())
        return {"path": "start.npy"}
    return example_settings("initial", name)


@pytest.mark.parametrize("name", available("initial"))
def test_every_start_keeps_the_contract(name, known_problem, tmp_path) -> None:
    start = build_plugin("initial", name, _start_settings(name, tmp_path), "initial")
    request = _start_request(known_problem, tmp_path)
    check_start(start, request, who=f"initial/{name}")


def _data_settings(name: str, problem: Problem, directory: Path) -> dict:
    """Settings of a data source: the known problem's caustic as a file for ``file``, as a photo
    of the receiver (corners at the image's corners) for ``photo``, else its own example."""
    image = problem.data.target.double().numpy()
    if name == "file":
        np.save(directory / "caustic.npy", image)
        np.save(directory / "mask.npy", problem.data.mask.numpy())
        return {"image": "caustic.npy", "mask": "mask.npy", "volume": problem.data.volume}
    if name == "photo":
        n = image.shape[-1]
        np.save(directory / "photo.npy", (image[0] / image.max() * 0.8)[::-1].astype(np.float32))
        np.save(directory / "mask.npy", problem.data.mask.numpy())
        return {"photo": "photo.npy", "corners": [[0, n - 1], [n - 1, n - 1], [n - 1, 0], [0, 0]], "mask": "mask.npy"}
    return example_settings("data", name)


@pytest.mark.parametrize("name", available("data"))
def test_every_data_source_keeps_the_contract(name, known_problem, tmp_path) -> None:
    source = build_plugin("data", name, _data_settings(name, known_problem, tmp_path), "data")
    operator = known_problem.operator
    if isinstance(source, ShotStack):  # the run renders through the stacked operator of the shots' setups
        operator = StackOperator([type(operator)(setup.scene(known_problem.scene, "shot"), operator.settings)
                                  for setup in source.setups(known_problem.scene, 25.0)])
    request = DataRequest(operator, known_problem.grid, _truth, 0, tmp_path)
    check_data_source(source, request, who=f"data/{name}")


class _OffByATerm(ShadowOperator):
    """The shadow operator with a gradient that adds a term its image does not have."""

    def loss_and_grad(self, heights, target, image=None):
        loss, grad, image = super().loss_and_grad(heights, target, image)
        return loss, grad + 0.01 * heights, image


class _NoShrink(PixelL1):
    """An l1 regulariser whose prox forgets to shrink."""

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        return d.clone()


class _AdjointOffByATerm(ShadowOperator):
    """The shadow operator whose vjp adds a term its image does not have."""

    def vjp(self, heights, grad_image):
        return super().vjp(heights, grad_image) + 0.01 * heights


class _ForwardOffByAFactor(ShadowOperator):
    """The shadow operator whose Jacobian-vector product is 1.5 times the image's change."""

    has_jvp = True

    def jvp(self, heights, direction):
        return 1.5 * (self.render(heights + direction) - self.render(heights))


class _NeverStops(StagnationStopping):
    """A stagnation rule that forgets to ask the loop to stop."""

    def on_iteration(self, solver, record):
        super().on_iteration(solver, record)
        return None


class _QuietDesignReader(MaskMeanStart):
    """A start that reads the print's design without declaring it (``reads_design`` stays False)."""

    def __call__(self, request: StartRequest) -> StartResult:
        return StartResult(request.design().to(request.problem.operator.dtype), name="quiet")


def test_a_start_that_reads_the_design_declares_it_and_so_does_the_line_search_wrapping_it(
        known_problem, tmp_path) -> None:
    request = _start_request(known_problem, tmp_path)
    with pytest.raises(ContractViolation, match="declares reads_design=False but refuses data without a design"):
        check_start(_QuietDesignReader(), request, who="initial/quiet")
    design = build_plugin("initial", "design", {}, "initial")
    searched = SearchedLines(design, request)
    assert searched.reads_design and not SearchedLines(MaskMeanStart(), request).reads_design


def test_a_broken_plugin_of_each_kind_fails_the_contract(known_problem) -> None:
    with pytest.raises(ContractViolation, match="differs from finite differences"):
        check_operator(lambda seed: _OffByATerm.from_config(SCENE, 1, seed), who="operator/off_by_a_term")
    with pytest.raises(ContractViolation, match="adjoint identity fails"):
        check_operator(lambda seed: _AdjointOffByATerm.from_config(SCENE, 1, seed), who="operator/adjoint_off")
    with pytest.raises(ContractViolation, match="jvp differs from finite differences"):
        check_operator(lambda seed: _ForwardOffByAFactor.from_config(SCENE, 1, seed), who="operator/forward_off")
    with pytest.raises(ContractViolation, match="is not the minimiser"):
        check_regularizer(_NoShrink(alpha=0.1), who="regularizer/no_shrink")
    with pytest.raises(ContractViolation, match="does not solve a known problem"):  # a step far too small
        check_solver(
            lambda: build_plugin(
                "solver", "gradient_descent", {"step_size": {"name": "constant", "tau": 1e-9}}, "solver"
            ),
            known_problem,
            iterations=5,
            who="solver/timid",
        )
    with pytest.raises(ContractViolation, match="does not stop a run that converges"):
        check_stopping(lambda: _NeverStops(patience=2), who="stopping/never")


# Every piece operators/ and examples/ define (imported above); the suite's own broken ones are left out.
LINEAR_PIECES = [piece for piece in all_linear_maps() if not piece.__module__.startswith("tests.")]


def test_the_linear_pieces_are_all_found() -> None:
    names = {piece.__qualname__ for piece in LINEAR_PIECES}
    assert {"BlockMean", "Composition", "Gain", "GaussianBlur", "ShotWeights", "Vignetting"} <= names
    assert all(issubclass(piece, LinearMap) for piece in LINEAR_PIECES) and Vignetting.example()[1] == (2, 8, 8)


@pytest.mark.parametrize("piece", LINEAR_PIECES, ids=lambda piece: piece.__qualname__)
def test_every_linear_piece_passes_the_dot_test(piece) -> None:
    check_linear_map(piece)
