"""The forward operator F_{h,s}: printed heights d (m, m) -> caustic irradiance (c, n, n).

F(d) = E(P(d)): photons from the point light are traced through the substrate and splatted with
photon differentials. Two implementations of the same photons:

- the fused native path (:mod:`operators.heightfield.trace_native`), used by :meth:`CausticOperator.render`
  and :meth:`CausticOperator.vjp`: one numba pass per chunk, per photon from emission to splat
  (or, for the gradient, from emission to the splat adjoint and back into the heights), with no
  per-photon arrays; with ``device: cuda`` the same per-photon code runs as CUDA kernels, one GPU
  thread per photon (:mod:`operators.heightfield.trace_cuda`);
- the torch path (:mod:`operators.heightfield.trace_reference`, :mod:`operators.splat.splat`), kept as the
  independent reference (:meth:`CausticOperator.render_reference`,
  :meth:`CausticOperator.vjp_reference`), differentiated by torch autograd.

Photons flow in chunks of ``chunk_size``; the backward pass re-traces each chunk with the same
photons (deterministic emission), so memory does not grow with the photon count. Only the ray
parameters of the surface hits (8 bytes per photon, up to ``hit_cache_mb``) are kept from a render
for a gradient of the same heights, which then skips the hit search.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numba as nb
import numpy as np
import torch
from tqdm.auto import tqdm

from operators.emission import LightEmitter
from operators.heightfield.precompile import BackgroundCompile
from operators.heightfield.trace_native import FusedTracer, HitCache
from operators.heightfield.trace_reference import trace_substrate
from operators.kernels.numba_settings import to_numpy
from operators.light_paths import Arrivals, straight_landing
from operators.photon_operator import PhotonOperator, backward_through_splat, check_setting_keys, filter_radius_px
from operators.photon_settings import DTYPES, PhotonSettings
from operators.scene import Scene
from operators.splat.splat import splat_photons
from operators.supersample import SupersampledOperator, build_supersampled
from operators.values import checked_flag, checked_number, checked_print_heights
from operators.wavefront.extended import ExtendedLightReference
from operators.wavefront.renderer import WavefrontRenderer, wavefront_vertices


@dataclass(frozen=True)
class OperatorSettings(PhotonSettings):
    """Numerical settings of the caustic operator: those of every photon operator
    (:class:`operators.photon_settings.PhotonSettings`) and

    hit_cache_mb: memory (MiB, 8 bytes per photon) for the surface hits that a render records
        and a gradient of the same heights replays instead of searching again; 0 turns it off.
    simd: take the splat and its gather (footprints that fit an 8 x 8 pixel box), the surface
        jets and the hit adjoint from the AVX2 kernels of the compiled extension
        (operators/kernels/simd_kernels.c) where it was built and the CPU has AVX2; elsewhere, or with
        False, the numba kernels do them (same results to rounding).
    device: ``cpu`` or ``cuda`` (operators/heightfield/trace_cuda.py).
    """

    hit_cache_mb: float = 256.0
    simd: bool = True
    device: str = "cpu"

    def __post_init__(self) -> None:
        super().__post_init__()
        self._set("hit_cache_mb", checked_number(self.hit_cache_mb, "operator.hit_cache_mb", least=0.0,
                                                 unit="MiB; 0 turns the hit cache off"))
        checked_flag(self.simd, "operator.simd")
        try:
            device = torch.device(self.device)
        except (RuntimeError, TypeError):
            raise ValueError(f"operator.device={self.device!r} is not a torch device; use cpu or cuda") from None
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"operator.device={self.device} but CUDA is not available here; use operator.device=cpu")


class CausticOperator(PhotonOperator):
    """Differentiable caustic of a printed height field on a flat substrate.

    Call it on heights (m, m) in scene units: returns irradiance (c, n, n) in W per scene unit^2,
    differentiable w.r.t. the heights with memory bounded by the chunk size. The plugin
    ``operator/height_field`` (built by :meth:`from_config`).
    """

    @classmethod
    def example_settings(cls) -> dict[str, Any]:
        """Settings for the plugin contract checks (framework/core/contracts/checks.py): double
        precision, rendered on a 2 x finer receiver (operators/supersample.py)."""
        return {"dtype": "float64", "supersample": 2}

    @property
    def conserves_energy(self) -> bool:
        """Without Fresnel losses the print moves light and absorbs none (framework/core/contracts/checks.py)."""
        return not self.settings.fresnel

    @classmethod
    def from_config(
        cls, scene: Scene, photons: int, seed: int, **settings: Any
    ) -> CausticOperator | SupersampledOperator:
        """The operator for ``scene`` from the config's ``operator`` group (the fields of
        :class:`OperatorSettings` but photons and seed, which the run gives, and ``supersample``:
        rendered that many times finer and block-averaged, operators/supersample.py, footprints
        given in output pixels); checks every value."""
        check_setting_keys(settings, OperatorSettings, "height_field", extra=("supersample",))
        if photons < scene.channels:
            raise ValueError(f"photons={photons} is too few; need at least one per wavelength ({scene.channels})")
        return build_supersampled(lambda fine, given: cls(fine, OperatorSettings(photons=photons, seed=seed, **given)),
                                  scene, settings, OperatorSettings)

    def variant(self, photons: int, seed: int, resolution: int) -> CausticOperator:
        """The same physics with another sampling (:meth:`PhotonOperator.resampled`)."""
        return CausticOperator(*self.resampled(photons, seed, resolution))

    def exact_variant(self, photons: int, seed: int, resolution: int) -> WavefrontRenderer | ExtendedLightReference:
        """The same physics by wavefront triangles with exact pixel coverage
        (operators/wavefront/renderer.py): no footprint, no photon noise, about ``photons``
        vertices per wavelength over the square; ``seed`` is not needed (the method is
        deterministic). An extended light: the mean of such renders from points over the source
        (operators/wavefront/extended.py)."""
        scene, _ = self.resampled(photons, seed, resolution)
        vertices = wavefront_vertices(photons, scene.channels)
        if scene.light.extended:
            return ExtendedLightReference(scene, vertices=vertices, fresnel=self.settings.fresnel)
        return WavefrontRenderer(scene, vertices=vertices, fresnel=self.settings.fresnel)

    def warm_up(self) -> BackgroundCompile:
        """Context for a run that will take gradients: where the numba kernels trace on the CPU,
        compiles their gradient kernel in a second process while this one goes on (first run after
        an install, operators/heightfield/precompile.py); ``wait()`` on what it yields before the
        first gradient."""
        return BackgroundCompile(enabled=self.device.type != "cuda" and not self.fused.compiled)

    def __init__(self, scene: Scene, settings: OperatorSettings | None = None) -> None:
        self.scene = scene
        self.settings = settings or OperatorSettings()
        self.dtype = DTYPES[self.settings.dtype]
        self.device = torch.device(self.settings.device)
        self.emitter = LightEmitter(scene, self.settings.photons, self.settings.seed,
                                    self.settings.footprint_px, self.dtype, self.device)
        self._rim_reported = False  # a top raised beyond the aim square's reach is reported once
        self.glass_index = torch.tensor(scene.indices, dtype=self.dtype, device=self.device)
        self.fused = FusedTracer(scene, self.emitter,
                                 filter_radius_px(self.settings.min_footprint_px, self.settings.pixel_integration),
                                 self.settings.max_pixel_radius, self.settings.fresnel, self.settings.simd,
                                 self.settings.kernels)
        self.hit_cache = HitCache(self.settings.hit_cache_mb)
        self.gpu = None
        if self.device.type == "cuda":
            from operators.heightfield.trace_cuda import CudaTracer  # imports numba.cuda only where it is used
            self.gpu = CudaTracer(self.fused)

    def splat_inputs(self, heights: torch.Tensor, start: int, stop: int
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Photons start .. stop-1 traced onto the receiver: pixel positions (2, N), footprint
        metrics (3, N), flux (N,) and channel (N,); differentiable w.r.t. heights."""
        batch = self.emitter.batch(start, stop)
        hits = trace_substrate(heights.to(self.dtype), self.scene, batch, self.glass_index, self.settings.fresnel)
        pos, metric = self.receiver_pixels(hits.position, hits.footprint)
        return pos, metric, hits.flux, hits.channel

    def trace_chunk(self, heights: torch.Tensor, start: int, stop: int) -> torch.Tensor:
        """Irradiance (c, n, n) from photons start .. stop-1; differentiable w.r.t. heights."""
        image = splat_photons(*self.splat_inputs(heights, start, stop), self.scene.channels,
                              self.scene.receiver.resolution)
        return image / self.pixel_area

    def _check(self, heights: torch.Tensor) -> None:
        checked_print_heights(heights, self.scene.substrate.thickness)
        self.scene.check_heights_below_light(float(heights.max()))
        if not self._rim_reported:
            self._rim_reported = self.emitter.warn_dark_rim(to_numpy(heights))

    def render_irradiance(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """Splatted irradiance (c, n, n) by the fused native path (on the GPU with ``device: cuda``),
        no autograd graph; ``progress`` shows a bar over the chunks."""
        self._check(heights)
        d = to_numpy(heights).astype(np.float64)
        if self.gpu is not None:
            return self._render_gpu(d, progress)
        out = self.fused.image_buffers(np.dtype(self.settings.dtype))
        cache = self.hit_cache
        replaying = cache.replayable(d, self)  # hits a stack's other shot recorded for these heights
        if not replaying:
            cache.start_render(self)
        for start, stop in tqdm(self.chunks(), desc="photons", unit="chunk", disable=None if progress else True):
            known = cache.hits(d, start, stop) if replaying else None
            self.fused.render(d, start, stop, out, hit_t=known if replaying else cache.slot(start, stop),
                              replay=known is not None)
        if not replaying:
            cache.finish_render(d)
        return torch.from_numpy(out.sum(axis=0) / self.pixel_area)

    def vjp_irradiance(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """The gradient (m, m) of <E(d), grad_image>, by the fused native path."""
        self._check(heights)
        d = to_numpy(heights).astype(np.float64)
        if self.gpu is not None:
            return self._vjp_gpu(d, grad_image).to(self.dtype).to(dtype=heights.dtype, device=heights.device)
        padded = self.fused.pad_gradient(to_numpy(grad_image), self.pixel_area)
        out = np.zeros((nb.get_num_threads(), *d.shape))
        for start, stop in self.chunks():
            self.fused.vjp(d, start, stop, padded, out, hit_t=self.hit_cache.hits(d, start, stop))
        return torch.from_numpy(out.sum(axis=0)).to(self.dtype).to(dtype=heights.dtype, device=heights.device)

    @property
    def has_jvp(self) -> bool:  # type: ignore[override]
        """The CPU kernels give J v (operators/heightfield/tangent_native.py); the GPU's have none yet."""
        return self.gpu is None

    def jvp_irradiance(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """E'(d) v (c, n, n), the change of the splatted irradiance along a direction v (m, m) of
        the heights, by the fused native forward pass."""
        if self.gpu is not None:
            raise NotImplementedError("the CUDA kernels have no Jacobian-vector product yet; use operator.device=cpu")
        self._check(heights)
        d = to_numpy(heights).astype(np.float64)
        v = np.ascontiguousarray(to_numpy(direction), dtype=np.float64)
        out = self.fused.image_buffers(np.dtype(self.settings.dtype))
        for start, stop in self.chunks():
            self.fused.jvp(d, v, start, stop, out)
        return torch.from_numpy(out.sum(axis=0) / self.pixel_area)

    @property
    def hit_key(self) -> tuple:
        """What decides where the photons meet the print besides the heights: the light, the
        substrate, the photon pattern, the chunks and the device. Operators with equal keys may
        share their hit cache (:meth:`share_hits`)."""
        s = self.settings
        return (self.scene.light, self.scene.substrate, self.scene.channels, s.photons, s.seed, s.chunk_size,
                s.footprint_px, s.device)

    def share_hits(self, other: CausticOperator) -> None:
        """Use ``other``'s hit cache (its :attr:`hit_key` must equal this one's): a render of heights
        that ``other`` rendered last replays its hits instead of searching (operators/stack.py)."""
        if other.hit_key != self.hit_key:
            raise ValueError("operators whose photons meet the print differently cannot share their hits")
        self.hit_cache = other.hit_cache

    def _render_gpu(self, d: np.ndarray, progress: bool) -> torch.Tensor:
        """:meth:`render` on the GPU: one image (c, n, n) that all photons add into (the chunk
        size, which bounds per-photon memory on the CPU, does not apply: the GPU stores none)."""
        image = torch.zeros(self.output_shape, dtype=self.dtype, device=self.device)
        d_gpu = torch.from_numpy(d).to(self.device)
        launches = [(start, stop) for a, b in self.emitter.segments() for start, stop in self.gpu.launches(a, b)]
        for start, stop in tqdm(launches, desc="photons", unit="launch", disable=None if progress else True):
            self.gpu.render(self.fused.constants(d, start), d_gpu, start, stop, image)
        return image / self.pixel_area

    def _vjp_gpu(self, d: np.ndarray, grad_image: torch.Tensor) -> torch.Tensor:
        """:meth:`vjp` on the GPU, all photons in one pass (no per-photon memory to bound)."""
        pad = self.gpu.gather_pad
        g = grad_image.detach().to(dtype=torch.float64, device=self.device) / self.pixel_area
        padded = torch.nn.functional.pad(g, (pad, pad, pad, pad)).contiguous()
        grad = torch.zeros(d.shape, dtype=torch.float64, device=self.device)
        d_gpu = torch.from_numpy(d).to(self.device)
        for start, stop in self.emitter.segments():
            self.gpu.vjp(self.fused.constants(d, start), d_gpu, start, stop, padded, grad)
        return grad

    def render_reference(self, heights: torch.Tensor) -> torch.Tensor:
        """Irradiance (c, n, n) by the torch path, no autograd graph (the reference for render)."""
        self._check(heights)
        image = torch.zeros(self.output_shape, dtype=self.dtype, device=self.device)
        with torch.no_grad():
            for start, stop in self.chunks():
                image += self.trace_chunk(heights.detach(), start, stop)
        return self.image_chain.apply(image)

    def vjp_reference(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """F'(d)^* grad_image by torch autograd through the torch path (the reference for vjp)."""
        self._check(heights)
        leaf = heights.detach().to(self.dtype).requires_grad_(True)
        g = self.image_chain.adjoint(grad_image.detach().to(dtype=self.dtype, device=self.device)) / self.pixel_area
        for start, stop in self.chunks():
            with torch.enable_grad():
                backward_through_splat(*self.splat_inputs(leaf, start, stop), g)
        return leaf.grad.to(heights.dtype)

    # -- the light path around the print (operators/light_paths.py) ------------------------------
    has_light_path = True

    def arrivals(self, photons: int) -> Arrivals:
        """``photons`` photons of this light where they meet the flat print's top plane z = h
        (straight from the light: the emitter aims at that plane; an extended light's from its
        centre, where a start reads the light path)."""
        point = replace(self.scene, light=self.scene.light.at((0.0, 0.0)))
        emitter = LightEmitter(point, photons, self.settings.seed, self.settings.footprint_px, torch.float64)
        batch = emitter.batch(0, emitter.total)
        light = np.asarray(self.scene.light.position, dtype=np.float64)
        direction = batch.direction.numpy().T
        points = light[:2] + direction[:, :2] * ((self.scene.substrate.thickness - light[2]) / direction[:, 2:3])
        return Arrivals(points, direction, batch.flux.numpy(), np.arange(emitter.total))

    def land_from_bottom(self, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Receiver points (N, 2) of rays leaving the bottom at ``points`` along ``directions``:
        straight lines in air."""
        return straight_landing(points, directions, self.scene.receiver.z)

    def describe(self) -> dict[str, float]:
        """Derived sampling figures, for logs."""
        return {"photons": self.photons, "photons_per_channel": self.emitter.per_channel,
                "smoothing": self.emitter.smoothing,
                "footprint_radius_units": self.emitter.footprint_radius,
                "tiling_radius_units": math.sqrt(self.emitter.cell_area / math.pi)}
