"""What the camera records of a caustic: the screen's blur and the exposure gain.

The caustic falls on a diffuse screen (the paper's lab setup: a semi-transparent paper screen
photographed from below) that spreads every point of light over a small spot, the screen's
point-spread function; the camera then records it with an unknown gain (exposure, aperture,
flash energy). :class:`ImagingOperator` wraps any operator plugin F into

    G(d) = gain * K * F(d),

K a convolution over the receiver with the point-spread function (a Gaussian integrated over
each pixel, :class:`GaussianBlur`; zero outside the receiver), and gives its adjoint
G'(d)^* g = F'(d)^* (gain * K^T g) for the gradient. The camera side is one composition of linear
maps (operators/linear/), :attr:`ImagingOperator.chain`, whose adjoint feeds the wrapped vjp;
further linear stages on the output pixels (a vignetting, examples/plugins/vignetting_stage.py)
join it through ``stages``. Where F renders on a finer receiver and
block-averages (operators/supersample.py: F = A F_fine), the blur acts on the fine receiver,
G = gain A K_fine F_fine: a blur below a pixel applied after the pixels' averaging cannot be told
from a wider one (a 0.5-pixel spot fits best as 0.59 px and leaves a 13% misfit on sharp lines),
while on a 4 x finer grid it is found to 1% (docs/method.md, "Screen and camera"). The scene it was built for,
the gain and the
blur's width can be changed (joint calibration of the setup, framework/lab/calibration.py,
which takes dG/dsigma = gain (dK/dsigma) F(d) from the same render): the wrapped operator is
rebuilt for a new scene; ``revision`` counts the changes so that cached renders of an earlier
setup are not reused.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch

from operators.linear import BlockMean, Composition, Gain, GaussianBlur, LinearMap
from operators.image_operator import WrappingOperator
from operators.scene import Scene
from operators.supersample import SupersampledOperator

__all__ = ["ImagingOperator", "PSF_KINDS"]

PSF_KINDS = ("none", "gaussian")
# An exact reference seen through a blur is rendered this many times finer, blurred there and
# block-averaged, as the model is (synthetic data of a configured screen.psf).
EXACT_BLUR_SUPERSAMPLE = 4


def _fine_stage(operator: Any) -> tuple[Any, int]:
    """(the operator that renders the finest receiver, its factor over ``operator``'s pixels): a
    supersampled operator's fine one, else the operator itself and 1."""
    if isinstance(operator, SupersampledOperator):
        return operator.fine, operator.factor
    return operator, 1


class ImagingOperator(WrappingOperator):
    """G(d) = gain * S * K * F(d): an operator plugin seen through the screen and the camera.

    Args:
        build: Builds the wrapped operator plugin F for a scene (the same settings, photons and
            seed every time).
        scene: The scene to build it for.
        psf_sigma: The screen's Gaussian spot, standard deviation in scene units (0: none).
        gain: Exposure gain (image units per W per scene unit^2).
        stages: Linear maps S on the output pixels (c, n, n) -> (c, n, n), applied after the
            pixels' averaging and before the gain, first listed last applied (as ``@`` writes
            them); none by default.
    """

    def __init__(self, build: Callable[[Scene], Any], scene: Scene, psf_sigma: float = 0.0, gain: float = 1.0,
                 stages: Sequence[LinearMap] = ()) -> None:
        self._build = build
        self.psf_sigma = psf_sigma
        self.stages = tuple(stages)
        self.scene: Scene | None = None
        self.revision = -1
        self.set_setup(scene, gain)

    def set_setup(self, scene: Scene, gain: float, psf_sigma: float | None = None) -> None:
        """Rebuild for another scene (light, receiver distance), gain and screen blur (None: the
        current one); counts a revision."""
        camera = Gain(gain)
        sigma = self.psf_sigma if psf_sigma is None else psf_sigma
        if self.scene != scene:
            self.inner = self._build(scene)
            self.scene = scene
            self.fine, factor = _fine_stage(self.inner)
            self.mean = BlockMean(factor)
            self.blur = GaussianBlur(sigma, self.fine.scene.receiver.pixel_size)
        elif sigma != self.blur.sigma:
            self.blur = GaussianBlur(sigma, self.fine.scene.receiver.pixel_size)
        self.psf_sigma = self.blur.sigma
        self.gain = camera.gain
        self.chain = self._chain(camera, self.mean, self.blur)
        self.revision += 1

    def _chain(self, camera: Gain, mean: BlockMean, blur: GaussianBlur) -> Composition:
        """gain S A K: the camera side, from the fine receiver to the output pixels."""
        return Composition([camera, *self.stages, mean, blur])

    @property
    def factor(self) -> int:
        """Fine receiver pixels per output pixel side (1: the wrapped operator is not supersampled)."""
        return self.mean.factor

    def _blur_of(self, psf_sigma: float | None) -> GaussianBlur:
        if psf_sigma is None or psf_sigma == self.blur.sigma:
            return self.blur
        return GaussianBlur(psf_sigma, self.fine.scene.receiver.pixel_size)

    def render_with(self, scene: Scene, gain: float, heights: torch.Tensor, psf_sigma: float | None = None
                    ) -> torch.Tensor:
        """gain S A K F(d) (c, n, n) for another setup (the same receiver grid; ``psf_sigma`` None:
        the current blur), leaving this operator's own setup, and its wrapped operator, as they are."""
        fine, factor = (self.fine, self.factor) if scene == self.scene else _fine_stage(self._build(scene))
        return self._chain(Gain(gain), BlockMean(factor), self._blur_of(psf_sigma)).apply(fine.render(heights))

    def render_and_sigma_derivative(self, heights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(G(d), dG/dsigma) (c, n, n) each from one render of F(d): gain S A K F(d) and
        gain S A (dK/dsigma) F(d), sigma the screen blur's in scene units (joint calibration of
        ``psf_sigma``)."""
        caustic = self.fine.render(heights)
        before_blur = Composition(self.chain.maps[:-1])
        return self.chain.apply(caustic), before_blur.apply(self.blur.derivative(caustic))

    # -- what the framework uses of an operator plugin -------------------------------------------
    @property
    def wrapped(self) -> Any:
        """The wrapped operator plugin F."""
        return self.inner

    @property
    def pixel_area(self) -> float:
        return self.inner.pixel_area

    @property
    def output_shape(self) -> tuple[int, int, int]:
        return tuple(self.inner.output_shape)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """gain S K F(d) (c, n, n) (gain S A K_fine F_fine(d) for a supersampled F)."""
        return self.chain.apply(self.fine.render(heights, progress=progress))

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* (chain^T grad_image) (m, m) (F_fine'(d)^* (K_fine^T A^T S^T gain grad_image))."""
        if tuple(grad_image.shape) != self.output_shape:
            raise ValueError(f"grad_image has shape {tuple(grad_image.shape)}, expected {self.output_shape}")
        return self.fine.vjp(heights, self.chain.adjoint(grad_image))

    def jvp(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """chain F'(d) v (c, n, n)."""
        return self.chain.apply(self.fine.jvp(heights, direction))

    def _around(self, inner: Any) -> ImagingOperator:
        """The same camera (setup fixed) around another wrapped operator."""
        return ImagingOperator(lambda scene: inner, self.scene, self.psf_sigma, self.gain, self.stages)

    def variant(self, photons: int, seed: int, resolution: int) -> ImagingOperator:
        """The same camera on another sampling of the wrapped operator (the references of
        synthetic data); its setup stays fixed."""
        return self._around(self.inner.variant(photons, seed, resolution))

    def exact_variant(self, photons: int, seed: int, resolution: int) -> ImagingOperator:
        """The same camera on the wrapped operator's exact references (synthetic data). Through an
        active blur a reference that is not supersampled already is rendered
        ``EXACT_BLUR_SUPERSAMPLE`` times finer, blurred there and block-averaged."""
        inner = self.inner.exact_variant(photons, seed, resolution)
        if self.blur.active and not isinstance(inner, SupersampledOperator):
            fine = self.inner.exact_variant(photons, seed, resolution * EXACT_BLUR_SUPERSAMPLE)
            inner = SupersampledOperator(fine, inner.scene, EXACT_BLUR_SUPERSAMPLE)
        return self._around(inner)
