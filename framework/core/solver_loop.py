"""The solver loop shared by all methods: ``step()`` does one iteration, ``run()`` drives it.

Stopping rules, logging, progress and checkpoints are :class:`Callback` objects
(:mod:`framework.core.callbacks`); ``run`` only enforces the iteration cap and asks the solver whether
it has finished (:meth:`IterativeSolver.finished`, e.g. a direct method after its one step). The cap is
*absolute*: ``run(max_iter)`` stops when
``solver.iteration == max_iter``, so a solver restored from a checkpoint and run with the same
cap finishes exactly where an uninterrupted run would.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar
from collections.abc import Sequence

import torch
from torch import Tensor

from operators.plugin import Plugin
from operators.values import checked_whole

__all__ = [
    "Callback",
    "IterationRecord",
    "RunResult",
    "SolverState",
    "IterativeSolver",
    "IterationFailed",
    "returned_iterate",
]


class IterationFailed(RuntimeError):
    """An iteration could not produce a valid iterate; ``run`` stops and keeps the last one."""


@dataclass
class IterationRecord:
    """What one iteration produced (the new iterate d_k, k = ``iteration``).

    Attributes:
        iteration: k >= 1, the number of completed iterations.
        objective: F(d_k) = f(d_k) + sum of regulariser values.
        data_fidelity: f(d_k) (normalised, see :mod:`framework.core.objective`).
        rel_discrepancy: ||F(d_k) - b||_F / ||b||_F.
        step_size: The accepted step tau.
        elapsed_s: Solver time since the start of the (possibly resumed) reconstruction, seconds.
        extras: Further numbers (trials, forward evaluations; callbacks add e.g. errors).
    """

    iteration: int
    objective: float
    data_fidelity: float
    rel_discrepancy: float
    step_size: float
    elapsed_s: float
    extras: dict[str, float] = field(default_factory=dict)

    def metrics(self) -> dict[str, float]:
        """All numbers as one flat dict (extras merged in), for logging."""
        out = {k: float(v) for k, v in asdict(self).items() if k != "extras"}
        out.update({k: float(v) for k, v in self.extras.items()})
        return out


@dataclass
class RunResult:
    """The end of ``run``.

    Attributes:
        d: Final height field (m, m).
        iterations: Completed iterations (absolute, including those before a resume).
        stop_reason: Why the run ended ("max_iter", a callback's reason, or a failure).
        stopped_by: Name of the callback that stopped it, "max_iter", or "solver" on failure.
        history: All iteration records (including those before a resume).
        elapsed_s: Total solver time, seconds.
        accepted: Whether ``d`` is an accepted solution: the solver finished, or a callback with
            ``stop_accepts_iterate`` (Morozov's rule) stopped the run; otherwise a stopping rule
            may hold a better iterate (:meth:`Callback.best_iterate`).
        solver_metrics: What the solver says of its own run (:meth:`IterativeSolver.run_metrics`).
    """

    d: Tensor
    iterations: int
    stop_reason: str
    stopped_by: str
    history: list[IterationRecord]
    elapsed_s: float
    accepted: bool = False
    solver_metrics: dict[str, Any] = field(default_factory=dict)
    fitted: Any = None

    @property
    def last(self) -> IterationRecord | None:
        """The last iteration record, if any iteration ran."""
        return self.history[-1] if self.history else None


@dataclass
class SolverState:
    """The iterate and counters; everything needed to continue, with the evaluation cache.

    Attributes:
        d: Height field (m, m), scene units.
        iteration: Completed iterations.
        elapsed_s: Accumulated solver time, seconds.
    """

    d: Tensor
    iteration: int = 0
    elapsed_s: float = 0.0


class Callback:
    """A hook of the solver loop; every hook is a no-op.

    ``run`` calls ``on_start(solver)`` once, ``on_iteration(solver, record)`` after every
    iteration (a truthy return asks to stop; set ``stop_reason`` first) and
    ``on_end(solver, result)`` once, in ascending ``order``: metric callbacks (order < 0) first,
    so that stopping rules and loggers see the numbers they add to ``record.extras``.

    Attributes:
        order: Call order within a run (ascending); metric callbacks use negative values.
        stop_reason: Set by a callback before it returns True from :meth:`on_iteration`.
        stop_accepts_iterate: True for a rule whose stop means the current iterate is the
            solution (Morozov's discrepancy principle); False for a rule that gives up.
    """

    order: int = 0
    stop_reason: str | None = None
    stop_accepts_iterate: bool = False

    def on_start(self, solver: IterativeSolver) -> None:
        """Called once before the first iteration of ``run``."""

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> bool | None:
        """Called after each iteration; return True to stop (set ``stop_reason`` first)."""
        return None

    def on_end(self, solver: IterativeSolver, result: RunResult) -> None:
        """Called once when ``run`` ends normally (not on an exception)."""

    def best_iterate(self) -> tuple[Tensor, int] | None:
        """(d, iteration) to report instead of the last iterate when the run was not accepted
        (e.g. the lowest discrepancy seen), or None."""
        return None


def returned_iterate(result: RunResult, callbacks: Sequence[Callback]) -> tuple[Tensor, int]:
    """(d, iteration) a run reports: its last iterate, or when no callback accepted it the best one
    a callback kept (:meth:`Callback.best_iterate`, e.g. a stagnation rule's lowest discrepancy)."""
    if not result.accepted:
        best = next((b for b in (cb.best_iterate() for cb in callbacks) if b is not None), None)
        if best is not None:
            return best
    return result.d.detach(), result.iterations


class IterativeSolver(Plugin, ABC):
    """Base of all solvers: state, history, ``step()`` and the shared ``run()``.

    Subclasses implement :meth:`step` and, if they hold more state than ``state``,
    :meth:`state_dict` / :meth:`load_state_dict`. A plugin solver (kinds ``solver``, ``design``)
    also gives ``from_config`` (operators/plugin.py) returning its builder.

    Attributes:
        contract_iterations: How many iterations the contract check's known problem may take (a
            solver of many small steps by design declares more).
    """

    name: ClassVar[str] = "iterative"
    contract_iterations: ClassVar[int] = 40

    def __init__(self, d0: Tensor) -> None:
        if not isinstance(d0, Tensor) or d0.ndim != 2 or d0.shape[0] != d0.shape[1]:
            shape = tuple(d0.shape) if isinstance(d0, Tensor) else type(d0).__name__
            raise ValueError(f"d0 must be a square (m, m) torch.Tensor, got {shape}; start from torch.zeros(m, m)")
        if not d0.is_floating_point() or not bool(torch.isfinite(d0).all()):
            raise ValueError(f"d0 must be finite and floating point (dtype {d0.dtype}); start from torch.zeros(m, m)")
        self.state = SolverState(d=d0.detach().clone())
        self.history: list[IterationRecord] = []
        self.max_iter: int | None = None  # the cap of the current run (for progress bars)
        # A time.perf_counter() value by which a step that can stop early (a transport's Newton) ends
        # and says so; set by a time budget (framework/design/design_run.py, TimeBudget), None: none.
        self.deadline: float | None = None

    @property
    def d(self) -> Tensor:
        """The current height field (m, m)."""
        return self.state.d

    @property
    def iteration(self) -> int:
        """Completed iterations."""
        return self.state.iteration

    @abstractmethod
    def step(self) -> IterationRecord:
        """One iteration: update ``state``, append and return its record."""

    def finished(self) -> str | None:
        """Why no further iteration is needed (a direct method after its step), or None."""
        return None

    def stage(self) -> int:
        """The stage of a coarse-to-fine schedule the solver is in (0 without one)."""
        return 0

    def begin_from_shaped_start(self, schedule_from: str | None = None) -> None:
        """The start already holds the print's broad shape (a transport, a design, a file, a coarser
        grid's solution): a solver with a coarse-to-fine schedule may begin at a later stage
        (``schedule_from``: ``first`` or ``finest``; None: the solver's own setting); nothing
        without one."""

    def setup_changed(self) -> None:
        """The forward operator's setup changed (joint calibration, framework/lab/calibration.py,
        or its photons, framework/reconstruction/photon_budget.py): forget whatever was computed with the
        old one. Solvers that cache evaluations override it."""

    def set_heights(self, d: Tensor) -> None:
        """Go on from heights ``d`` (m, m) instead of the current ones (joint calibration moves the
        heights with the screen distance it changes, framework/lab/calibration.py): forgets
        whatever was computed at the old ones."""
        if tuple(d.shape) != tuple(self.state.d.shape) or not bool(torch.isfinite(d).all()):
            raise ValueError(f"set_heights needs finite heights of shape {tuple(self.state.d.shape)}")
        self.state.d = d.detach().to(self.state.d).clone()
        self.setup_changed()

    def refine(self, d: Tensor) -> bool:
        """Go to the next, finer stage of a coarse-to-fine schedule and continue from ``d`` (m, m)
        (the best iterate so far); False, and nothing changes, without a finer stage (here: none)."""
        return False

    def volume_band(self) -> tuple[float, float] | None:
        """The band [q1, q2] of the height sum sum_j d_j that the solver enforces (a known
        deposited volume), or None; Morozov's rule accepts only iterates inside it."""
        return None

    def fitted(self) -> Any:
        """What the solver fitted besides the heights (a representation and its parameters,
        framework/reconstruction/solvers/parametric_fit.py), or None."""
        return None

    def run_metrics(self) -> dict[str, Any]:
        """What sums up this solver's run for the run's metrics.json (e.g. the iterations after
        which a coarse-to-fine schedule refined); nothing by default."""
        return {}

    def run(self, max_iter: int, callbacks: Sequence[Callback] = ()) -> RunResult:
        """Iterate until a callback asks to stop, an iteration fails, or ``iteration == max_iter``.

        Callbacks are called in ascending ``order`` (metric callbacks first, so that loggers and
        stopping rules see their numbers), then in list order. Every callback sees the record of
        the iteration on which one of them asks to stop; the first reason wins.

        Args:
            max_iter: Absolute iteration cap (counts iterations done before a resume).
            callbacks: :class:`Callback` instances.
        """
        max_iter = checked_whole(max_iter, "max_iter", 0)
        for cb in callbacks:
            if not isinstance(cb, Callback):
                raise ValueError(f"{type(cb).__name__} is not a Callback (framework/core/solver_loop.py); derive it "
                                 "from Callback, see framework/core/callbacks.py")
        ordered = sorted(callbacks, key=lambda cb: cb.order)
        self.max_iter = max_iter
        for cb in ordered:
            cb.on_start(self)
        stop_reason, stopped_by, accepted = "", "", False
        while not stop_reason:
            done = self.finished()
            if done:
                stop_reason, stopped_by, accepted = done, "solver", True
                break
            if self.iteration >= max_iter:
                stop_reason, stopped_by = f"reached max_iter={max_iter}", "max_iter"
                break
            try:
                record = self.step()
            except IterationFailed as err:
                stop_reason, stopped_by = f"iteration {self.iteration + 1} failed: {err}", "solver"
                break
            for cb in ordered:
                if cb.on_iteration(self, record) and not stop_reason:
                    stopped_by, accepted = type(cb).__name__, bool(cb.stop_accepts_iterate)
                    stop_reason = cb.stop_reason or f"stopped by {stopped_by}"
        result = RunResult(
            d=self.state.d,
            iterations=self.iteration,
            stop_reason=stop_reason,
            stopped_by=stopped_by,
            history=list(self.history),
            elapsed_s=self.state.elapsed_s,
            accepted=accepted,
            solver_metrics=self.run_metrics(),
            fitted=self.fitted(),
        )
        for cb in ordered:
            cb.on_end(self, result)
        return result

    # -- checkpoints ---------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue bit-for-bit (tensors, numbers, lists; torch.save-able)."""
        return {
            "solver": type(self).__name__,
            "d": self.state.d,
            "iteration": self.state.iteration,
            "elapsed_s": self.state.elapsed_s,
            "history": [asdict(r) for r in self.history],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (tensors move to the device and dtype of the current d)."""
        if state.get("solver") != type(self).__name__:
            raise ValueError(
                f"checkpoint was written by solver {state.get('solver')!r}, cannot load into {type(self).__name__}"
            )
        d = state["d"]
        if tuple(d.shape) != tuple(self.state.d.shape):
            raise ValueError(f"checkpoint d has shape {tuple(d.shape)}, solver has {tuple(self.state.d.shape)}")
        like = self.state.d
        self.state = SolverState(
            d=d.to(device=like.device, dtype=like.dtype),
            iteration=int(state["iteration"]),
            elapsed_s=float(state["elapsed_s"]),
        )
        self.history = [IterationRecord(**r) for r in state["history"]]
