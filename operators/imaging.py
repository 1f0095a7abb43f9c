"""What the camera records of a caustic: the screen's blur and the exposure gain.

The caustic falls on a diffuse screen (the paper's lab setup: a semi-transparent paper screen
photographed from below) that spreads every point of light over a small spot, the screen's
point-spread function; the camera then records it with an unknown gain (exposure, aperture,
flash energy). :class:`ImagingOperator` wraps any operator plugin F into

    G(d) = gain * K * F(d),

K a convolution over the receiver with the point-spread function (a Gaussian integrated over
each pixel, :class:`ScreenBlur`; zero outside the receiver), and gives its adjoint
G'(d)^* g = F'(d)^* (gain * K^T g) for the gradient. Where F renders on a finer receiver and
block-averages (operators/supersample.py: F = A F_fine), the blur acts on the fine receiver,
G = gain A K_fine F_fine: a blur below a pixel applied after the pixels' averaging cannot be told
from a wider one (a 0.5-pixel spot fits best as 0.59 px and leaves a 13% misfit on sharp lines),
while on a 4 x finer grid it is found to 1% (docs/method.md, "Screen and camera"). The scene it was built for, the gain and the
blur's width can be changed (joint calibration of the setup, framework/pipeline/calibration.py,
which takes dG/dsigma = gain (dK/dsigma) F(d) from the same render): the wrapped operator is
rebuilt for a new scene; ``revision`` counts the changes so that cached renders of an earlier
setup are not reused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import torch

from operators.band_filter import separable_correlate
from operators.photon_operator import ImageOperator
from operators.scene import Scene
from operators.supersample import SupersampledOperator, block_mean, block_mean_adjoint

__all__ = ["ScreenBlur", "ImagingOperator", "PSF_KINDS", "pixel_integrated_gaussian"]

PSF_KINDS = ("none", "gaussian")
PSF_TRUNCATE = 6.0  # the blur's taps reach 6 sigma: the Gaussian's mass beyond is 2e-9
# An exact reference seen through a blur is rendered this many times finer, blurred there and
# block-averaged, as the model is (synthetic data of a configured screen.psf).
EXACT_BLUR_SUPERSAMPLE = 4


def _fine_stage(operator: Any) -> tuple[Any, int]:
    """(the operator that renders the finest receiver, its factor over ``operator``'s pixels): a
    supersampled operator's fine one, else the operator itself and 1."""
    if isinstance(operator, SupersampledOperator):
        return operator.fine, operator.factor
    return operator, 1


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


class ScreenBlur:
    """Convolution of receiver images (c, n, n) with the screen's point-spread function.

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
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"screen.sigma={sigma!r} must be a length >= 0 (scene units or e.g. '0.1 mm')")
        self.sigma = float(sigma)
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


class ImagingOperator(ImageOperator):
    """G(d) = gain * K * F(d): an operator plugin seen through the screen and the camera.

    Args:
        build: Builds the wrapped operator plugin F for a scene (the same settings, photons and
            seed every time).
        scene: The scene to build it for.
        psf_sigma: The screen's Gaussian spot, standard deviation in scene units (0: none).
        gain: Exposure gain (image units per W per scene unit^2).
    """

    def __init__(self, build: Callable[[Scene], Any], scene: Scene, psf_sigma: float = 0.0, gain: float = 1.0) -> None:
        self._build = build
        self.psf_sigma = psf_sigma
        self.scene: Scene | None = None
        self.revision = -1
        self.set_setup(scene, gain)

    def set_setup(self, scene: Scene, gain: float, psf_sigma: float | None = None) -> None:
        """Rebuild for another scene (light, receiver distance), gain and screen blur (None: the
        current one); counts a revision."""
        if not (math.isfinite(gain) and gain > 0.0):
            raise ValueError(f"gain={gain!r} must be a positive finite number")
        sigma = self.psf_sigma if psf_sigma is None else psf_sigma
        if self.scene != scene:
            self.inner = self._build(scene)
            self.scene = scene
            self.fine, self.factor = _fine_stage(self.inner)
            self.blur = ScreenBlur(sigma, self.fine.scene.receiver.pixel_size)
        elif sigma != self.blur.sigma:
            self.blur = ScreenBlur(sigma, self.fine.scene.receiver.pixel_size)
        self.psf_sigma = self.blur.sigma
        self.gain = float(gain)
        self.revision += 1

    def _blur_of(self, psf_sigma: float | None) -> ScreenBlur:
        if psf_sigma is None or psf_sigma == self.blur.sigma:
            return self.blur
        return ScreenBlur(psf_sigma, self.fine.scene.receiver.pixel_size)

    def _blurred(self, fine: Any, factor: int, blur: ScreenBlur, heights: torch.Tensor, progress: bool = False
                 ) -> torch.Tensor:
        """A K_fine F_fine(d) (c, n, n): the fine render blurred, then block-averaged."""
        return block_mean(blur.apply(fine.render(heights, progress=progress)), factor)

    def render_with(self, scene: Scene, gain: float, heights: torch.Tensor, psf_sigma: float | None = None
                    ) -> torch.Tensor:
        """gain * K * F(d) (c, n, n) for another setup (the same receiver grid; ``psf_sigma`` None:
        the current blur), leaving this operator's own setup, and its wrapped operator, as they are."""
        fine, factor = (self.fine, self.factor) if scene == self.scene else _fine_stage(self._build(scene))
        return gain * self._blurred(fine, factor, self._blur_of(psf_sigma), heights)

    def render_and_sigma_derivative(self, heights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(G(d), dG/dsigma) (c, n, n) each from one render of F(d): gain A K F(d) and
        gain A (dK/dsigma) F(d), sigma the screen blur's in scene units (joint calibration of
        ``psf_sigma``)."""
        caustic = self.fine.render(heights)
        return (self.gain * block_mean(self.blur.apply(caustic), self.factor),
                self.gain * block_mean(self.blur.derivative(caustic), self.factor))

    # -- what the framework uses of an operator plugin -------------------------------------------
    @property
    def dtype(self) -> torch.dtype:
        return self.inner.dtype

    @property
    def photons(self) -> int:
        return self.inner.photons

    @property
    def pixel_area(self) -> float:
        return self.inner.pixel_area

    @property
    def output_shape(self) -> tuple[int, int, int]:
        return tuple(self.inner.output_shape)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """gain * K * F(d) (c, n, n) (gain A K_fine F_fine(d) for a supersampled F)."""
        return self.gain * self._blurred(self.fine, self.factor, self.blur, heights, progress)

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* (gain * K^T grad_image) (m, m) (F_fine'(d)^* (gain K_fine^T A^T grad_image))."""
        if tuple(grad_image.shape) != self.output_shape:
            raise ValueError(f"grad_image has shape {tuple(grad_image.shape)}, expected {self.output_shape}")
        return self.fine.vjp(heights, self.gain * self.blur.adjoint(block_mean_adjoint(grad_image, self.factor)))

    @property
    def has_light_path(self) -> bool:
        """The wrapped operator's (whose ``arrivals`` and ``land_from_bottom`` it passes on)."""
        return bool(self.inner.has_light_path)

    def warm_up(self) -> AbstractContextManager[Any]:
        """The wrapped operator's warm-up."""
        return self.inner.warm_up()

    def variant(self, photons: int, seed: int, resolution: int) -> ImagingOperator:
        """The same camera on another sampling of the wrapped operator (the references of
        synthetic data); its setup stays fixed."""
        inner = self.inner.variant(photons, seed, resolution)
        return ImagingOperator(lambda scene: inner, self.scene, self.psf_sigma, self.gain)

    def exact_variant(self, photons: int, seed: int, resolution: int) -> ImagingOperator:
        """The same camera on the wrapped operator's exact references (synthetic data). Through an
        active blur a reference that is not supersampled already is rendered
        ``EXACT_BLUR_SUPERSAMPLE`` times finer, blurred there and block-averaged."""
        inner = self.inner.exact_variant(photons, seed, resolution)
        if self.blur.active and not isinstance(inner, SupersampledOperator):
            fine = self.inner.exact_variant(photons, seed, resolution * EXACT_BLUR_SUPERSAMPLE)
            inner = SupersampledOperator(fine, inner.scene, EXACT_BLUR_SUPERSAMPLE)
        return ImagingOperator(lambda scene: inner, self.scene, self.psf_sigma, self.gain)

    def __getattr__(self, name: str) -> Any:
        # Anything else an operator plugin offers (device, settings, ...) comes from the
        # wrapped one.
        if name.startswith("_") or name in ("inner", "fine", "factor"):
            raise AttributeError(name)
        return getattr(self.inner, name)
