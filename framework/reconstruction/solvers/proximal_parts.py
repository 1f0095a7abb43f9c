"""What a proximal-gradient solver (framework/reconstruction/solvers/proximal_gradient.py) is built from,
checked: its parts from the ``solver`` config by registry key (:func:`build_parts`), and the checks
of the parts and settings handed to it directly, each a one-line ValueError naming the key."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
from collections.abc import Sequence

from framework.core.plugin_config import build_plugin, build_plugin_map, split_name
from framework.optimization.preconditioner import check_stage_index
from framework.optimization.quasi_newton import check_quasi_newton
from framework.reconstruction.solvers.momentum import check_momentum_from
from regularizers import PostStepUpdate, Regularizer

__all__ = ["SHAPED_START_FROM", "build_parts", "check_post_steps", "check_regularizers", "check_shaped_start_from",
           "check_two_metric_from"]


def build_parts(step_size: Mapping[str, Any], preconditioner: Mapping[str, Any] | None = None,
                regularizers: Mapping[str, Any] | None = None,
                post_steps: Mapping[str, Any] | None = None,
                two_metric_from: int | None = None, momentum_from: int | None = None,
                quasi_newton: Mapping[str, Any] | None = None, shaped_start_from: str = "first") -> dict[str, Any]:
    """The configured parts of a proximal-gradient solver, by registry key: the step size
    ``{name: backtracking, tau: ...}``, the preconditioner ``{name: sobolev, ...}`` (or None), the
    regularisers and post steps ``{name: {params}}`` in config order; ``two_metric_from``,
    ``momentum_from``, ``quasi_newton`` and ``shaped_start_from`` as :class:`ProximalGradientSolver`
    takes them (checked here)."""
    step_name, step_params = split_name(step_size, "solver.step_size")
    parts: dict[str, Any] = {
        "step_size": build_plugin("step_size", step_name, step_params, "solver.step_size"),
        "preconditioner": None,
        "regularizers": build_plugin_map("regularizer", regularizers, "solver.regularizers"),
        "post_steps": build_plugin_map("post_step", post_steps, "solver.post_steps"),
        "two_metric_from": check_two_metric_from(two_metric_from),
        "momentum_from": check_momentum_from(momentum_from),
        "quasi_newton": check_quasi_newton(quasi_newton),
        "shaped_start_from": check_shaped_start_from(shaped_start_from),
    }
    if preconditioner:
        name, params = split_name(preconditioner, "solver.preconditioner")
        parts["preconditioner"] = build_plugin("preconditioner", name, params, "solver.preconditioner")
    return parts


SHAPED_START_FROM = ("first", "finest")


def check_shaped_start_from(value: Any) -> str:
    """``solver.shaped_start_from``: where the schedule begins from a start that holds the broad
    shape (``first``: the whole schedule; ``finest``: its last stage)."""
    if value not in SHAPED_START_FROM:
        raise ValueError(f"solver.shaped_start_from={value!r} must be one of {', '.join(SHAPED_START_FROM)} (where the "
                         "preconditioner schedule begins from a transport, design or file start)")
    return str(value)


def check_two_metric_from(stage: Any) -> int | None:
    """``solver.two_metric_from`` as a preconditioner stage index >= 0, or None."""
    return check_stage_index(stage, "solver.two_metric_from", "never")


def check_regularizers(regularizers: Sequence[Any], solver: str, role: str = "regularizers") -> list[Any]:
    """``regularizers`` as a list, each a :class:`regularizers.base.Regularizer` with a proximal map,
    else a ValueError naming the solver and the entry."""
    out = list(regularizers)
    for r in out:
        if not isinstance(r, Regularizer):
            raise ValueError(f"{solver}: {role} entry {type(r).__name__} is not a Regularizer (regularizers/base.py); "
                             "derive it from Regularizer with value(d) and prox(d, step)")
        if not r.has_prox:
            raise ValueError(
                f"{solver}: {type(r).__name__} has no proximal map (has_prox=False); "
                "a proximal-gradient solver can only use regularisers with a prox"
            )
    return out


def check_post_steps(post_steps: Sequence[Any], solver: str) -> list[PostStepUpdate]:
    """``post_steps`` as a list, each a :class:`regularizers.base.PostStepUpdate`, else a ValueError
    naming the solver and the entry."""
    out = list(post_steps)
    for u in out:
        if not isinstance(u, PostStepUpdate):
            raise ValueError(f"{solver}: post step {type(u).__name__} is not a PostStepUpdate (regularizers/base.py); "
                             "derive it from PostStepUpdate with __call__(d) -> d")
    return out
