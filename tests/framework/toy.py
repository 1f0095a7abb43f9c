"""Small linear toy problems and fake regularisers for the solver-framework tests (float64)."""

from __future__ import annotations

import torch
from torch import Tensor

from framework.core.objective import DataFidelity
from regularizers import CoefficientRegularizer, CoefficientTransform, PostStepUpdate, Regularizer
from operators.image_operator import ImageOperator

DTYPE = torch.float64


class LinearOperator(ImageOperator):
    """F(d) = A vec(d) reshaped to (c, n, n); gradient of 1/2||F(d) - b||^2 is A^T (A d - b)."""

    dtype = DTYPE
    photons = 0
    pixel_area = 1.0

    def __init__(self, A: Tensor, m: int, output_shape: tuple[int, int, int], noise: float = 0.0) -> None:
        self.A, self.m, self._shape, self.noise = A, m, output_shape, noise
        self.calls = 0

    @property
    def output_shape(self) -> tuple[int, int, int]:
        return self._shape

    def render(self, d: Tensor, progress: bool = False) -> Tensor:
        return self(d)

    def vjp(self, d: Tensor, grad_image: Tensor) -> Tensor:
        return (self.A.T @ grad_image.reshape(-1)).reshape(d.shape)

    def __call__(self, d: Tensor) -> Tensor:
        self.calls += 1
        image = (self.A @ d.reshape(-1)).reshape(self.output_shape)
        if self.noise:  # a "stochastic" operator drawing from the global torch RNG
            image = image + self.noise * torch.randn(self.output_shape, dtype=image.dtype)
        return image

    def loss_and_grad(self, d: Tensor, target: Tensor, image: Tensor | None = None) -> tuple[float, Tensor, Tensor]:
        image = self(d) if image is None else image
        r = (image - target).reshape(-1)
        return 0.5 * float(r @ r), (self.A.T @ r).reshape(d.shape), image


def make_problem(m: int = 8, n: int = 10, seed: int = 0, noise: float = 0.01, op_noise: float = 0.0):
    """A = [I; B] with B >= 0 (well-conditioned, non-negative images), sparse d_true >= 0."""
    g = torch.Generator().manual_seed(seed)
    k = n * n - m * m
    B = torch.rand(k, m * m, generator=g, dtype=DTYPE) / 8.0
    A = torch.cat([torch.eye(m * m, dtype=DTYPE), B])
    d_true = torch.zeros(m, m, dtype=DTYPE)
    idx = torch.randperm(m * m, generator=g)[:6]
    d_true.view(-1)[idx] = 0.05 + 0.1 * torch.rand(6, generator=g, dtype=DTYPE)
    op = LinearOperator(A, m, (1, n, n), noise=op_noise)
    clean = (A @ d_true.reshape(-1)).reshape(1, n, n)
    b = clean + noise * clean.norm() / n * torch.randn(1, n, n, generator=g, dtype=DTYPE)
    data = DataFidelity(op, b)
    lipschitz = float(torch.linalg.matrix_norm(A, ord=2) ** 2) / data.target_norm_sq
    return data, op, A, b, d_true, lipschitz


class L1(Regularizer):
    """alpha ||d||_1 with soft-shrink prox."""

    has_prox = True

    def __init__(self, alpha: float, log: list | None = None, tag: str = "pixel_prox") -> None:
        self.alpha, self.log, self.tag, self.steps = alpha, log, tag, []

    def value(self, d: Tensor) -> float:
        return self.alpha * float(d.abs().sum())

    def prox(self, d: Tensor, step: float) -> Tensor:
        if self.log is not None:
            self.log.append(self.tag)
        self.steps.append(step)
        return torch.sign(d) * torch.clamp(d.abs() - step * self.alpha, min=0.0)


class Bounds(Regularizer):
    """Indicator of [p1, p2]; prox = clamp."""

    has_prox = True

    def __init__(self, p1: float = 0.0, p2: float = 0.3) -> None:
        self.p1, self.p2 = p1, p2

    def value(self, d: Tensor) -> float:
        return 0.0 if bool(((d >= self.p1) & (d <= self.p2)).all()) else float("inf")

    def prox(self, d: Tensor, step: float) -> Tensor:
        return d.clamp(self.p1, self.p2)


class OrthogonalTransform(CoefficientTransform):
    """w = Q vec(d) with Q orthogonal; records forward/inverse/inverse_adjoint calls in ``log``."""

    def __init__(self, m: int, log: list, seed: int = 1) -> None:
        g = torch.Generator().manual_seed(seed)
        self.Q, _ = torch.linalg.qr(torch.randn(m * m, m * m, generator=g, dtype=DTYPE))
        self.m, self.log = m, log

    def forward(self, d: Tensor) -> Tensor:
        self.log.append("forward")
        return self.Q @ d.reshape(-1)

    def inverse(self, w: Tensor) -> Tensor:
        self.log.append("inverse")
        return (self.Q.T @ w).reshape(self.m, self.m)

    def inverse_adjoint(self, g: Tensor) -> Tensor:
        self.log.append("inverse_adjoint")
        return self.Q @ g.reshape(-1)


class WaveletL1(CoefficientRegularizer):
    """alpha_w ||Q d||_1 with prox_coefficients = soft shrink; records its prox calls."""

    def __init__(self, transform: OrthogonalTransform, alpha: float, log: list) -> None:
        self.transform, self.alpha, self.log = transform, alpha, log

    def value(self, d: Tensor) -> float:
        return self.alpha * float((self.transform.Q @ d.reshape(-1)).abs().sum())

    def transform_for(self, shape: tuple[int, int]) -> OrthogonalTransform:
        return self.transform

    def prox_coefficients(self, w: Tensor, step: float, metric: Tensor | None = None) -> Tensor:
        self.log.append("prox_coefficients")
        return torch.sign(w) * torch.clamp(w.abs() - step * self.alpha, min=0.0)


class SpyPostStep(PostStepUpdate):
    """A post step that records its calls and returns d unchanged (a copy)."""

    def __init__(self, log: list) -> None:
        self.log = log

    def __call__(self, d: Tensor) -> Tensor:
        self.log.append("post")
        return d.clone()
