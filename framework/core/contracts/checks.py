"""The contract every plugin of a kind keeps, as checks a test runs on each registered plugin.

tests/test_plugin_contracts.py runs them on every installed plugin of every kind (third-party ones
included, found through their entry points); a plugin package may call them from its own tests. A
plugin with required settings declares an example of them in a classmethod
``example_settings() -> dict`` (e.g. the mesh scene's elements).

- operator: framework/core/contracts/operator_checks.py;
- regularizer (:func:`check_regularizer`): ``prox`` is the minimiser of step R(x) + 1/2 ||x - d||^2
  (no nearby point does better), its result lies where R is finite, and ``value`` is finite there;
- post_step (:func:`check_post_step`): same shape and dtype, finite, the input untouched,
  deterministic;
- solver (:func:`check_solver`): a known problem solved (the discrepancy of exact data falls to a
  fraction of the start's), finite iterates, the same result twice;
- stopping (:func:`check_stopping`): a stopping rule that, after ``setup``, ends a run whose
  discrepancy falls to zero before its cap, says why, and does so at the same iteration twice;
- initial (:func:`check_start`): a start of the grid's shape and the operator's dtype, finite,
  the same twice, its phases named;
- data (:func:`check_data_source`): ``check`` and ``load`` agree on the printed area and on the
  volume where ``check`` knows it, the target has the operator's shape, the noise level lies in (0, 1), the
  same data twice;
- representation (framework/core/contracts/representation_checks.py): shapes, a start inside its bounds, its stages,
  and its vjp and its prior's gradient against central differences (the adjoint identity);
- the image chain's linear pieces (framework/core/contracts/linear_checks.py): the dot test.

Before any of these, :func:`check_base`: the registered object derives from its kind's base.

A failed check raises :class:`framework.core.contracts.violation.ContractViolation` naming the
plugin and the check.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any
from collections.abc import Callable

import torch

from framework.core.contracts.calibration import SetupCalibration
from framework.core.contracts.data_source import DataRequest, DataSource
from framework.core.contracts.representation import Representation
from framework.core.contracts.run_log import RunLog
from framework.core.contracts.solver import SolverBuilder
from framework.core.contracts.operator_checks import smooth_bump
from framework.core.contracts.stage import RunStage
from framework.core.contracts.start import Start, StartRequest
from framework.core.contracts.stopping import StoppingRule
from framework.core.contracts.violation import ContractViolation, require
from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid, Problem
from framework.core.plugin_config import plugin_class
from framework.core.registry import lookup
from framework.core.solver_loop import Callback, IterationRecord, IterativeSolver
from operators.image_operator import ImageOperator
from operators.plugin import Plugin
from operators.scene import Receiver, Scene
from regularizers import PostStepUpdate, Regularizer, RegularizerContext

__all__ = [
    "BASES",
    "ContractViolation",
    "check_base",
    "example_settings",
    "check_regularizer",
    "check_post_step",
    "check_solver",
    "check_stopping",
    "check_start",
    "check_data_source",
]


# The base every registered plugin of a kind derives from (step_size and preconditioner: their
# bases in framework/optimization/, checked by tests/test_plugin_contracts.py).
BASES: dict[str, type] = {"operator": ImageOperator, "data": DataSource, "initial": Start, "solver": IterativeSolver,
                          "design": IterativeSolver, "stopping": StoppingRule, "regularizer": Regularizer,
                          "post_step": PostStepUpdate, "representation": Representation, "stage": RunStage,
                          "tracker": RunLog, "calibration": SetupCalibration}


def check_base(kind: str, name: str, base: type | None = None) -> None:
    """The registered plugin ``kind/name`` is a subclass of the kind's base (``base``, or
    :data:`BASES`); a solver also has its ``from_config``."""
    plugin, base, who = lookup(kind, name), base or BASES[kind], f"{kind}/{name}"
    require(isinstance(plugin, type) and issubclass(plugin, base), who,
             f"is {plugin!r}, not a subclass of {base.__module__}.{base.__qualname__}; derive from it")
    if kind in ("solver", "design"):
        require(plugin.from_config is not None, who,
                 "has no from_config(**settings) returning the builder (problem, d0) -> solver")


def example_settings(kind: str, name: str) -> dict[str, Any]:
    """The settings plugin ``kind/name`` declares for the contract checks (its ``example_settings()``), else {}."""
    return dict(plugin_class(kind, name, Plugin).example_settings())


def _context(m: int) -> RegularizerContext:
    mask = torch.zeros(m, m, dtype=torch.bool)
    mask[m // 4: 3 * m // 4, m // 4: 3 * m // 4] = True
    area = (2.0 / m) ** 2
    x = torch.linspace(-1.0, 1.0, m, dtype=torch.float64)
    design = 0.1 * torch.exp(-8.0 * (x[:, None] ** 2 + x[None, :] ** 2)) * mask
    return RegularizerContext(mask=mask, volume=0.05 * float(mask.sum()) * area, pixel_area=area, design=design)


def check_regularizer(regularizer: Regularizer, m: int = 16, who: str = "regularizer", trials: int = 30) -> None:
    """Check a regularizer: with ``has_prox``, prox(d, step) minimises step R(x) + 1/2 ||x - d||^2
    (no random nearby point, nor its projection, does better) and R is finite at it."""
    require(isinstance(regularizer, Regularizer), who, f"is a {type(regularizer).__name__}, not a Regularizer")
    regularizer.setup(_context(m))
    generator = torch.Generator().manual_seed(0)
    d = 0.2 * torch.rand(m, m, generator=generator, dtype=torch.float64) - 0.05
    require(math.isfinite(regularizer.value(regularizer.project(d))), who, "value is not finite at project(d)")
    if not regularizer.has_prox:
        return
    for step in (1e-3, 1e-1, 10.0):
        x = regularizer.prox(d, step)
        best = step * regularizer.value(x) + 0.5 * float(((x - d) ** 2).sum())
        require(math.isfinite(best), who, f"value is not finite at prox(d, {step:g})")
        for trial in range(trials):
            scale = 10.0 ** (-1 - trial % 4)
            y = x + scale * torch.randn(m, m, generator=generator, dtype=torch.float64)
            for candidate in (y, regularizer.project(y)):
                other = step * regularizer.value(candidate) + 0.5 * float(((candidate - d) ** 2).sum())
                require(other >= best - 1e-9 * (1.0 + abs(best)), who,
                         f"prox(d, {step:g}) is not the minimiser: a point {scale:g} away does better "
                         f"({other:.10g} < {best:.10g})")


def check_post_step(post_step: PostStepUpdate, m: int = 16, who: str = "post_step") -> None:
    """Check a post-step update: same shape and dtype, finite, the input untouched, deterministic."""
    require(isinstance(post_step, PostStepUpdate), who, f"is a {type(post_step).__name__}, not a PostStepUpdate")
    post_step.setup(_context(m))
    d = smooth_bump(m, 0.05)
    before = d.clone()
    out = post_step(d)
    require(out.shape == d.shape and out.dtype == d.dtype, who,
             f"gives {tuple(out.shape)} {out.dtype} for {tuple(d.shape)} {d.dtype}")
    require(bool(torch.isfinite(out).all()), who, "gives non-finite heights")
    require(torch.equal(d, before), who, "modifies its input")
    require(torch.equal(post_step(d), out), who, "is not deterministic")


SAME_TWICE_ITERATIONS = 10  # a run repeated this far must end on the first run's iterate, bit for bit


class _IterateAt(Callback):
    """Keeps a copy of the solver's heights after iteration ``k``."""

    def __init__(self, k: int) -> None:
        self.k = k
        self.d: torch.Tensor | None = None

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> bool | None:
        if record.iteration == self.k:
            self.d = solver.d.detach().clone()
        return None


def check_solver(make: Callable[[], SolverBuilder], problem: Problem, iterations: int = 40, who: str = "solver",
                 reduction: float = 0.5) -> None:
    """Check a solver plugin (``make()`` builds its builder) on a known problem with exact data
    (``problem.data.target`` = F(d_true)): from flat glass, within ``iterations`` the relative
    discrepancy falls to ``reduction`` times the start's, every iterate finite, and a second run
    ends its first :data:`SAME_TWICE_ITERATIONS` iterations on the first run's iterate."""
    start = torch.zeros(problem.grid.shape, dtype=problem.operator.dtype)
    first = problem.fidelity.evaluate(start, with_grad=False).rel_discrepancy
    again = min(iterations, SAME_TWICE_ITERATIONS)
    solver = make()(problem, start.clone())
    require(isinstance(solver, IterativeSolver), who, f"builds a {type(solver).__name__}, not an IterativeSolver")
    seen = _IterateAt(again)
    result = solver.run(iterations, [seen])
    require(bool(torch.isfinite(result.d).all()) and tuple(result.d.shape) == problem.grid.shape, who,
             f"ends with non-finite heights or shape {tuple(result.d.shape)}")
    last = problem.fidelity.evaluate(result.d, with_grad=False).rel_discrepancy
    require(last <= reduction * first, who, f"does not solve a known problem: the relative discrepancy goes from "
             f"{first:.4g} to {last:.4g} in {iterations} iterations (at most {reduction:g} x the start's asked)")
    repeated = make()(problem, start.clone()).run(again)
    reference = seen.d if seen.d is not None else result.d  # a run that ended before iteration ``again``
    require(repeated.iterations == min(again, result.iterations) and torch.equal(repeated.d, reference), who,
            "two runs on the same problem end differently")


class _Identity(ImageOperator):
    """F(d) = 1 + d on an m x m receiver: the operator of the stopping-rule checks."""

    dtype, photons, pixel_area = torch.float64, 0, 1.0

    def __init__(self, m: int) -> None:
        self.m = m

    @property
    def output_shape(self) -> tuple[int, int, int]:
        return (1, self.m, self.m)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        return 1.0 + heights.reshape(1, self.m, self.m).to(self.dtype)

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        return grad_image.reshape(self.m, self.m).to(self.dtype)

    def variant(self, photons: int, seed: int, resolution: int) -> _Identity:
        """The same map on a ``resolution`` x ``resolution`` receiver (it has no sampling)."""
        return _Identity(resolution)


class _Converging(IterativeSolver):
    """Halves the residual of d = d_true each iteration: the discrepancy falls geometrically to 0."""

    def __init__(self, problem: Problem, truth: torch.Tensor) -> None:
        super().__init__(torch.zeros_like(truth))
        self.problem, self.truth = problem, truth

    def step(self) -> IterationRecord:
        self.state.d = self.truth + 0.5 * (self.state.d - self.truth)
        self.state.iteration += 1
        evaluation = self.problem.fidelity.evaluate(self.state.d, with_grad=False)
        record = IterationRecord(self.state.iteration, evaluation.value, evaluation.value, evaluation.rel_discrepancy,
                                 0.5, 0.0)
        self.history.append(record)
        return record


def check_stopping(make: Callable[[], StoppingRule], m: int = 8, cap: int = 200, who: str = "stopping") -> None:
    """Check a stopping rule built by ``make()``: after ``setup(problem)`` it ends a run whose
    discrepancy falls geometrically to zero before the cap, with a reason, at the same iteration twice."""
    truth = smooth_bump(m, 0.5)
    operator = _Identity(m)
    mask = torch.ones(m, m, dtype=torch.bool)
    data = ReconstructionData(target=operator.render(truth), mask=mask, volume=float(truth.sum()) * (2.0 / m) ** 2,
                              delta=0.01)
    problem = Problem(operator, data, HeightGrid(m, 1.0, 0.1), Scene(receiver=Receiver(resolution=m)))
    stops = []
    for _ in range(2):
        rule = make()
        require(isinstance(rule, StoppingRule), who, f"is a {type(rule).__name__}, not a StoppingRule")
        rule.setup(problem)
        result = _Converging(problem, truth).run(cap, [rule])
        require(result.stopped_by == type(rule).__name__, who,
                 f"does not stop a run that converges ({result.stop_reason})")
        require(bool(result.stop_reason), who, "stops without a reason")
        stops.append(result.iterations)
    require(stops[0] == stops[1], who, f"stops at iteration {stops[0]}, then at {stops[1]}")


def check_start(start: Start, request: StartRequest, who: str = "initial") -> None:
    """Check a start plugin on a request: d0 of the grid's shape and the operator's dtype, finite,
    the same twice; its phases named."""
    require(isinstance(start, Start), who, f"is a {type(start).__name__}, not a Start")
    phases = start.phases()
    require(bool(phases) and all(isinstance(name, str) and name and isinstance(s, Start) for name, s in phases), who,
             f"phases() gives {phases!r}; a non-empty list of (name, start)")
    start.check(request.base_dir)
    results = [start(request) for _ in range(2)]
    d = results[0].d
    problem = request.problem
    require(
        tuple(d.shape) == problem.grid.shape and d.dtype == problem.operator.dtype,
        who,
        f"gives {tuple(d.shape)} {d.dtype}; the grid is {problem.grid.shape}, "
        f"the operator's dtype {problem.operator.dtype}",
    )
    require(bool(torch.isfinite(d).all()), who, "gives non-finite heights")
    require(torch.equal(d, results[1].d), who, "gives another start the second time")
    # What it reads, as declared: data without a design refuse a start that reads one, and run any other.
    bare = replace(request, problem=replace(problem, data=replace(problem.data, design=None)))
    try:
        start(bare)
        read = False
    except ValueError:
        read = True
    behaves = "refuses" if read else "runs on"
    require(read == bool(start.reads_design), who,
             f"declares reads_design={start.reads_design!r} but {behaves} data without a design")


def check_data_source(source: DataSource, request: DataRequest, who: str = "data") -> None:
    """Check a data plugin on a request: ``check`` and ``load`` agree on the printed area and on
    the volume where ``check`` knows it, the target has the operator's shape and is finite, delta lies in (0,
    1), the same twice."""
    require(isinstance(source, DataSource), who, f"is a {type(source).__name__} without check and load")
    facts = source.check(request)
    require(tuple(facts.mask.shape) == request.grid.shape and facts.mask.dtype == torch.bool, who,
             f"check gives a mask {tuple(facts.mask.shape)} {facts.mask.dtype}; the grid is {request.grid.shape} bool")
    data = source.load(request)
    require(tuple(data.target.shape) == tuple(request.operator.output_shape), who,
             f"loads a target {tuple(data.target.shape)}; the operator renders {tuple(request.operator.output_shape)}")
    require(bool(torch.isfinite(data.target).all()), who, "loads a non-finite target")
    require(torch.equal(data.mask, facts.mask), who, "load and check give different printed areas")
    require(facts.volume is None or data.volume == facts.volume, who,
             f"load gives the volume {data.volume}, check {facts.volume}")
    require(0.0 < data.delta < 1.0, who, f"loads the noise level {data.delta}, not in (0, 1)")
    require(torch.equal(source.load(request).target, data.target), who, "loads another target the second time")
