"""Joint calibration: estimate parts of the setup together with the heights.

A lab setup is never known exactly: the screen's distance below the substrate, the light's
position and the camera's exposure gain are measured with a ruler or not at all. With
``calibration.params`` set, :class:`JointCalibration` alternates with the height solver: every
``every`` iterations it takes a damped Gauss-Newton (Levenberg-Marquardt) step on the chosen
parameters p at the current heights d,

    min_dp || W^(1/2) (G(d; p) + J dp - b) ||^2 + lambda || diag(J^T W J)^(1/2) dp ||^2,

J = dG/dp by central differences of renders with the same photons (common random numbers, so
the renders differ only by the change of p), or exactly for the gain (dG/dgain = G / gain).
A step is kept only if it lowers the weighted residual; otherwise lambda grows tenfold (up to
three tries). The reported uncertainty is the Gauss-Newton standard error at the current
heights, sigma_p = sqrt(diag((J^T W J)^-1) s^2) with s^2 = ||W^(1/2) r||^2 / (N - k): it holds
the heights fixed, so it is a lower bound on the joint uncertainty.

The state (parameters, updates, uncertainties) is written to ``calibration.json`` beside the
checkpoint after every update, and a resumed run starts from it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from framework.solvers.base import Callback
from operators.imaging import ImagingOperator
from operators.scene import Scene

__all__ = ["CALIBRATION_PARAMS", "JointCalibration", "setup_values", "with_setup"]

CALIBRATION_PARAMS = ("gain", "screen_distance", "light_height", "light_x", "light_y")
# Central-difference step, relative to the value (of the light height for the light's x and y,
# which may be 0).
_FD_STEP = 1e-3
_MAX_TRIES = 3


def setup_values(scene: Scene, gain: float) -> dict[str, float]:
    """Every calibration parameter's value for a scene and gain (scene units)."""
    x, y, z = scene.light.position
    return {"gain": gain, "screen_distance": -scene.receiver.z, "light_height": z, "light_x": x, "light_y": y}


def with_setup(scene: Scene, values: Mapping[str, float]) -> Scene:
    """``scene`` with the geometric calibration parameters in ``values`` replaced."""
    x, y, z = scene.light.position
    light = dataclasses.replace(scene.light, position=(values.get("light_x", x), values.get("light_y", y),
                                                       values.get("light_height", z)))
    receiver = dataclasses.replace(scene.receiver, z=-values.get("screen_distance", -scene.receiver.z))
    return dataclasses.replace(scene, light=light, receiver=receiver)


class JointCalibration(Callback):
    """Levenberg-Marquardt updates of setup parameters between height iterations.

    Args:
        operator: The operator seen through the camera, whose setup the updates change.
        params: Names from :data:`CALIBRATION_PARAMS`.
        every: Iterations between updates. Before iteration 1 only the gain is fitted (the flat
            start says little about the geometry).
        damping: Initial lambda of the Levenberg-Marquardt step.
    """

    order = 50  # after the stopping rules: an update acts on the next iteration

    def __init__(self, operator: ImagingOperator, params: Sequence[str], every: int = 10,
                 damping: float = 1e-3) -> None:
        if not isinstance(operator, ImagingOperator):
            raise ValueError("joint calibration needs the operator built with imaging=True (framework/scene_config.py)")
        unknown = [p for p in params if p not in CALIBRATION_PARAMS]
        if unknown or not params or len(set(params)) != len(params):
            raise ValueError(f"calibration.params={list(params)!r}: give distinct names from "
                             f"{', '.join(CALIBRATION_PARAMS)}")
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"calibration.every={every!r} must be an integer >= 1, e.g. 10")
        if isinstance(damping, bool) or not isinstance(damping, (int, float)) or not damping > 0:
            raise ValueError(f"calibration.damping={damping!r} must be a number > 0, e.g. 1e-3")
        self.operator, self.params, self.every = operator, list(params), every
        self.damping = float(damping)
        self.state_path: Path | None = None
        self.initial = self.values()
        self.std: dict[str, float] = {}
        self.updates = 0
        self.target: Tensor | None = None
        self.weights: Tensor | None = None

    @classmethod
    def from_config(cls, operator: Any, settings: Mapping[str, Any]) -> JointCalibration | None:
        """The calibration of the config group ``calibration`` (keys params, every, damping), or
        None when ``params`` is empty."""
        unknown = [k for k in settings if k not in ("params", "every", "damping")]
        if unknown:
            raise ValueError(f"unknown key calibration.{unknown[0]}; calibration takes params, every, damping")
        params = settings.get("params") or []
        if isinstance(params, str):
            params = [params]
        if not params:
            return None
        return cls(operator, list(params), every=settings.get("every", 10), damping=settings.get("damping", 1e-3))

    def values(self) -> dict[str, float]:
        """The current value of every calibrated parameter."""
        every_value = setup_values(self.operator.scene, self.operator.gain)
        return {p: every_value[p] for p in self.params}

    def setup(self, target: Tensor, weights: Tensor | None, state_path: Path, resume_from: Path | None = None) -> None:
        """The data b (c, n, n) and their weights (None: 1); the state is written to ``state_path``
        after every update; ``resume_from``, the state file of an interrupted run, restores it."""
        self.target = target.double()
        self.weights = None if weights is None else weights.double()
        self.state_path = state_path
        if resume_from is not None:
            if not resume_from.is_file():
                raise FileNotFoundError(f"resuming a calibrated run needs {resume_from} beside the checkpoint")
            state = json.loads(resume_from.read_text())
            self._apply(state["values"])
            self.initial, self.std, self.updates = state["initial"], state["std"], state["updates"]

    # -- the callback ----------------------------------------------------------------------------
    def on_start(self, solver) -> None:  # noqa: D102
        if solver.iteration == 0 and self.updates == 0 and "gain" in self.params:
            self.update(solver.d, ["gain"])
            solver.setup_changed()

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        if record.iteration % self.every == 0:
            self.update(solver.d)
            solver.setup_changed()
        record.extras.update({f"calibration_{p}": v for p, v in self.values().items()})

    # -- one Levenberg-Marquardt update -----------------------------------------------------------
    def _apply(self, values: Mapping[str, float]) -> None:
        gain = values.get("gain", self.operator.gain)
        self.operator.set_setup(with_setup(self.operator.scene, values), gain)

    def _render(self, d: Tensor, values: Mapping[str, float]) -> Tensor:
        """G(d) (c, n, n) with ``values`` in place of the current parameters (state restored after)."""
        current = self.values()
        self._apply(values)
        try:
            return self.operator.render(d).double()
        finally:
            self._apply(current)

    def _weighted_sq(self, x: Tensor) -> float:
        return float((x ** 2 if self.weights is None else self.weights * x ** 2).sum())

    def jacobian(self, d: Tensor, params: Sequence[str]) -> tuple[Tensor, Tensor]:
        """(G(d) (c, n, n), dG/dp (k, c, n, n)) at the current values, for ``params``."""
        values = self.values()
        image = self.operator.render(d).double()
        light_height = setup_values(self.operator.scene, self.operator.gain)["light_height"]
        columns = []
        for p in params:
            if p == "gain":
                columns.append(image / values["gain"])
                continue
            h = _FD_STEP * (abs(values[p]) if p in ("screen_distance", "light_height") else light_height)
            plus = self._render(d, {**values, p: values[p] + h})
            minus = self._render(d, {**values, p: values[p] - h})
            columns.append((plus - minus) / (2.0 * h))
        return image, torch.stack(columns)

    def update(self, d: Tensor, params: Sequence[str] | None = None) -> dict[str, float]:
        """One Levenberg-Marquardt step at heights d (m, m) on ``params`` (default: all of them);
        returns the new values."""
        if self.target is None:
            raise RuntimeError("JointCalibration.setup(target, weights) must be called before the first update")
        params = list(self.params if params is None else params)
        image, jac = self.jacobian(d, params)
        residual = image - self.target
        w = torch.ones_like(self.target) if self.weights is None else self.weights
        k = len(params)
        flat_j = jac.reshape(k, -1)
        normal = (flat_j * w.reshape(1, -1)) @ flat_j.T
        rhs = -(flat_j * w.reshape(1, -1)) @ residual.reshape(-1)
        before = self._weighted_sq(residual)
        values, lam = self.values(), self.damping
        for _ in range(_MAX_TRIES):
            step = torch.linalg.solve(normal + lam * torch.diag(torch.diag(normal)), rhs)
            trial = {**values, **{p: values[p] + float(s) for p, s in zip(params, step)}}
            if self._valid(trial) and self._weighted_sq(self._render(d, trial) - self.target) < before:
                self._apply(trial)
                break
            lam *= 10.0
        dof = max(int((w > 0).sum()) - k, 1)
        s2 = self._weighted_sq(self.operator.render(d).double() - self.target) / dof
        covariance = torch.linalg.pinv(normal) * s2
        self.std.update({p: math.sqrt(max(float(covariance[i, i]), 0.0)) for i, p in enumerate(params)})
        self.updates += 1
        self._save()
        return self.values()

    def _valid(self, values: Mapping[str, float]) -> bool:
        """Whether a trial keeps the setup physical (positive gain and distance, light above the glass)."""
        try:
            with_setup(self.operator.scene, values)
        except ValueError:
            return False
        return values.get("gain", 1.0) > 0.0 and values.get("screen_distance", 1.0) > 0.0

    def report(self) -> dict[str, float]:
        """Initial and final value and standard error of every parameter, for metrics."""
        out: dict[str, float] = {}
        for p, v in self.values().items():
            out[f"calibration_{p}"] = v
            out[f"calibration_{p}_initial"] = self.initial[p]
            if p in self.std:
                out[f"calibration_{p}_std"] = self.std[p]
        return out

    def _save(self) -> None:
        if self.state_path is not None:
            state: dict[str, Any] = {"values": self.values(), "std": self.std, "updates": self.updates,
                                     "initial": self.initial}
            self.state_path.write_text(json.dumps(state, indent=2))
