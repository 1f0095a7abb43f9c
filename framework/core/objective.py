"""The data term of every reconstruction: f(d) = 1/2 ||F(d) - b||_F^2 / (||b||_F^2 a).

(With per-pixel weights, both norms are weighted: :class:`DataFidelity`.)

The paper writes the data term as f(d) = 1/2 ||F(d) - b^delta||_F^2 (docs/method.md,
"The data term"). We divide it by ||b^delta||_F^2 so that f is dimensionless and does not
depend on the brightness or units of the caustic image (photon count, exposure, flux
normalisation). **This is our step-size unit**: a step tau multiplies grad f of the
*normalised* data term, so tau is in scene units^2 per unit of relative squared residual, and
the same tau works for a dim and a bright image. Step sizes taken from the official code
(tau_p = 0.1, ...) are in that code's own image scaling and must be re-tuned in this unit.

The optional cell area a (default 1) makes the unit resolution independent as well (see
:class:`DataFidelity`). The relative discrepancy ||F(d) - b||_F / ||b||_F equals sqrt(2 a f(d))
(docs/method.md, "The data term").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from operators.image_operator import ImageOperator
from operators.values import checked_number

__all__ = [
    "DataEvaluation",
    "DataFidelity",
]


@dataclass(frozen=True)
class DataEvaluation:
    """The data term at one height field.

    Attributes:
        value: f(d) = 1/2 ||F(d) - b||^2 / ||b||^2 (dimensionless).
        grad: grad f(d), shape (m, m) (1 / scene unit), or None for a value-only evaluation.
        image: F(d), shape (c, n, n).
        rel_discrepancy: ||F(d) - b||_F / ||b||_F.
    """

    value: float
    grad: Tensor | None
    image: Tensor
    rel_discrepancy: float


class DataFidelity:
    """f(d) = 1/2 ||F(d) - b||_W^2 / ||b||_W^2, its gradient and the relative discrepancy.

    ||x||_W^2 = sum w x^2 with per-pixel weights w in [0, 1] (1 everywhere unless given: pixels
    a photo cannot tell, such as saturated ones, get 0 and drop out of the fit).

    Args:
        operator: The forward operator F (framework/core/contracts/operator.py).
        target: The measured caustic image b^delta, shape (c, n, n), finite; it may hold small
            negative values (additive noise) but its total energy must be positive.
        max_negative_fraction: Refuse a target whose negative mass exceeds this fraction of its
            positive mass (a sign or offset error, not noise).
        cell_area: Area a of one height sample (scene units^2). f is divided by a, which makes
            grad f the gradient in the L2 metric of the substrate (sum_j a u_j v_j) rather than of
            the sample vector: step sizes and L1 weights then mean the same at every height-field
            resolution m (the per-sample gradient of f shrinks like a as m grows).
        weights: Per-pixel weights w (c, n, n) in [0, 1], or None for 1 everywhere; the weighted
            gradient is the operator's ``vjp(d, w (F(d) - b))``.

    Example:
        >>> from operators.image_operator import ImageOperator
        >>> class Identity(ImageOperator):  # F(d) = d on a 2 x 2 receiver
        ...     dtype, photons, pixel_area, output_shape = torch.float64, 0, 1.0, (1, 2, 2)
        ...     def render(self, d, progress=False): return d.reshape(1, 2, 2).clone()
        ...     def vjp(self, d, g): return g.reshape(2, 2).clone()
        >>> data = DataFidelity(Identity(), torch.ones(1, 2, 2, dtype=torch.float64))
        >>> data.evaluate(torch.zeros(2, 2, dtype=torch.float64)).rel_discrepancy
        1.0
    """

    def __init__(self, operator: ImageOperator, target: Tensor, max_negative_fraction: float = 0.25,
                 cell_area: float = 1.0, weights: Tensor | None = None) -> None:
        self.cell_area = checked_number(cell_area, "cell_area", above=0.0, unit="scene units^2")
        if not isinstance(operator, ImageOperator):
            raise ValueError(f"operator {type(operator).__name__} does not keep the operator contract: derive it from "
                             "operators.image_operator.ImageOperator")
        self.operator = operator
        self.target = self._validated_target(target, operator, max_negative_fraction)
        self.weights = None if weights is None else self._validated_weights(weights, self.target)
        self.target_norm_sq = float(torch.sum(self._weighted(self.target.double() ** 2)))
        if not self.target_norm_sq > 0.0:
            raise ValueError("the target is zero wherever the weights are non-zero; check the image and its weights")
        self.target_norm = math.sqrt(self.target_norm_sq)
        # The last value-only evaluation (d, operator revision, F(d)): a gradient evaluation at the
        # same d of the same operator (the accepted trial of a line search) hands F(d) to the
        # operator instead of rendering again.
        self._last_forward: tuple[Tensor, int, Tensor] | None = None
        self.renders = 0  # forward passes of the operator so far
        self.gradient_passes = 0  # backward passes
        self.photon_traces = 0  # photons traced by both (a backward pass traces every photon again)

    @staticmethod
    def _validated_weights(weights: Tensor, target: Tensor) -> Tensor:
        if not isinstance(weights, Tensor) or tuple(weights.shape) != tuple(target.shape):
            shape = tuple(weights.shape) if isinstance(weights, Tensor) else type(weights).__name__
            raise ValueError(f"weights have shape {shape}; they must match the target {tuple(target.shape)}")
        if not bool(torch.isfinite(weights).all()) or float(weights.min()) < 0.0 or float(weights.max()) > 1.0:
            raise ValueError("weights must be finite and lie in [0, 1] (0: a pixel left out of the fit)")
        return weights.detach().to(target)

    def _weighted(self, squares: Tensor) -> Tensor:
        return squares if self.weights is None else squares * self.weights.to(squares)

    def _revision(self) -> int:
        return int(self.operator.revision)

    def _loss_and_grad(self, d: Tensor, rendered: Tensor | None) -> tuple[Tensor, Tensor]:
        """(gradient of 1/2 ||F(d) - b||_W^2, F(d))."""
        if self.weights is None:
            if rendered is None:
                _, grad, image = self.operator.loss_and_grad(d, self.target)
            else:
                _, grad, image = self.operator.loss_and_grad(d, self.target, image=rendered)
            return grad, image
        image = self.operator.render(d) if rendered is None else rendered
        self._check_image(image)
        return self.operator.vjp(d, self.weights.to(image) * (image - self.target.to(image))), image

    @staticmethod
    def _validated_target(target: Tensor, operator: ImageOperator, max_negative_fraction: float) -> Tensor:
        if not isinstance(target, Tensor):
            raise ValueError(f"target must be a torch.Tensor (c, n, n), got {type(target).__name__}")
        if target.ndim != 3 or target.shape[1] != target.shape[2] or target.shape[0] < 1:
            raise ValueError(
                f"target must have shape (c, n, n) with square images, got {tuple(target.shape)}; "
                "add a channel axis with target[None] for a single-wavelength image"
            )
        if not target.is_floating_point():
            raise ValueError(f"target has dtype {target.dtype}; convert it with target.double() or target.float()")
        if not bool(torch.isfinite(target).all()):
            bad = int((~torch.isfinite(target)).sum())
            raise ValueError(f"target has {bad} non-finite pixels (nan/inf); clean the image before reconstructing")
        positive = float(target.clamp(min=0).sum())
        negative = float((-target).clamp(min=0).sum())
        if positive <= 0.0:
            raise ValueError("target has no positive energy (sum of positive pixels is 0); is it the right image?")
        if negative > max_negative_fraction * positive:
            raise ValueError(
                f"target's negative mass is {negative / positive:.3g} of its positive mass "
                f"(allowed {max_negative_fraction}); noise gives small negatives only, check sign and offset"
            )
        expected = operator.output_shape
        if tuple(expected) != tuple(target.shape):
            raise ValueError(
                f"target shape {tuple(target.shape)} does not match the operator's output_shape "
                f"{tuple(expected)}; resample the image or configure the operator's resolution"
            )
        return target.detach()

    def _check_d(self, d: Tensor) -> None:
        if not isinstance(d, Tensor) or d.ndim != 2 or d.shape[0] != d.shape[1]:
            shape = tuple(d.shape) if isinstance(d, Tensor) else type(d).__name__
            raise ValueError(f"height field d must be a square (m, m) tensor, got {shape}")

    def _check_image(self, image: Tensor) -> None:
        if tuple(image.shape) != tuple(self.target.shape):
            raise ValueError(
                f"operator {type(self.operator).__name__} returned an image of shape {tuple(image.shape)}, "
                f"but the target has shape {tuple(self.target.shape)}"
            )

    def evaluate(self, d: Tensor, with_grad: bool = True) -> DataEvaluation:
        """f(d), grad f(d) (if ``with_grad``; else one forward pass only), F(d) and the discrepancy.

        Args:
            d: Height field, shape (m, m), scene units.
            with_grad: False for a value-only evaluation (one forward pass, no backward).
        """
        self._check_d(d)
        known = self._last_forward
        rendered = None
        if known is not None and known[1] == self._revision() and torch.equal(known[0], d):
            rendered = known[2]
        if with_grad:
            self.count_passes(renders=int(rendered is None), gradients=1)
            grad, image = self._loss_and_grad(d, rendered)
            if tuple(grad.shape) != tuple(d.shape):
                raise ValueError(
                    f"operator {type(self.operator).__name__} returned a gradient of shape "
                    f"{tuple(grad.shape)} for d of shape {tuple(d.shape)}"
                )
            grad = grad.detach() / (self.target_norm_sq * self.cell_area)
        else:
            if rendered is None:
                self.count_passes(renders=1, gradients=0)
                with torch.no_grad():
                    rendered = self.operator(d).detach()
                self._last_forward = (d.detach().clone(), self._revision(), rendered)
            image = rendered
            grad = None
        image = image.detach()
        self._check_image(image)
        rel = self.relative_discrepancy(image)
        return DataEvaluation(value=0.5 * rel * rel / self.cell_area, grad=grad, image=image, rel_discrepancy=rel)

    def curvature_product(self, d: Tensor, image: Tensor | None, v: Tensor, fd_step: float,
                          operator: ImageOperator | None = None, exact: bool = False) -> Tensor:
        """The Gauss-Newton product J^T W J v / (||b||_W^2 a) (m, m) of the data term at d (m, m)
        with a direction v (m, m), through ``operator`` (default: the data term's; another photon
        count of the same physics for a cheaper product), whose render at d is ``image``.

        J v is the operator's exact Jacobian-vector product where ``exact`` (it must declare
        ``has_jvp``; ``image`` may then be None), else the forward difference (F(d + h v) - F(d)) / h
        of two renders with the same photons (common random numbers), h = ``fd_step`` / max |v|
        (the largest height change, scene units); then one adjoint pass. Costs a JVP or a render,
        and an adjoint pass, of ``operator``."""
        operator = self.operator if operator is None else operator
        scale = float(v.abs().max())
        if not scale > 0.0:
            return torch.zeros_like(d)
        if exact:
            jv = operator.jvp(d, v).detach()
        elif image is None:
            raise ValueError("a forward-difference curvature product needs the operator's render at d")
        else:
            h = fd_step / scale
            with torch.no_grad():
                moved = operator.render(d + h * v).detach()
            self._check_image(moved)
            jv = (moved - image) / h
        product = operator.vjp(d, jv if self.weights is None else self.weights.to(jv) * jv)
        self.count_passes(renders=1, gradients=1, photons=int(operator.photons))
        return product.detach() / (self.target_norm_sq * self.cell_area)

    def count_passes(self, renders: int, gradients: int, photons: int | None = None) -> None:
        """Count operator passes spent on this data term (``photons`` per shot each; default: the
        operator's; a stack of shots, operators/stack.py, traces them once per shot)."""
        self.renders += renders
        self.gradient_passes += gradients
        photons = int(self.operator.photons) if photons is None else photons
        self.photon_traces += (renders + gradients) * photons * int(self.operator.shot_count)

    def relative_discrepancy(self, image: Tensor) -> float:
        """||image - b||_W / ||b||_W."""
        return self.relative_difference(image, self.target)

    def relative_difference(self, image: Tensor, other: Tensor) -> float:
        """||image - other||_W / ||b||_W for two images (c, n, n)."""
        return math.sqrt(float(torch.sum(self._weighted((image.double() - other.double()) ** 2)))
                         / self.target_norm_sq)

    def use_operator(self, operator: ImageOperator) -> None:
        """Go on with another operator of the same output shape (e.g. the same physics with other
        photons, framework/reconstruction/photon_budget.py); forgets the last render."""
        if tuple(operator.output_shape) != tuple(self.target.shape):
            raise ValueError(f"operator {type(operator).__name__} renders {tuple(operator.output_shape)}, "
                             f"the target has shape {tuple(self.target.shape)}")
        self.operator = operator
        self._last_forward = None

    def value(self, d: Tensor) -> float:
        """f(d) by one forward pass."""
        return self.evaluate(d, with_grad=False).value

    __call__ = value
