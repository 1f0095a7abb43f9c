"""A Gaussian spot integrated over each pixel, as a blur of receiver images and its derivative in
the width: the screen's blur (operators/imaging.py) and the blur of an extended light's patches
(operators/emission.py, in the photon operators' image chain, operators/photon_operator.py)."""

from __future__ import annotations

import math

import torch

from operators.linear.band_filter import separable_correlate
from operators.linear.linear_map import LinearMap
from operators.values import checked_number

__all__ = ["GaussianBlur", "PSF_TRUNCATE", "pixel_integrated_gaussian"]

PSF_TRUNCATE = 6.0  # the blur's taps reach 6 sigma: the Gaussian's mass beyond is 2e-9


def pixel_integrated_gaussian(sigma_px: float, truncate: float = PSF_TRUNCATE
                              ) -> tuple[torch.Tensor, torch.Tensor]:
    """The normalised 1-D taps p_k (k = -R .. R, R = ceil(truncate sigma), at least 1 for sigma > 0)
    of a Gaussian of standard deviation ``sigma_px`` (pixels) integrated over each pixel
    [k - 1/2, k + 1/2], and their derivative dp_k/dsigma (per pixel), both float64 (2R + 1,).
    sigma 0 gives the delta [1] and a zero derivative."""
    if sigma_px <= 0.0:
        return torch.ones(1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    radius = max(1, int(math.ceil(truncate * sigma_px)))
    scale = sigma_px * math.sqrt(2.0)
    # Taps k >= 0 (the kernel is even); erfc of the outer edges keeps the far taps accurate.
    taps = [math.erf(0.5 / scale)] + [0.5 * (math.erfc((k - 0.5) / scale) - math.erfc((k + 0.5) / scale))
                                     for k in range(1, radius + 1)]

    def density(x: float) -> float:  # x phi(x / sigma) / sigma^2 (0 where phi underflows)
        z = abs(x) / sigma_px
        return 0.0 if z > 40.0 else x * math.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * sigma_px ** 2)

    # d/dsigma [Phi(b / sigma) - Phi(a / sigma)] = (a phi(a / sigma) - b phi(b / sigma)) / sigma^2
    slopes = [-2.0 * density(0.5)] + [density(k - 0.5) - density(k + 0.5) for k in range(1, radius + 1)]
    half, half_slope = torch.tensor(taps, dtype=torch.float64), torch.tensor(slopes, dtype=torch.float64)
    t = torch.cat([half.flip(0), half[1:]])
    dt = torch.cat([half_slope.flip(0), half_slope[1:]])
    total, total_slope = t.sum(), dt.sum()
    p = t / total
    return p, (dt - p * total_slope) / total


class GaussianBlur(LinearMap):
    """Convolution of receiver images (c, n, n) with a Gaussian spot: the screen's point-spread
    function, or the patch of an extended light each emission point stands for.

    Args:
        sigma: Standard deviation of the Gaussian spot, scene units (0: no blur).
        pixel_size: Receiver pixel size, scene units.

    Each tap of the (separable) kernel is the Gaussian's integral over that pixel, by erf
    differences: the light of a point at a pixel's centre, spread by the screen, as the pixels
    collect it. Taps reach ``PSF_TRUNCATE`` (6) sigma (at least one pixel) and are normalised to sum 1, so
    the blur keeps the light that stays on the receiver; light spread past the edge is lost, as
    on a screen of that size. The kernel's variance is sigma^2 + 1/12 pixel^2 (the pixel box's),
    widths below a pixel keep their weight on the neighbours, and the taps are smooth in sigma
    down to 0, where the kernel is a delta (:meth:`derivative`: dK/dsigma, analytic).
    """

    def __init__(self, sigma: float, pixel_size: float) -> None:
        self.sigma = checked_number(sigma, "screen.sigma", 0.0,
                                    must="must be a length >= 0 (scene units or e.g. '0.1 mm')")
        self.pixel_size = float(pixel_size)
        self.sigma_px = self.sigma / self.pixel_size
        self.profile, self.profile_derivative = pixel_integrated_gaussian(self.sigma_px)

    @property
    def active(self) -> bool:
        """Whether the blur changes an image: sigma > 0 and a kernel that differs from a delta by more
        than rounding."""
        if self.profile.numel() == 1:
            return False
        centre = (self.profile.numel() - 1) // 2
        return 1.0 - float(self.profile[centre]) > 4.0 * torch.finfo(torch.float64).eps

    def _convolve(self, image: torch.Tensor) -> torch.Tensor:
        if not self.active:
            return image
        return separable_correlate(image, self.profile, self.profile)

    def apply(self, image: torch.Tensor) -> torch.Tensor:
        """K image: the blurred image (c, n, n)."""
        return self._convolve(image)

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        """K^T image; the kernel is symmetric and the padding zero, so K^T = K."""
        return self._convolve(image)

    def derivative(self, image: torch.Tensor) -> torch.Tensor:
        """(dK/dsigma) image (c, n, n), sigma in scene units: the 2-D kernel is p (x) p, so its
        derivative is p' (x) p + p (x) p'. Zero where the blur is not active."""
        if not self.active:
            return torch.zeros_like(image)
        p, dp = self.profile, self.profile_derivative / self.pixel_size
        return separable_correlate(image, dp, p) + separable_correlate(image, p, dp)

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(0.07, 0.05), (2, 16, 16)
