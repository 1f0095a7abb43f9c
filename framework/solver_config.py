"""Building a solver, its regularisers and step-size policy from config (registry keys only)."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from framework.objective import DataFidelity
from framework.registry import build, lookup
from framework.solvers.step_size import BacktrackingStep, ConstantStep, StepSizePolicy
from regularizers import RegularizerContext


def make_step_size(spec: Mapping[str, Any]) -> StepSizePolicy:
    """``{policy: constant, tau: 1.0}`` or ``{policy: backtracking, tau: 4.0, shrink: 0.5, grow: 1.25}``."""
    params = dict(spec)
    policy = params.pop("policy", "constant")
    tau = params.pop("tau")
    if policy == "constant":
        if params:
            raise ValueError(f"step_size.policy=constant takes only tau; remove {sorted(params)}")
        return ConstantStep(tau)
    if policy == "backtracking":
        return BacktrackingStep(tau, **params)
    raise ValueError(f"unknown step_size.policy {policy!r}; use constant or backtracking")


def build_preconditioner(spec: Mapping[str, Any] | None) -> Any:
    """``{name: sobolev, length: 0.125, order: 2}`` (registry kind ``preconditioner``), or None."""
    if not spec:
        return None
    params = dict(spec)
    if "name" not in params:
        raise ValueError(f"solver.preconditioner={params} needs a name, e.g. {{name: sobolev, length: 0.125}}")
    return build("preconditioner", params.pop("name"), **params)


def build_plugins(specs: Mapping[str, Any] | None) -> list[Any]:
    """Regularisers / post-step updates from ``{registry_name: {params}}``, in config order."""
    return [build("regularizer", name, **dict(params or {})) for name, params in (specs or {}).items()]


@dataclass
class SolverRecipe:
    """A registered solver class with its configured parts (step size, preconditioner,
    regularisers, post-steps, wavelet), built, and so checked, from config before any data
    exists; :meth:`build` makes the solver once the data term and the start are known."""

    cls: type
    parts: dict[str, Any]
    takes_context: bool

    def build(self, data: DataFidelity, d0: torch.Tensor, context: RegularizerContext) -> Any:
        """The solver for data term ``data``, start ``d0`` (m, m) and the regularisers' ``context``."""
        extra = {"context": context} if self.takes_context else {}
        return self.cls(data=data, d0=d0, **self.parts, **extra)


def solver_recipe(solver_cfg: Mapping[str, Any], regularizer_cfg: Mapping[str, Any] | None,
                  post_step_cfg: Mapping[str, Any] | None, wavelet_cfg: Mapping[str, Any] | None,
                  shape: tuple[int, int]) -> SolverRecipe:
    """The registered solver ``solver_cfg.name`` with the parts it takes, for heights of ``shape``.

    A part that is configured but that the solver does not use (e.g. regularisers for gradient
    descent) is an error rather than silently ignored.
    """
    name = solver_cfg["name"]
    cls = lookup("solver", name)
    accepted = set(inspect.signature(cls.__init__).parameters)
    regularizers = build_plugins(regularizer_cfg)
    parts: dict[str, Any] = {"step_size": make_step_size(solver_cfg["step_size"])}
    preconditioner_cfg = solver_cfg.get("preconditioner")
    offered: dict[str, tuple[Any, bool]] = {
        "preconditioner": (build_preconditioner(preconditioner_cfg), bool(preconditioner_cfg)),
        "regularizers": (regularizers, bool(regularizers)),
        "pixel_regularizers": (regularizers, bool(regularizers)),
        "post_steps": (build_plugins(post_step_cfg), bool(post_step_cfg)),
    }
    if wavelet_cfg:
        wavelet_regularizer = build("regularizer", "l1_wavelet", **dict(wavelet_cfg))
        offered["wavelet_regularizer"] = (wavelet_regularizer, True)
        offered["wavelet"] = (wavelet_regularizer.transform_for(tuple(shape)), True)
    for key, (value, configured) in offered.items():
        if key in accepted:
            parts[key] = value
    used = {k for k in offered if k in accepted}
    # regularizers / pixel_regularizers are two names for the same configured list.
    unused = {k.replace("pixel_", "") for k, (_, configured) in offered.items() if configured and k not in used}
    unused -= {k.replace("pixel_", "") for k in used}
    if unused:
        raise ValueError(f"solver {name} does not use {', '.join(sorted(unused))}; remove them from the config "
                         "or pick a solver that does (landweber_pixel, landweber_wavelet)")
    return SolverRecipe(cls, parts, "context" in accepted)
