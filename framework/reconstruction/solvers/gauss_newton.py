"""``gauss_newton``: M2 with Levenberg-Marquardt directions from conjugate gradients on J^T J
(docs/method.md, "Gauss-Newton steps").

The proximal-gradient iteration of M2 (framework/reconstruction/solvers/proximal_gradient.py) with its
regularisers, post steps, bounds, two-metric steps and stopping rules, whose direction on the free
samples is the damped Gauss-Newton step

    (H + lambda I) p = grad f,    H = J^T W J / (||b||_W^2 a)    (the data term's curvature),

solved inexactly by conjugate gradients preconditioned with the Sobolev metric P. Each product
H v costs one adjoint pass and J v: a forward difference of two renders with the same photons, or
the operator's exact Jacobian-vector product (``product: exact``)
(:meth:`framework.core.objective.DataFidelity.curvature_product`). The products may trace a share
of the data term's photons (``curvature_share``) in a pattern of the iteration's own, the same for
all of one direction's products, so that conjugate gradients see one symmetric matrix: the
Gauss-Newton matrix of a sampled operator. lambda = mu times the Rayleigh quotient of H along the
first preconditioned residual. The search's first trial is the full step p; mu adapts as in
Levenberg-Marquardt: halved when the search accepts that trial, doubled when it had to shorten it,
and back to ``damping`` when the preconditioner's stage changes. As with the quasi-Newton direction, p
is returned divided by gamma = <g, p> / <g, P g>, so that the step size tau and the L1 prox's
threshold tau alpha keep their meaning; the full step is tau = gamma.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
from collections.abc import Callable

import torch
from torch import Tensor

from framework.core.contracts.solver import SolverBuilder
from framework.core.solver_loop import IterationRecord
from framework.reconstruction.solvers.pixel_methods import PixelLandweber
from framework.reconstruction.solvers.proximal_parts import build_parts, check_regularizers
from operators.image_operator import ImageOperator
from operators.values import checked_number, checked_seed, checked_whole

__all__ = ["GaussNewtonLandweber", "check_gauss_newton"]

DEFAULTS = {"cg_iterations": 6, "cg_tolerance": 0.1, "damping": 0.1, "fd_step": 1e-4, "curvature_share": 0.125,
            "product": "difference", "seed": 0, "misfit_share": None}
PRODUCTS = ("difference", "exact")
MIN_CURVATURE_PHOTONS = 4096  # a curvature operator never traces fewer photons than this
CURVATURE_SEED_OFFSET = 5000  # the curvature patterns: seed + 5000 + the iteration (photon_budget uses + 3000)


def check_gauss_newton(settings: Any) -> dict[str, float]:
    """``solver.gauss_newton`` (the keys of :data:`DEFAULTS`, each optional) checked, with
    :data:`DEFAULTS` for those not given."""
    if settings is None:
        settings = {}
    if not isinstance(settings, Mapping) or set(settings) - set(DEFAULTS):
        raise ValueError(f"solver.gauss_newton={settings!r} must be a map with keys among {', '.join(DEFAULTS)}, "
                         "e.g. {cg_iterations: 6, damping: 0.1}")
    out = {**DEFAULTS, **settings}
    out["cg_iterations"] = checked_whole(out["cg_iterations"], "solver.gauss_newton.cg_iterations", 1)
    out["seed"] = checked_seed(out["seed"], "solver.gauss_newton.seed")
    if out["misfit_share"] is not None:
        out["misfit_share"] = checked_number(
            out["misfit_share"], "solver.gauss_newton.misfit_share", above=0.0, below=1.0,
            must="must lie in (0, 1) or be null: the share of the relative discrepancy a step may leave by its "
                 "linear model")
    if out["product"] not in PRODUCTS:
        raise ValueError(f"solver.gauss_newton.product={out['product']!r} must be one of {', '.join(PRODUCTS)}")
    out["curvature_share"] = checked_number(
        out["curvature_share"], "solver.gauss_newton.curvature_share", above=0.0, most=1.0,
        must="must lie in (0, 1]: the share of the data term's photons that the curvature products trace")
    for key in ("damping", "fd_step"):
        out[key] = checked_number(out[key], f"solver.gauss_newton.{key}", above=0.0)
    out["cg_tolerance"] = checked_number(
        out["cg_tolerance"], "solver.gauss_newton.cg_tolerance", above=0.0, below=1.0,
        must="must lie in (0, 1): the residual of the linear solve relative to the gradient")
    return out


class GaussNewtonLandweber(PixelLandweber):
    """M2 (:class:`PixelLandweber`) along damped Gauss-Newton directions (module docstring).

    Args:
        gauss_newton: ``{cg_iterations, cg_tolerance, damping, fd_step, curvature_share, product,
            seed, misfit_share}``: conjugate-gradient iterations per direction at most, their
            stopping residual relative to the gradient, the initial Levenberg-Marquardt factor mu,
            the largest height change of a forward difference (scene units), the share of the data
            term's photons the curvature products trace (default 1/8; 1: the data term's own
            operator and render), ``difference`` or ``exact`` Jacobian-vector products, the seed of
            the curvature's photon patterns (seed + 5000 + the iteration), and the inexact Newton
            rule's rho (None: off).

    The other arguments are :class:`PixelLandweber`'s (``quasi_newton`` is not used).
    """

    name = "gauss_newton"

    def __init__(self, *args: Any, gauss_newton: Mapping[str, Any] | None = None, **kwargs: Any) -> None:
        kwargs["quasi_newton"] = None
        kwargs["momentum_from"] = None
        super().__init__(*args, **kwargs)
        self.settings = check_gauss_newton(gauss_newton)
        if self.settings["product"] == "exact" and not self.data.operator.has_jvp:
            raise ValueError(f"solver.gauss_newton.product=exact needs an operator with a Jacobian-vector product; "
                             f"{type(self.data.operator).__name__} has none: use product=difference")
        self.mu = float(self.settings["damping"])
        self.cg_steps = 0  # conjugate-gradient iterations of the last direction
        self.full_step: float | None = None  # gamma of the last direction: tau of its full Gauss-Newton step

    def _plain_gradient(self) -> bool:
        return False

    def _free_direction(self, grad: Tensor, free: Tensor | None = None) -> Tensor:
        """p / gamma (m, m) on the ``free`` samples (None: all), zero elsewhere."""
        keep = (lambda x: x) if free is None else (lambda x: torch.where(free, x, torch.zeros_like(x)))
        d = self.state.d
        exact = self.settings["product"] == "exact"
        operator, image = self._curvature_operator(d, exact)

        def curvature(v: Tensor) -> Tensor:
            return keep(self.data.curvature_product(d, image, v, self.settings["fd_step"], operator, exact))

        g = keep(grad)
        p = self._conjugate_gradients(curvature, g, lambda x: keep(self._apply_metric(x)),
                                      self._current_evaluation().value)
        gamma = float(torch.sum(g * p)) / max(float(torch.sum(g * keep(self._apply_metric(g)))), 1e-300)
        if not gamma > 0.0:  # not a descent direction (a curvature product of the wrong sign): P grad
            self.full_step = None
            return keep(self._apply_metric(g))
        self.full_step = gamma
        return p / gamma

    def _curvature_operator(self, d: Tensor, exact: bool) -> tuple[ImageOperator, Tensor | None]:
        """The operator of this direction's curvature products and its render at d (None for
        ``exact`` products): the data term's own and its image, or with ``curvature_share`` of its
        photons (at least MIN_CURVATURE_PHOTONS) in a pattern of this iteration's own, the same for
        every product of the direction, so that conjugate gradients see one symmetric matrix."""
        operator = self.data.operator
        photons = max(MIN_CURVATURE_PHOTONS, round(int(operator.photons) * self.settings["curvature_share"]))
        if photons >= int(operator.photons):
            return operator, None if exact else self._current_evaluation().image
        operator = operator.with_photons(photons, self.settings["seed"] + CURVATURE_SEED_OFFSET + self.iteration)
        if exact:
            return operator, None
        self.data.count_passes(renders=1, gradients=0, photons=photons)
        with torch.no_grad():
            return operator, operator.render(d).detach()

    def _conjugate_gradients(self, curvature: Callable[[Tensor], Tensor], g: Tensor,
                             precondition: Callable[[Tensor], Tensor], value: float) -> Tensor:
        """Approximately solve (H + lambda I) p = g by preconditioned CG from p = 0; lambda = mu
        times the Rayleigh quotient of H along the first preconditioned residual. With
        ``misfit_share`` rho, CG stops as soon as the step's linear model of the data term,
        f - <g, p> + <p, H p> / 2, falls to rho^2 f (``value``): the step explains all but rho of
        the relative discrepancy (the inexact Newton rule of Hanke and Rieder)."""
        p = torch.zeros_like(g)
        hp = torch.zeros_like(g)  # H p, without the damping
        r = g.clone()
        z = precondition(r)
        direction = z.clone()
        rz = float(torch.sum(r * z))
        g_norm = float(torch.linalg.vector_norm(g))
        share = self.settings["misfit_share"]
        lam = None
        self.cg_steps = 0
        for _ in range(int(self.settings["cg_iterations"])):
            hq = curvature(direction)
            qq = float(torch.sum(direction * direction))
            if lam is None:
                lam = self.mu * max(float(torch.sum(direction * hq)) / max(qq, 1e-300), 0.0)
            aq = hq + lam * direction
            curv = float(torch.sum(direction * aq))
            self.cg_steps += 1
            if not curv > 0.0:
                break
            alpha = rz / curv
            p = p + alpha * direction
            hp = hp + alpha * hq
            r = r - alpha * aq
            if float(torch.linalg.vector_norm(r)) <= self.settings["cg_tolerance"] * g_norm:
                break
            if share is not None and value - float(torch.sum(g * p)) + 0.5 * float(torch.sum(p * hp)) <= (
                    share * share * value):
                break
            z = precondition(r)
            rz_new = float(torch.sum(r * z))
            direction = z + (rz_new / rz) * direction
            rz = rz_new
        return p if self.cg_steps and float(torch.sum(p * p)) > 0.0 else precondition(g)

    def step(self) -> IterationRecord:
        """One iteration whose search first tries the full Gauss-Newton step (tau = gamma, where the
        direction p / gamma is p); then mu adapts to how the search received it."""
        self.full_step = None
        self._step_direction()
        if self.full_step is not None:
            self.step_size.start_from(self.full_step)
        record = super().step()
        self.mu = self.mu * 0.5 if record.extras.get("trials", 1.0) <= 1.0 else self.mu * 2.0
        self.mu = min(max(self.mu, 1e-4), 1e4)
        record.extras["gauss_newton_cg_steps"] = float(self.cg_steps)
        record.extras["gauss_newton_damping"] = self.mu
        return record

    def refine(self, d: Tensor) -> bool:
        """The next preconditioner stage (:meth:`PixelLandweber.refine`); mu starts again from ``damping``
        (a new metric; the photon budget's changes keep it)."""
        if not super().refine(d):
            return False
        self.mu = float(self.settings["damping"])
        return True

    def state_dict(self) -> dict[str, Any]:
        """Adds the damping factor mu."""
        return {**super().state_dict(), "gauss_newton_mu": self.mu}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        super().load_state_dict(state)
        self.mu = float(state.get("gauss_newton_mu", self.settings["damping"]))

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py)."""
        return {"step_size": {"name": "backtracking", "tau": 5e-3}, "regularizers": {"l1_bounds": {}},
                "preconditioner": {"name": "sobolev", "length": [0.25]}, "gauss_newton": {"cg_iterations": 3}}

    @classmethod
    def from_config(cls, step_size: Mapping[str, Any], regularizers: Mapping[str, Any] | None = None,
                    post_steps: Mapping[str, Any] | None = None, preconditioner: Mapping[str, Any] | None = None,
                    two_metric_from: int | None = None, momentum_from: int | None = None,
                    quasi_newton: Mapping[str, Any] | None = None, shaped_start_from: str = "first",
                    gauss_newton: Mapping[str, Any] | None = None) -> SolverBuilder:
        """The plugin ``solver/gauss_newton``: the keys of ``landweber_pixel`` (``momentum_from`` and
        ``quasi_newton`` accepted and unused) and ``gauss_newton``."""
        check_gauss_newton(gauss_newton)

        def fresh_parts() -> dict[str, Any]:
            parts = build_parts(step_size, preconditioner, regularizers, post_steps, two_metric_from, None, None,
                                shaped_start_from)
            cls._require_regularizers(parts["regularizers"])
            check_regularizers(parts["regularizers"], cls.name)
            return parts

        fresh_parts()  # a bad value fails now, before any render
        return lambda problem, d0: cls(problem.fidelity, d0, context=problem.context, gauss_newton=gauss_newton,
                                       **fresh_parts())
