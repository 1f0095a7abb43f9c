"""Joint calibration: parts of the setup estimated together with the heights (docs/method.md,
"Joint calibration", which derives and measures what this module does).

With ``calibration.params`` set, :class:`JointCalibration` alternates with the height solver:
every ``every`` iterations one Levenberg-Marquardt step on the chosen parameters p at the current
heights d, on the posterior of p given the data and the measured (configured) values p0,

    Phi(p) = ||W^(1/2) (G(d; p) - b)||^2 / s^2 + sum_i ((p_i - p0_i) / (prior * |p0_i|))^2,

J = dG/dp by central differences of renders with the same photons, exactly for the gain and the
screen blur's width (operators/imaging.py); a step is kept only if it lowers Phi, else lambda grows
tenfold (``_MAX_TRIES`` tries). The geometry moves only once the fit is within twice the noise
level and stays within ``BOUND`` prior standard deviations of its measured value; ``psf_sigma``
and ``light_size`` have a weak prior (``PSF_PRIOR`` times the start) and steps of at most a factor
``PSF_STEP``. On a stack of shots (framework/stack/stack_data.py) the screen distance moves with a
factor k on the heights (the shots' offsets tell the distance only jointly with the heights'
strength), and an iteration Morozov's rule would accept is first followed by an update at its
heights until the geometry settles. The state goes to ``calibration.json`` after every update, and
a resumed run starts from it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from framework.core.data import weighted_norm_sq
from framework.core.contracts.calibration import SetupCalibration
from framework.lab.calibrated_setup import PSF, CameraSetup, StackSetup, is_gain, setup_values, with_setup
from framework.lab.calibration_config import calibration_settings
from operators.stack import StackOperator
from operators.values import checked_number, checked_whole

__all__ = ["CALIBRATION_PARAMS", "JointCalibration", "setup_values", "with_setup"]

SIZE = "light_size"  # an extended light's diameter or side, scene units (operators/scene.py)
CALIBRATION_PARAMS = ("gain", "screen_distance", "light_height", "light_x", "light_y", SIZE, PSF)
# Parameters that no ruler measures (the blur's width, the flash's size): a weak prior and steps of
# at most a factor PSF_STEP.
WIDTHS = (PSF, SIZE)
# A run whose calibration moved the light's size by more than this share is solved again from its
# start under the calibrated setup (framework/reconstruction/reconstruction.py): the heights fitted
# while the size was off absorbed part of its blur.
REFIT_SHARE = 0.02
# Central-difference step, relative to the value (of the light height for the light's x and y,
# which may be 0).
_FD_STEP = 1e-3
# The geometry stays within BOUND prior standard deviations of its measured value.
BOUND = 2.0
# The factor on the heights that a stack's screen distance moves with (internal, not reported).
HEIGHT_SCALE = "height_scale"
_MAX_TRIES = 3
# Iterations at the noise level in a row whose update still moves the geometry by more than its
# standard error, after which Morozov's rule may stop anyway.
MAX_SETTLE_ROUNDS = 20
# The prior of psf_sigma: standard deviation PSF_PRIOR x its start (at least one receiver pixel).
PSF_PRIOR = 10.0
# One update changes psf_sigma by at most this factor either way (the image is far from linear in a
# width below a pixel, where a Gauss-Newton step overshoots).
PSF_STEP = 2.0


class JointCalibration(SetupCalibration):
    """Levenberg-Marquardt updates of setup parameters between height iterations (the calibration
    plugin ``joint``, framework/core/contracts/calibration.py).

    Args:
        operator: The operator seen through the camera, or a stack of shots each seen through its
            camera (framework/lab/calibrated_setup.py), whose setup the updates change.
        params: Names from :data:`CALIBRATION_PARAMS` (for a stack, ``gain`` is every shot's gain).
        every: Iterations between updates. Before iteration 1 only the gain is fitted (the flat
            start says little about the geometry).
        damping: Initial lambda of the Levenberg-Marquardt step.
        prior: Relative standard deviation of the configured (measured) geometry, e.g. 0.1 for a
            distance known to 10%; the light's x and y relative to its height.
        psf_sigma_start: Where ``psf_sigma`` starts, scene units (None: the operator's blur when it
            has one, else one receiver pixel); it is moved there by :meth:`setup`.
    """

    # Before the stopping rules: on a stack, an iteration whose discrepancy Morozov's rule would
    # accept is first judged under the setup calibrated at its heights (module docstring).
    order = -40

    def __init__(self, operator: Any, params: Sequence[str], every: int = 30,
                 damping: float = 1e-3, prior: float = 0.1, scene: Any = None,
                 psf_sigma_start: float | None = None, volume_held: bool = False) -> None:
        unknown = [p for p in params if p not in CALIBRATION_PARAMS]
        if unknown or not params or len(set(params)) != len(params):
            raise ValueError(f"calibration.params={list(params)!r}: give distinct names from "
                             f"{', '.join(CALIBRATION_PARAMS)}")
        every = checked_whole(every, "calibration.every", 1, example="30")
        damping = checked_number(damping, "calibration.damping", above=0.0, must="must be a number > 0", example="1e-3")
        prior = checked_number(prior, "calibration.prior", above=0.0, must="must be a relative standard deviation > 0",
                               example="0.1")
        self.setup_of = StackSetup(operator, scene) if isinstance(operator, StackOperator) else CameraSetup(operator)
        if SIZE in params and not self.setup_of.scene.light.extended:
            raise ValueError(f"calibration.params has {SIZE} but light.shape=point; give light.shape=disc or square "
                             "and light.size where the fit starts (e.g. '30 mm')")
        self.params, self.every = self.setup_of.names(params), every
        self.damping, self.prior = float(damping), float(prior)
        self.state_path: Path | None = None
        self.initial = self.values()
        if PSF in self.params:
            if psf_sigma_start is not None:
                checked_number(psf_sigma_start, "calibration.psf_sigma_start", above=0.0,
                               must="must be a length > 0 (scene units or e.g. '0.1 mm'), or null to start from "
                                    "screen.sigma")
            configured = self.initial[PSF]
            self.initial[PSF] = float(psf_sigma_start if psf_sigma_start is not None else
                                      configured if configured > 0.0 else self.setup_of.pixel_size)
        self.std: dict[str, float] = {}
        self.updates = 0
        self.target: Tensor | None = None
        self.weights: Tensor | None = None
        self.delta = 0.0
        self.goal: float | None = None
        self.geometry_started = False
        # A stack's screen distance moves with a scale of the heights (the shots' offsets tell the
        # distance only jointly with the heights' strength; module docstring), unless the solver
        # holds the known volume (regularizers/volume_hold.py), which fixes that strength itself.
        # Its geometry, and that of a run that fits the light's size (which the heights absorb in
        # part while it is off), is updated at every iteration at the noise level until it settles.
        distance = isinstance(self.setup_of, StackSetup) and "screen_distance" in self.params
        self.settles = distance or SIZE in self.params
        self.scales_heights = distance and not volume_held
        self.height_scale = 1.0  # the last update's factor on the heights (1: none)
        self.settle_rounds = 0  # updates at the noise level in a row that still moved the geometry

    @classmethod
    def from_config(cls, operator: Any, settings: Mapping[str, Any], scene: Any = None,
                    screen_sigma: float = 0.0, volume_held: bool = False) -> JointCalibration | None:
        """The calibration of the config group ``calibration`` (keys params, every, damping, prior,
        psf_sigma_start), or None when ``params`` is empty; ``scene``: the configured scene (a
        stack's shots keep their offsets from it); ``screen_sigma``: the configured ``screen.sigma``
        (scene units, whatever ``screen.psf``), where ``psf_sigma`` starts unless
        ``psf_sigma_start`` is given (0: one receiver pixel); ``volume_held``: the solver holds the
        known volume, so a stack's distance moves without a factor on the heights."""
        settings_ = calibration_settings(settings, operator, scene, screen_sigma)
        return None if settings_ is None else cls(operator, scene=scene, volume_held=volume_held, **settings_)

    def gain_of_shot(self, index: int) -> JointCalibration | None:
        """The calibration of shot ``index``'s gain alone (a stack's first fit,
        framework/stack/first_fit.py), or None when the gains are not calibrated or there is no
        stack."""
        if not isinstance(self.setup_of, StackSetup) or not any(is_gain(p) for p in self.params):
            return None
        return JointCalibration(self.setup_of.shots[index], ["gain"], every=self.every, damping=self.damping,
                                prior=self.prior)

    def values(self) -> dict[str, float]:
        """The current value of every calibrated parameter."""
        every_value = self.setup_of.values()
        return {p: every_value[p] for p in self.params}

    def setup(self, target: Tensor, weights: Tensor | None, delta: float, state_path: Path,
              resume_from: Path | None = None, goal: float | None = None) -> None:
        """The data b (c, n, n), their weights (None: 1) and relative noise level delta; the state
        is written to ``state_path`` after every update; ``resume_from``, the state file of an
        interrupted run, restores it; ``goal``: the discrepancy Morozov's rule accepts (tau_dis
        delta; None: no rule). A calibrated ``psf_sigma`` moves to its start here (a fresh run)."""
        self.target = target.double()
        self.weights = None if weights is None else weights.double()
        self.delta = float(delta)
        self.goal = goal
        self.state_path = state_path
        if PSF in self.params and resume_from is None:
            self._apply({PSF: self.initial[PSF]})
        if resume_from is not None:
            if not resume_from.is_file():
                raise FileNotFoundError(f"resuming a calibrated run needs {resume_from} beside the checkpoint")
            state = json.loads(resume_from.read_text())
            self._apply(state["values"])
            self.initial, self.std, self.updates = state["initial"], state["std"], state["updates"]
            self.geometry_started = state["geometry_started"]
            self.settle_rounds = int(state.get("settle_rounds", 0))  # a state without it: none counted

    # -- the callback ----------------------------------------------------------------------------
    def on_start(self, solver) -> None:  # noqa: D102
        gains = [p for p in self.params if is_gain(p)]
        if solver.iteration == 0 and self.updates == 0 and gains:
            self.update(solver.d, gains)
            solver.setup_changed()

    def on_iteration(self, solver, record) -> None:  # noqa: D102
        self.geometry_started |= record.rel_discrepancy <= 2.0 * self.delta
        params = self.params if self.geometry_started else [p for p in self.params if is_gain(p)]
        settle = (self.settles and self.geometry_started and self.goal is not None
                  and record.rel_discrepancy <= self.goal)
        if (record.iteration % self.every == 0 or settle) and params:
            before = self.values()
            self.update(solver.d, params)
            if settle:  # a geometry still moving by more than its standard error has not settled
                now = self.values()
                moved = [p for p in params if not is_gain(p) and abs(now[p] - before[p]) > self.std.get(p, 0.0)]
                self.settle_rounds = self.settle_rounds + 1 if moved else 0
                record.extras["calibration_settled"] = float(not moved or self.settle_rounds > MAX_SETTLE_ROUNDS)
                self._save()
            if self.height_scale != 1.0:
                solver.set_heights(solver.d * self.height_scale)
            solver.setup_changed()
            if settle:  # the stopping rules judge the heights under the setup calibrated at them
                record.rel_discrepancy = math.sqrt(self._weighted_sq(self.setup_of.render(solver.d) - self.target)
                                                   / self._weighted_sq(self.target))
        record.extras.update({f"calibration_{p}": v for p, v in self.values().items()})

    # -- one Levenberg-Marquardt update -----------------------------------------------------------
    def _apply(self, values: Mapping[str, float]) -> None:
        self.setup_of.apply(values)

    def _render(self, d: Tensor, values: Mapping[str, float]) -> Tensor:
        """G(k d) with ``values`` in place of the current parameters (the setup unchanged), k their
        ``height_scale`` (1 if absent)."""
        return self.setup_of.render(d * values.get(HEIGHT_SCALE, 1.0), values)

    def _weighted_sq(self, x: Tensor) -> float:
        return weighted_norm_sq(x, self.weights)

    def _scale(self, p: str) -> float:
        """The size of parameter p at its measured value (of the light height for the light's x, y)."""
        if p == HEIGHT_SCALE:
            return 1.0
        own = is_gain(p) or p in ("screen_distance", "light_height", SIZE)
        return abs(self.initial.get(p, 1.0)) if own else abs(setup_values(self.setup_of.scene, 1.0)["light_height"])

    def jacobian(self, d: Tensor, params: Sequence[str]) -> tuple[Tensor, Tensor]:
        """(G(d) (c, n, n), dG/dp (k, c, n, n)) at the current values, for ``params``."""
        values = {**self.values(), HEIGHT_SCALE: 1.0}
        if PSF in params:
            image, psf_column = self.setup_of.render_and_psf_column(d)
        else:
            image = self.setup_of.render(d)
        columns = []
        for p in params:
            if is_gain(p):
                columns.append(self.setup_of.gain_column(image, p, values))
                continue
            if p == PSF:
                columns.append(psf_column)
                continue
            h = _FD_STEP * (values[p] if p == SIZE else self._scale(p))
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
        if self.scales_heights and "screen_distance" in params:
            params.append(HEIGHT_SCALE)
        image, jac = self.jacobian(d, params)
        w = torch.ones_like(self.target) if self.weights is None else self.weights
        k = len(params)
        s2 = self._weighted_sq(image - self.target) / max(int((w > 0).sum()) - k, 1)
        flat_j = jac.reshape(k, -1)
        data_normal = (flat_j * w.reshape(1, -1)) @ flat_j.T / s2
        precision = torch.diag(torch.tensor([self._precision(p) for p in params], dtype=torch.float64))
        values, lam = {**self.values(), HEIGHT_SCALE: 1.0}, self.damping
        initial = {**self.initial, HEIGHT_SCALE: 1.0}
        offset = torch.tensor([values[p] - initial[p] for p in params], dtype=torch.float64)
        rhs = -(flat_j * w.reshape(1, -1)) @ (image - self.target).reshape(-1) / s2 - precision @ offset
        normal = data_normal + precision

        def posterior(trial: Mapping[str, float], rendered: Tensor) -> float:
            shift = torch.tensor([trial[p] - initial[p] for p in params], dtype=torch.float64)
            return self._weighted_sq(rendered - self.target) / s2 + float(shift @ precision @ shift)

        before = posterior(values, image)
        self.height_scale = 1.0
        for _ in range(_MAX_TRIES):
            step = torch.linalg.solve(normal + lam * torch.diag(torch.diag(normal)), rhs)
            trial = {**values, **{p: self._bounded(p, values[p] + float(s), values[p]) for p, s in zip(params, step)}}
            if self._valid(trial) and posterior(trial, self._render(d, trial)) < before:
                self._apply(trial)
                self.height_scale = trial[HEIGHT_SCALE]
                break
            lam *= 10.0
        covariance = torch.linalg.pinv(normal)
        self.std.update({p: math.sqrt(max(float(covariance[i, i]), 0.0)) for i, p in enumerate(params)
                         if p != HEIGHT_SCALE})
        self.updates += 1
        self._save()
        return self.values()

    def _precision(self, p: str) -> float:
        """The prior's precision of parameter p: 0 for the gains (no prior), weak for psf_sigma and
        light_size (a standard deviation of PSF_PRIOR times the start)."""
        if is_gain(p) or p == HEIGHT_SCALE:
            return 0.0
        if p == PSF:
            return (PSF_PRIOR * max(self.initial[PSF], self.setup_of.pixel_size)) ** -2
        if p == SIZE:
            return (PSF_PRIOR * self.initial[SIZE]) ** -2
        return (self.prior * self._scale(p)) ** -2

    def _bounded(self, p: str, value: float, current: float) -> float:
        """``value`` of parameter p clipped to BOUND prior standard deviations around its measured
        value; psf_sigma's and light_size's to [current / 2, 2 current] (PSF_STEP), so they stay > 0."""
        if is_gain(p):
            return value
        if p in WIDTHS:
            return min(max(value, current / PSF_STEP), current * PSF_STEP)
        if p == HEIGHT_SCALE:
            return min(max(value, 1.0 - BOUND * self.prior), 1.0 + BOUND * self.prior)
        reach = BOUND * self.prior * self._scale(p)
        return min(max(value, self.initial[p] - reach), self.initial[p] + reach)

    def _valid(self, values: Mapping[str, float]) -> bool:
        """Whether a trial keeps the setup physical (positive gain and distance, light above the glass)."""
        try:
            with_setup(self.setup_of.scene, values)
        except ValueError:
            return False
        return all(v > 0.0 for p, v in values.items() if is_gain(p)) and values.get("screen_distance", 1.0) > 0.0

    def needs_refit(self, before: Mapping[str, float]) -> bool:
        """Whether the light's size moved by more than REFIT_SHARE from ``before`` (the values when
        the heights' run began): heights fitted under a wrong size absorb part of its blur, and a
        run from the start under the calibrated size ends nearer the truth."""
        return SIZE in self.params and abs(self.values()[SIZE] / before[SIZE] - 1.0) > REFIT_SHARE

    def describe_move(self, before: Mapping[str, float]) -> str:
        """``light_size 35 -> 49.3 mm``: how the size moved from ``before``."""
        mm = float(self.setup_of.scene.mm_per_unit)
        return f"{SIZE} {before[SIZE] * mm:.4g} -> {self.values()[SIZE] * mm:.4g} mm"

    def never_updated(self) -> list[str]:
        """The calibrated parameters that no update has moved yet (the run met the noise level before
        the first update that includes them): they keep their configured values."""
        return [p for p in self.params if p not in self.std]

    def report(self) -> dict[str, float]:
        """Initial and final value and standard error of every parameter, for metrics (psf_sigma
        also in receiver pixels and mm)."""
        out: dict[str, float] = {}
        for p, v in self.values().items():
            out[f"calibration_{p}"] = v
            out[f"calibration_{p}_initial"] = self.initial[p]
            if p in self.std:
                out[f"calibration_{p}_std"] = self.std[p]
            if not is_gain(p) and p not in WIDTHS:
                reach = BOUND * self.prior * self._scale(p)
                out[f"calibration_{p}_at_bound"] = float(abs(v - self.initial[p]) >= reach * (1 - 1e-9))
        out.update({f"calibration_{k}": v for k, v in self.psf_units().items()})
        if SIZE in self.params:
            mm = float(self.setup_of.scene.mm_per_unit)
            out[f"calibration_{SIZE}_mm"] = self.values()[SIZE] * mm
            if SIZE in self.std:
                out[f"calibration_{SIZE}_std_mm"] = self.std[SIZE] * mm
        return out

    def psf_units(self) -> dict[str, float]:
        """The calibrated psf_sigma and its standard error in receiver pixels and mm
        (``psf_sigma_px``, ``psf_sigma_mm``, ``psf_sigma_std_px``, ``psf_sigma_std_mm``); empty when
        it is not calibrated."""
        if PSF not in self.params:
            return {}
        units = {"px": 1.0 / self.setup_of.pixel_size, "mm": float(self.setup_of.scene.mm_per_unit)}
        out = {f"{PSF}_{unit}": self.values()[PSF] * factor for unit, factor in units.items()}
        if PSF in self.std:
            out.update({f"{PSF}_std_{unit}": self.std[PSF] * factor for unit, factor in units.items()})
        return out

    def _save(self) -> None:
        if self.state_path is not None:
            state: dict[str, Any] = {"values": self.values(), "std": self.std, "updates": self.updates,
                                     "initial": self.initial, "geometry_started": self.geometry_started,
                                     "settle_rounds": self.settle_rounds, **self.psf_units()}
            self.state_path.write_text(json.dumps(state, indent=2))
