"""Orthogonal 2-D discrete wavelet transform W (Daubechies-3 by default) and the wavelet L1 prior.

Used by the wavelet Landweber method M3 (eq. (9); docs/method.md, "The methods M1, M2 and M3"):
    w_d <- S(w_d - tau_w grad_w f, tau_w alpha_w),  grad_w f = (W^-1)^* grad_d f.

We fix the boundary mode to ``"periodization"`` with an orthogonal wavelet and a grid width
divisible by 2**levels: then the coefficient vector has exactly m*m entries and W is an
orthogonal matrix, so W^* = W^-1 and (W^-1)^* = W, which the adjoint methods use (and the
tests check numerically). Other modes (e.g. "symmetric") add coefficients, make W a
non-square frame operator and would need separately derived adjoints, so they are refused.

The transform runs in PyWavelets on the CPU (a numpy round trip, cheap at m = 128) and
returns tensors of the input's dtype and device. It is not differentiable by autograd:
use the adjoint methods.
"""

from __future__ import annotations

import math

import numpy as np
import pywt
import torch

from operators.values import checked_height_field, checked_number

from .base import CoefficientRegularizer, CoefficientTransform, RegularizerContext
from .shrinkage import soft_shrink


class WaveletTransform(CoefficientTransform):
    """Orthogonal 2-D DWT W: R^(m x m) -> R^(m*m) (flat coefficient vector).

    Coefficients are laid out as ``pywt.coeffs_to_array`` does (approximation block top left),
    flattened row-major.

    Args:
        shape: Grid shape (m1, m2); each side divisible by 2**levels.
        wavelet: Name of an orthogonal PyWavelets wavelet (official "db3").
        levels: Number of decomposition levels >= 1 (official 3).
        mode: Boundary mode; only "periodization" (which keeps W orthogonal) is supported.
    """

    def __init__(
        self,
        shape: tuple[int, int] = (128, 128),
        wavelet: str = "db3",
        levels: int = 3,
        mode: str = "periodization",
    ) -> None:
        if len(shape) != 2 or any(int(s) < 1 for s in shape):
            raise ValueError(f"shape={shape!r} is not a 2-D grid shape; pass (m, m), e.g. (128, 128)")
        if int(levels) < 1:
            raise ValueError(f"levels={levels!r} must be >= 1; the paper uses 3")
        if mode != "periodization":
            raise ValueError(
                f"wavelet mode={mode!r} makes W non-orthogonal and its adjoints are not implemented; "
                "use mode='periodization'"
            )
        try:
            wav = pywt.Wavelet(wavelet)
        except ValueError:
            raise ValueError(f"unknown wavelet {wavelet!r}; pass a PyWavelets name such as 'db3'") from None
        if not wav.orthogonal:
            raise ValueError(f"wavelet {wavelet!r} is not orthogonal, so W would not be; pass e.g. 'db3' or 'haar'")
        self.shape = (int(shape[0]), int(shape[1]))
        self.levels = int(levels)
        block = 2**self.levels
        if any(s % block for s in self.shape):
            raise ValueError(
                f"grid shape {self.shape} is not divisible by 2**levels = {block}; "
                f"pick levels with m % 2**levels == 0 or resize the grid"
            )
        self.wavelet = wavelet
        self.mode = mode
        zeros = np.zeros(self.shape)
        array, self._slices = pywt.coeffs_to_array(pywt.wavedec2(zeros, wavelet, mode=mode, level=self.levels))
        self._array_shape = array.shape
        self.size = int(math.prod(array.shape))  # == m1 * m2 with periodization

    # --- the transform and its inverse -------------------------------------------------------
    def forward(self, d: torch.Tensor) -> torch.Tensor:
        """w = W d: flat coefficients, shape (m1*m2,), dtype/device of d."""
        self._check_grid(d)
        coeffs = pywt.wavedec2(d.detach().cpu().numpy(), self.wavelet, mode=self.mode, level=self.levels)
        array, _ = pywt.coeffs_to_array(coeffs)
        return torch.from_numpy(np.ascontiguousarray(array).reshape(-1)).to(dtype=d.dtype, device=d.device)

    def inverse(self, w: torch.Tensor) -> torch.Tensor:
        """d = W^-1 w: height field (m1, m2) from flat coefficients (m1*m2,), dtype/device of w."""
        self._check_coefficients(w)
        array = w.detach().cpu().numpy().reshape(self._array_shape)
        coeffs = pywt.array_to_coeffs(array, self._slices, output_format="wavedec2")
        d = pywt.waverec2(coeffs, self.wavelet, mode=self.mode)
        return torch.from_numpy(np.ascontiguousarray(d)).to(dtype=w.dtype, device=w.device)

    def subbands(self) -> list[tuple[torch.Tensor, int]]:
        """One (mask, centre) per subband: the approximation, then (horizontal, vertical, diagonal)
        detail from the coarsest level to the finest. ``mask`` (m1*m2,) bool selects the subband's
        flat coefficients; ``centre`` is the flat index of its middle coefficient, whose basis function
        lies away from the grid's border."""
        bands = [self._slices[0]] + [level[key] for level in self._slices[1:] for key in ("ad", "da", "dd")]
        out = []
        for rows, cols in bands:
            mask = np.zeros(self._array_shape, dtype=bool)
            mask[rows, cols] = True
            r0, r1, _ = rows.indices(self._array_shape[0])
            c0, c1, _ = cols.indices(self._array_shape[1])
            centre = ((r0 + r1) // 2) * self._array_shape[1] + (c0 + c1) // 2
            out.append((torch.from_numpy(mask.reshape(-1)), int(centre)))
        return out

    # --- adjoints (exact because W is orthogonal) --------------------------------------------
    def forward_adjoint(self, w: torch.Tensor) -> torch.Tensor:
        """W^* w = W^-1 w (W orthogonal); shape (m1, m2)."""
        return self.inverse(w)

    def inverse_adjoint(self, g: torch.Tensor) -> torch.Tensor:
        """(W^-1)^* g = W g (W orthogonal); maps a pixel gradient grad_d f (m1, m2) to grad_w f (m1*m2,)."""
        return self.forward(g)

    # --- checks --------------------------------------------------------------------------------
    def _check_grid(self, d: torch.Tensor) -> None:
        checked_height_field(d)
        if tuple(d.shape) != self.shape:
            raise ValueError(
                f"height field shape {tuple(d.shape)} does not match the transform grid {self.shape}; "
                "build WaveletTransform(shape=d.shape)"
            )

    def _check_coefficients(self, w: torch.Tensor) -> None:
        if not isinstance(w, torch.Tensor) or w.ndim != 1 or w.numel() != self.size:
            shape = tuple(w.shape) if isinstance(w, torch.Tensor) else type(w).__name__
            raise ValueError(f"wavelet coefficients must be a flat tensor of {self.size} values, got {shape}")
        if not bool(torch.isfinite(w).all()):
            raise ValueError("wavelet coefficients contain NaN/inf; check the step size or the gradient")

    def __repr__(self) -> str:
        return (
            f"WaveletTransform(shape={self.shape}, wavelet={self.wavelet!r}, "
            f"levels={self.levels}, mode={self.mode!r})"
        )


class WaveletL1(CoefficientRegularizer):
    """R(d) = alpha_w * ||W d||_1 with the orthogonal DWT W (method M3).

    In coefficient space (w = W d) the prox is soft shrinkage, :meth:`prox_coefficients`;
    in pixel space, since W is orthogonal, prox_{step R}(d) = W^-1 S(W d, step * alpha_w).
    The transform is built by :meth:`setup` from the mask's shape, or on first use from d.

    Args:
        alpha_w: Weight >= 0 (official 1e-2).
        wavelet: Orthogonal PyWavelets wavelet (official "db3").
        levels: Decomposition levels (official 3).
    """

    has_prox = True
    smooth = False

    def __init__(self, alpha_w: float = 1e-2, wavelet: str = "db3", levels: int = 3) -> None:
        self.alpha_w = checked_number(
            alpha_w, "alpha_w", least=0.0, unit="the wavelet L1 weight", example="1e-2 (the paper)"
        )
        self.wavelet = wavelet
        self.levels = int(levels)
        self._transform: WaveletTransform | None = None

    def setup(self, ctx: RegularizerContext) -> None:
        """Store the context and build W for the mask's grid."""
        super().setup(ctx)
        self._transform = WaveletTransform(tuple(ctx.mask.shape), self.wavelet, self.levels)  # type: ignore[arg-type]

    def transform_for(self, shape: tuple[int, int]) -> WaveletTransform:
        """The transform W on grid ``shape`` (built and cached on first use)."""
        shape = (int(shape[0]), int(shape[1]))
        if self._transform is None or self._transform.shape != shape:
            self._transform = WaveletTransform(shape, self.wavelet, self.levels)
        return self._transform

    def value(self, d: torch.Tensor) -> float:
        """alpha_w * ||W d||_1 for d of shape (m, m)."""
        checked_height_field(d)
        return self.alpha_w * float(self.transform_for(tuple(d.shape)).forward(d).abs().sum())

    def prox_coefficients(self, w: torch.Tensor, step: float, metric: torch.Tensor | None = None) -> torch.Tensor:
        """S(w, step * alpha_w * metric): prox of step * alpha_w * ||.||_1 on flat coefficients w,
        in the metric diag(1 / metric) if ``metric`` (flat, positive) is given, else the plain one."""
        if not isinstance(w, torch.Tensor) or not bool(torch.isfinite(w).all()):
            raise ValueError("wavelet coefficients must be a finite torch.Tensor; check the step size or gradient")
        k = self._check_step(step) * self.alpha_w
        return soft_shrink(w, k if metric is None else k * metric.to(w))

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """W^-1 S(W d, step * alpha_w), shape (m, m) (exact because W is orthogonal)."""
        checked_height_field(d)
        transform = self.transform_for(tuple(d.shape))
        return transform.inverse(self.prox_coefficients(transform.forward(d), step))
