"""What the camera records of a caustic: the screen's blur and the exposure gain.

The caustic falls on a diffuse screen (the paper's lab setup: a semi-transparent paper screen
photographed from below) that spreads every point of light over a small spot, the screen's
point-spread function; the camera then records it with an unknown gain (exposure, aperture,
flash energy). :class:`ImagingOperator` wraps any operator plugin F into

    G(d) = gain * K * F(d),

K a convolution over the receiver with the point-spread function (zero outside the receiver),
and gives its adjoint G'(d)^* g = F'(d)^* (gain * K^T g) for the gradient. The scene it was
built for can be changed (joint calibration of the setup, framework/pipeline/calibration.py): the
wrapped operator is then rebuilt for the new scene; ``revision`` counts the changes so that
cached renders of an earlier setup are not reused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import torch
import torch.nn.functional as F

from operators.photon_operator import ImageOperator
from operators.scene import Scene

__all__ = ["ScreenBlur", "ImagingOperator", "PSF_KINDS"]

PSF_KINDS = ("none", "gaussian")


class ScreenBlur:
    """Convolution of receiver images (c, n, n) with the screen's point-spread function.

    Args:
        sigma: Standard deviation of the Gaussian spot, scene units (0: no blur).
        pixel_size: Receiver pixel size, scene units.

    The kernel is sampled at the pixel centres out to 4 sigma and normalised to sum 1, so the
    blur keeps the light that stays on the receiver; light spread past the edge is lost, as on
    a screen of that size.
    """

    def __init__(self, sigma: float, pixel_size: float) -> None:
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"screen.sigma={sigma!r} must be a length >= 0 (scene units or e.g. '0.1 mm')")
        self.sigma = float(sigma)
        self.sigma_px = self.sigma / pixel_size
        radius = int(math.ceil(4.0 * self.sigma_px))
        offsets = torch.arange(-radius, radius + 1, dtype=torch.float64)
        profile = torch.exp(-0.5 * (offsets / max(self.sigma_px, 1e-12)) ** 2)
        self.profile = profile / profile.sum()  # separable: the 2-D kernel is the outer product

    @property
    def active(self) -> bool:
        """Whether the blur changes an image (a kernel wider than one pixel)."""
        return self.profile.numel() > 1

    def _convolve(self, image: torch.Tensor) -> torch.Tensor:
        if not self.active:
            return image
        k = self.profile.to(image)
        r = (k.numel() - 1) // 2
        x = image.unsqueeze(1)  # (c, 1, n, n)
        x = F.conv2d(x, k.view(1, 1, -1, 1), padding=(r, 0))
        x = F.conv2d(x, k.view(1, 1, 1, -1), padding=(0, r))
        return x.squeeze(1)

    def apply(self, image: torch.Tensor) -> torch.Tensor:
        """K image: the blurred image (c, n, n)."""
        return self._convolve(image)

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        """K^T image; the kernel is symmetric and the padding zero, so K^T = K."""
        return self._convolve(image)


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

    def set_setup(self, scene: Scene, gain: float) -> None:
        """Rebuild for another scene (light, receiver distance) and gain; counts a revision."""
        if not (math.isfinite(gain) and gain > 0.0):
            raise ValueError(f"gain={gain!r} must be a positive finite number")
        if self.scene != scene:
            self.inner = self._build(scene)
            self.scene = scene
            self.blur = ScreenBlur(self.psf_sigma, self.inner.scene.receiver.pixel_size)
        self.gain = float(gain)
        self.revision += 1

    def render_with(self, scene: Scene, gain: float, heights: torch.Tensor) -> torch.Tensor:
        """gain * K * F(d) (c, n, n) for another setup (the same receiver grid), leaving this
        operator's own setup, and its wrapped operator, as they are."""
        inner = self.inner if scene == self.scene else self._build(scene)
        return gain * self.blur.apply(inner.render(heights))

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
        """gain * K * F(d) (c, n, n)."""
        return self.gain * self.blur.apply(self.inner.render(heights, progress=progress))

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* (gain * K^T grad_image) (m, m)."""
        return self.inner.vjp(heights, self.gain * self.blur.adjoint(grad_image))

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

    def __getattr__(self, name: str) -> Any:
        # Anything else an operator plugin offers (device, settings, ...) comes from the
        # wrapped one.
        if name.startswith("_") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
