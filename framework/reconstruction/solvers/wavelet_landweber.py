"""M3: wavelet-based thresholded Landweber, eq. (9) (docs/method.md, "The methods M1, M2 and M3").

One iteration, in exactly this order (w = W d, W a Daubechies-3 wavelet transform):

    w <- S(w - tau_w (W^-1)^* grad_d f(W^-1 w), tau_w alpha_w)     (wavelet regulariser's prox)
    d  = W^-1 w
    d <- P_pixel(d, tau_p)        (pixel shrink alpha_p, bounds [p1, p2], mask), tau_p = ratio * tau_w
    d <- u_K(... u_1(d))          (post steps, e.g. the volume heuristic V1)
    w  = W d

grad_d f is evaluated at the current d, which equals W^-1 w because the previous iteration ended
with w = W d (W^-1 W = I).

With a preconditioner P the gradient step is w - tau W P grad_d f, a step in the metric
(W P W^*)^-1, and the shrinkage must be taken in the same metric: otherwise it moves the fine
scales, which P has damped, by tau alpha_w, and the step is no longer a descent direction (every
trial step then increases f and the run stops early). The shrinkage therefore uses the
diagonal of W P W^* (one value per subband, probed at the subband's middle coefficient; exact for a
translation-invariant P away from the border): S(w_i, tau alpha_w [W P W^*]_ii). The fixed points
are those of the unpreconditioned iteration up to that diagonal approximation.

The step-size policy chooses tau_w; the pixel prox step follows it with the fixed ratio
``pixel_step_ratio`` (the paper: tau_p = tau_w = 0.1, ratio 1).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
from collections.abc import Sequence

import torch
from torch import Tensor

from framework.core.contracts.solver import SolverBuilder
from framework.core.objective import DataFidelity
from framework.core.plugin_config import build_plugin, split_name
from framework.optimization.preconditioner import GradientPreconditioner
from framework.optimization.step_size import StepSizePolicy
from framework.reconstruction.solvers.proximal_gradient import Candidate, ProximalGradientSolver
from framework.reconstruction.solvers.proximal_parts import build_parts
from operators.values import checked_number
from regularizers import CoefficientRegularizer, CoefficientTransform

__all__ = ["WaveletLandweber"]


class WaveletLandweber(ProximalGradientSolver):
    """M3 (eq. 9): soft shrinkage of wavelet coefficients, then the pixel prox and post steps.

    Args:
        data: The data term f.
        d0: Initial height field (m, m).
        step_size: Policy or constant tau_w for the wavelet-domain gradient step.
        wavelet: Transform with ``forward(d) -> w`` (flat), ``inverse(w) -> d`` (m, m) and
            ``inverse_adjoint(g) -> (W^-1)^* g`` (flat).
        wavelet_regularizer: Has ``prox_coefficients(w, step[, metric])`` (shrink by step * alpha_w
            [* metric], see :meth:`regularizers.wavelet.WaveletL1.prox_coefficients`) and
            ``value(d)`` (alpha_w ||W d||_1, used for the objective and backtracking).
        pixel_regularizers: Pixel proxes (L1 with alpha_p, bounds, mask), applied in order.
        post_steps: Heuristic updates ``u(d) -> d`` (volume heuristic V1).
        pixel_step_ratio: tau_p / tau_w > 0.
        preconditioner: If given, grad_d f is replaced by P grad_d f (see :mod:`.preconditioner`).
        context: If given, passed to ``setup`` of every regulariser and post step.
    """

    name = "landweber_wavelet"

    def __init__(
        self,
        data: DataFidelity,
        d0: Tensor,
        step_size: StepSizePolicy | float,
        wavelet: Any,
        wavelet_regularizer: Any,
        pixel_regularizers: Sequence[Any] = (),
        post_steps: Sequence[Any] = (),
        pixel_step_ratio: float = 1.0,
        preconditioner: GradientPreconditioner | None = None,
        context: Any = None,
        two_metric_from: int | None = None,
        momentum_from: int | None = None,
        quasi_newton: Mapping[str, Any] | None = None,
        shaped_start_from: str = "first",
    ) -> None:
        checked_number(pixel_step_ratio, "pixel_step_ratio", above=0.0, unit="tau_p / tau_w")
        if not isinstance(wavelet, CoefficientTransform):
            raise ValueError(
                "landweber_wavelet needs a wavelet transform (a CoefficientTransform, regularizers/base.py); "
                f"got {type(wavelet).__name__}"
            )
        if not isinstance(wavelet_regularizer, CoefficientRegularizer):
            raise ValueError(
                "landweber_wavelet needs a wavelet regulariser (a CoefficientRegularizer with "
                f"prox_coefficients(w, step), regularizers/base.py); got {type(wavelet_regularizer).__name__}"
            )
        self.wavelet = wavelet
        self.wavelet_regularizer = wavelet_regularizer
        self.pixel_step_ratio = float(pixel_step_ratio)
        super().__init__(data, d0, step_size, pixel_regularizers, post_steps, preconditioner, context,
                         two_metric_from, momentum_from, quasi_newton, shaped_start_from)
        self.coefficients: Tensor = self.wavelet.forward(self.state.d)  # w = W d, flat
        self._metric: Tensor | None = None  # diag of W P W^* for the current preconditioner stage

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py)."""
        return {
            "step_size": {"name": "backtracking", "tau": 5e-3},
            "wavelet_regularizer": {"name": "l1_wavelet", "levels": 2},
            "preconditioner": {"name": "sobolev", "length": [0.25]},
            "quasi_newton": {"memory": 8, "from_stage": 0},
        }

    @classmethod
    def from_config(cls, step_size: Mapping[str, Any], wavelet_regularizer: Mapping[str, Any],
                    regularizers: Mapping[str, Any] | None = None, post_steps: Mapping[str, Any] | None = None,
                    pixel_step_ratio: float = 1.0, preconditioner: Mapping[str, Any] | None = None,
                    two_metric_from: int | None = None, momentum_from: int | None = None,
                    quasi_newton: Mapping[str, Any] | None = None, shaped_start_from: str = "first") -> SolverBuilder:
        """The plugin ``solver/landweber_wavelet``: ``wavelet_regularizer`` is a regulariser by key
        with ``prox_coefficients`` and ``transform_for`` (``{name: l1_wavelet, alpha_w: 1e-2,
        wavelet: db3, levels: 3}``); the other keys as :func:`build_parts`."""
        def fresh_parts() -> dict[str, Any]:
            return build_parts(step_size, preconditioner, regularizers, post_steps, two_metric_from, momentum_from,
                               quasi_newton, shaped_start_from)

        fresh_parts()  # a bad value fails now, before any render
        name, params = split_name(wavelet_regularizer, "solver.wavelet_regularizer")
        shrink = build_plugin("regularizer", name, params, "solver.wavelet_regularizer")
        if not isinstance(shrink, CoefficientRegularizer):
            raise ValueError(f"solver.wavelet_regularizer={name} has no wavelet transform (transform_for); "
                             "use l1_wavelet")
        checked_number(pixel_step_ratio, "solver.pixel_step_ratio", above=0.0, unit="tau_p / tau_w")

        def build(problem, d0: Tensor) -> WaveletLandweber:
            parts = fresh_parts()  # every run from a start with its own step size and preconditioner stage
            pixel = parts.pop("regularizers")
            return cls(
                problem.fidelity,
                d0,
                wavelet=shrink.transform_for(problem.grid.shape),
                wavelet_regularizer=shrink,
                pixel_regularizers=pixel,
                pixel_step_ratio=pixel_step_ratio,
                context=problem.context,
                **parts,
            )

        return build

    def _shrink_metric(self) -> Tensor | None:
        """Flat (m*m,) diagonal of W P W^* per subband, or None without a preconditioner (or for a
        transform without ``subbands()``)."""
        if self.preconditioner is None or not self.wavelet.subbands():
            return None
        if self._metric is None:
            like = self.state.d
            metric = torch.empty(like.numel(), dtype=like.dtype)
            for band, index in self.wavelet.subbands():
                probe = torch.zeros(like.numel(), dtype=like.dtype)
                probe[index] = 1.0
                response = self.wavelet.forward(self.preconditioner(self.wavelet.inverse(probe)))
                metric[band] = float(response[index])
            self._metric = metric
        return self._metric

    def _context_users(self) -> list[Any]:
        return [self.wavelet_regularizer, *super()._context_users()]

    def regularization_value(self, d: Tensor) -> float:
        """g(d) = alpha_w ||W d||_1 + the pixel regularisers' values."""
        return float(self.wavelet_regularizer.value(d)) + super().regularization_value(d)

    def _propose(self, tau: float) -> Candidate:
        grad_w = self.wavelet.inverse_adjoint(self._step_direction())
        shrink, metric = self.wavelet_regularizer.prox_coefficients, self._shrink_metric()
        moved = self.coefficients - tau * grad_w
        w = shrink(moved, tau) if metric is None else shrink(moved, tau, metric)
        d = self.wavelet.inverse(w)
        return {"d": self._prox_pixels(d, tau * self.pixel_step_ratio)}

    def _finalize(self, candidate: Candidate) -> Candidate:
        d = super()._finalize(candidate)["d"]
        return {"d": d, "w": self.wavelet.forward(d)}

    def _accept(self, candidate: Candidate) -> None:
        super()._accept(candidate)
        self.coefficients = candidate["w"]

    def refine(self, d: Tensor) -> bool:  # noqa: D102 (coefficients follow d, as after every iteration)
        if not super().refine(d):
            return False
        self.coefficients = self.wavelet.forward(self.state.d)
        self._metric = None
        return True

    def state_dict(self) -> dict[str, Any]:
        """Adds the wavelet coefficients w."""
        return {**super().state_dict(), "coefficients": self.coefficients}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        if state.get("coefficients") is None:
            raise ValueError("landweber_wavelet checkpoint has no wavelet coefficients; was it written by M3?")
        super().load_state_dict(state)
        self.coefficients = state["coefficients"].to(device=self.state.d.device)
