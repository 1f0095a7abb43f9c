"""M1 and M2 as configurations of the proximal-gradient iteration
(framework/reconstruction/solvers/proximal_gradient.py; docs/method.md, "The methods M1, M2 and M3"):
M1 ``gradient_descent`` with no regulariser, M2 ``landweber_pixel`` with regularisers such as
[L1 with alpha_p, bounds [p1, p2] with the mask], eq. (4)-(7).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any
from collections.abc import Sequence

from torch import Tensor

from framework.core.contracts.solver import SolverBuilder
from framework.core.objective import DataFidelity
from framework.optimization.preconditioner import GradientPreconditioner
from framework.optimization.step_size import StepSizePolicy
from framework.reconstruction.solvers.proximal_gradient import Candidate, ProximalGradientSolver
from framework.reconstruction.solvers.proximal_parts import build_parts, check_regularizers
from operators.values import checked_number

__all__ = ["GradientDescent", "PixelLandweber"]


class GradientDescent(ProximalGradientSolver):
    """M1: d <- d - t grad f(d), t <= tau. No regulariser, no post step (docs/method.md, "M1").

    The only limit is physical: the glass top may not reach the substrate bottom (d = -h, where
    the operator has no glass left to trace). A sample that a step would take below ``floor`` =
    -(1 - min_thickness) h stops at the floor; nothing else is constrained (no mask, no upper
    bound, no sparsity), so M1 stays the unregularised fit of the data term. Shortening the whole
    step instead freezes the run: once one sample sits at the floor with its gradient pointing
    down, every later step has length zero (docs/method.md, "M1").

    Args:
        data: The data term f.
        d0: Initial height field (m, m).
        step_size: Policy or constant tau (the paper: tau_p).
        floor: Lowest height a sample may take (scene units, < 0); None: no limit.
    """

    name = "gradient_descent"

    def __init__(self, data: DataFidelity, d0: Tensor, step_size: StepSizePolicy | float,
                 preconditioner: GradientPreconditioner | None = None, context: Any = None,
                 floor: float | None = None, two_metric_from: int | None = None,
                 momentum_from: int | None = None, quasi_newton: Mapping[str, Any] | None = None,
                 shaped_start_from: str = "first") -> None:
        super().__init__(data, d0, step_size, preconditioner=preconditioner, context=context,
                         two_metric_from=two_metric_from, momentum_from=momentum_from, quasi_newton=quasi_newton,
                         shaped_start_from=shaped_start_from)
        if floor is not None and not (math.isfinite(float(floor)) and float(floor) < 0.0):
            raise ValueError(f"gradient_descent floor={floor!r} must be a negative height (scene units) or None")
        self.floor = None if floor is None else float(floor)

    def _propose(self, tau: float) -> Candidate:
        """d - tau P grad f, each sample kept at or above the floor."""
        return {"d": self._project(self.state.d - tau * self._step_direction())}

    def _project(self, d: Tensor) -> Tensor:
        """d with every sample at or above the floor."""
        return d if self.floor is None else d.clamp(min=self.floor)

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py)."""
        return {
            "step_size": {"name": "backtracking", "tau": 5e-3},
            "preconditioner": {"name": "sobolev", "length": [0.25]},
        }

    @classmethod
    def from_config(cls, step_size: Mapping[str, Any], preconditioner: Mapping[str, Any] | None = None,
                    min_thickness: float | None = 0.1, two_metric_from: int | None = None,
                    momentum_from: int | None = None, quasi_newton: Mapping[str, Any] | None = None,
                    shaped_start_from: str = "first") -> SolverBuilder:
        """The plugin ``solver/gradient_descent`` from its config keys (see :func:`build_parts`;
        without regularisers no sample is pinned, so ``two_metric_from`` changes nothing);
        ``min_thickness`` in [0, 1): the fraction of the substrate thickness h that every sample
        keeps (floor = -(1 - min_thickness) h; null: no floor)."""
        if min_thickness is not None:
            checked_number(min_thickness, "solver.min_thickness", 0.0, below=1.0, must="must lie in [0, 1) (fraction "
                           "of the substrate thickness every sample keeps, e.g. 0.1) or be null")
        def fresh_parts() -> dict[str, Any]:
            return build_parts(step_size, preconditioner, two_metric_from=two_metric_from, momentum_from=momentum_from,
                               quasi_newton=quasi_newton, shaped_start_from=shaped_start_from)

        fresh_parts()  # a bad value fails now, before any render

        def build(problem, d0: Tensor) -> GradientDescent:
            parts = fresh_parts()  # every run from a start with its own step size and preconditioner stage
            floor = None if min_thickness is None else -(1.0 - float(min_thickness)) * problem.scene.substrate.thickness
            return cls(problem.fidelity, d0, parts["step_size"], parts["preconditioner"], context=problem.context,
                       floor=floor, two_metric_from=parts["two_metric_from"], momentum_from=parts["momentum_from"],
                       quasi_newton=parts["quasi_newton"], shaped_start_from=parts["shaped_start_from"])

        return build


class PixelLandweber(ProximalGradientSolver):
    """M2: thresholded nonlinear Landweber, d <- P(d - tau grad f(d), tau), then post steps (eq. 4-7).

    Typical ``regularizers``: an L1 term (alpha_p) and the masked bounds [p1, p2]; typical
    ``post_steps``: the volume heuristic V1 (eq. 8). Arguments as :class:`ProximalGradientSolver`;
    at least one regulariser is required (without one, use ``gradient_descent``).
    """

    name = "landweber_pixel"

    def __init__(
        self,
        data: DataFidelity,
        d0: Tensor,
        step_size: StepSizePolicy | float,
        regularizers: Sequence[Any],
        post_steps: Sequence[Any] = (),
        preconditioner: GradientPreconditioner | None = None,
        context: Any = None,
        two_metric_from: int | None = None,
        momentum_from: int | None = None,
        quasi_newton: Mapping[str, Any] | None = None,
        shaped_start_from: str = "first",
    ) -> None:
        self._require_regularizers(regularizers)
        super().__init__(data, d0, step_size, regularizers, post_steps, preconditioner, context, two_metric_from,
                         momentum_from, quasi_newton, shaped_start_from)

    @staticmethod
    def _require_regularizers(regularizers: Sequence[Any]) -> None:
        if not list(regularizers):
            raise ValueError(
                "landweber_pixel needs at least one regulariser with a prox (e.g. solver.regularizers: "
                "{l1_bounds: {alpha: 2e-3}}); for plain gradient descent use solver 'gradient_descent'"
            )

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py)."""
        return {"step_size": {"name": "backtracking", "tau": 5e-3}, "regularizers": {"l1_bounds": {}},
                "preconditioner": {"name": "sobolev", "length": [0.25]}, "quasi_newton": {"memory": 8, "from_stage": 0}}

    @classmethod
    def from_config(cls, step_size: Mapping[str, Any], regularizers: Mapping[str, Any] | None = None,
                    post_steps: Mapping[str, Any] | None = None, preconditioner: Mapping[str, Any] | None = None,
                    two_metric_from: int | None = None, momentum_from: int | None = None,
                    quasi_newton: Mapping[str, Any] | None = None, shaped_start_from: str = "first") -> SolverBuilder:
        """The plugin ``solver/landweber_pixel`` from its config keys (see :func:`build_parts`)."""
        def fresh_parts() -> dict[str, Any]:
            parts = build_parts(step_size, preconditioner, regularizers, post_steps, two_metric_from, momentum_from,
                                quasi_newton, shaped_start_from)
            cls._require_regularizers(parts["regularizers"])
            check_regularizers(parts["regularizers"], cls.name)
            return parts

        fresh_parts()  # a bad value fails now, before any render
        # every run from a start with its own step size, preconditioner stage and regularisers
        return lambda problem, d0: cls(problem.fidelity, d0, context=problem.context, **fresh_parts())
