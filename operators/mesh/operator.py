"""The mesh-scene forward operator: photons through optical elements, the printed substrate as a
closed solid, and any number of refractions, onto the receiver (plugin ``operator/mesh_scene``).

Each photon leaves the point light with its differentials (:mod:`operators.emission`, aimed at
the square of half width ``aperture_half_width`` on the substrate top's plane) and is traced event
by event, all photons of a chunk in lockstep, up to ``max_depth`` events. An event is the first
of: a face of an element (Embree, :mod:`operators.mesh.intersect_reference`), the printed top of the
substrate (the exact C1 height-field hit, :func:`operators.heightfield.surface.intersect_height_field`),
the substrate's side walls and bottom (planes), or the receiver plane. At an interface the photon
refracts (Snell, with its differentials and the shading normal's derivative,
:mod:`operators.optics.reference`) or, under total internal reflection, reflects; with ``fresnel`` its flux
is weighted by the transmittance and the reflected share is dropped and counted. Lost photons
(escaped, past ``max_depth``, reaching the printed top from inside the glass) are counted in
:attr:`MeshSceneOperator.losses`, and so is the flux of photons that land beside the receiver
(splatted all the same: their footprints may reach it). Photons on the receiver plane are
splatted with the native kernels (:mod:`operators.splat.splat`).

Everything after the print is torch, so the gradient w.r.t. the heights passes through the
refractions at fixed elements below the print by autograd; elements above the print do not
depend on the heights. The gradient is computed chunk by chunk with bounded memory. On a mesh the
shading normal is continuous but its derivative is constant on each face, so a photon's footprint
steps where its hit crosses an edge: the image is piecewise smooth in the heights.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from operators.emission import CELL_FOOTPRINT, LightEmitter
from operators.heightfield.surface import HeightFieldGrid, intersect_height_field
from operators.light_paths import Arrivals
from operators.materials import refractive_indices
from operators.mesh.elements import MeshProgress, OpticalElement, PrintReachesElement, check_layout, make_elements
from operators.mesh.intersect_reference import MIN_FACE_DISTANCE, MeshIntersector
from operators.mesh.rays import AIR, Rays, Surface, box_planes, reflect
from operators.mesh.settings import MeshSceneSettings
from operators.mesh.trace_native import LOSSES, NativeMeshTracer
from operators.optics.reference import (fresnel_transmittance, height_field_normal, height_field_normal_differential,
                                        refract, transfer)
from operators.photon_operator import PhotonOperator, backward_through_splat, check_setting_keys
from operators.photon_settings import DTYPES
from operators.scene import Scene
from operators.splat.splat import splat_photons
from operators.supersample import SupersampledOperator, build_supersampled, finer_scene
from operators.lengths import scene_length
from operators.values import checked_print_heights

__all__ = ["EXACT_FILTER_PX", "MeshSceneOperator"]

EXACT_SUPERSAMPLE = 4  # the exact references render 4 x 4 fine pixels per pixel ...
EXACT_FILTER_PX = 0.3  # ... with this pixel filter (fine pixels)


class MeshSceneOperator(PhotonOperator):
    """F: printed heights (m, m) -> irradiance (c, n, n) through a scene of optical elements."""

    dtype: torch.dtype

    def __init__(self, scene: Scene, elements: Sequence[OpticalElement], settings: MeshSceneSettings) -> None:
        self.scene, self.elements, self.settings = scene, list(elements), settings
        if scene.substrate.walls != "clear":
            raise ValueError(f"substrate.walls={scene.substrate.walls} is not traced by operator=mesh_scene (its "
                             "substrate has clear walls); use substrate.walls=clear, or operator=height_field")
        if scene.light.extended and self.elements:
            raise ValueError(f"light.shape={scene.light.shape} is traced by operator=mesh_scene without optical "
                             "elements only (each emission point's patch is blurred as flat glass blurs it); use "
                             "light.shape=point with elements, or operator=height_field")
        progress = MeshProgress("mesh scene", sum(len(e.mesh.faces) for e in self.elements), estimate=False)
        with progress.step("checking the elements' layout"):
            check_layout(self.elements, scene.light.position[2], scene.receiver.z)
        top = scene.substrate.thickness
        inside = self._element_within(top)
        if inside is not None:
            low, high = inside.z_range
            raise ValueError(f"element {inside.name} (z {low:.4g} .. {high:.4g}) overlaps the substrate "
                             f"(z 0 .. {top:g}); move it above or below")
        self.dtype = DTYPES[settings.dtype]
        aimed = self._aimed_scene()
        self.emitter = LightEmitter(aimed, settings.photons, settings.seed, settings.footprint_px, self.dtype)
        with progress.step("building the ray-intersection structures"):
            self.intersector = MeshIntersector(self.elements)
        self._lowest_element = min((e.z_range[0] for e in self.elements), default=math.inf)
        self.substrate_index = torch.tensor(scene.indices, dtype=self.dtype)
        self.element_index = torch.tensor([refractive_indices(e.material, scene.wavelengths) for e in self.elements]
                                          or np.zeros((0, scene.channels)), dtype=self.dtype)
        # Refractive index (K + 1, c) of each element and, last, the substrate, per channel.
        self.index_table = torch.cat([self.element_index, self.substrate_index.unsqueeze(0)])
        self.losses: dict[str, float] = {}
        self.native: NativeMeshTracer | None = None
        if settings.native:
            with progress.step("preparing the native tracer"):
                self.native = NativeMeshTracer(self)

    @classmethod
    def example_settings(cls) -> dict[str, Any]:
        """Settings for the plugin contract checks (framework/core/contracts/checks.py): one lens above the
        print, double precision, rendered on a 2 x finer receiver (operators/supersample.py)."""
        lens = {"radius": 1.0, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0}
        element = {"name": "lens", "shape": "lens", "position": [0, 0, 1.15], "params": lens}
        return {"dtype": "float64", "supersample": 2, "elements": [element]}

    @property
    def conserves_energy(self) -> bool:
        """Without Fresnel losses the print moves light and absorbs none (framework/core/contracts/checks.py)."""
        return not self.settings.fresnel

    @classmethod
    def from_config(cls, scene: Scene, photons: int, seed: int, elements: Any = (), **settings: Any
                    ) -> MeshSceneOperator | SupersampledOperator:
        """The plugin ``operator/mesh_scene``: ``elements`` is a list of element configs
        (:func:`operators.mesh.elements.make_elements`), ``supersample`` as for the height-field
        operator (operators/supersample.py), the rest are :class:`MeshSceneSettings`; lengths may
        be given with a unit (``scene.mm_per_unit``)."""
        if settings.get("aperture_half_width") is not None:
            settings["aperture_half_width"] = scene_length(settings["aperture_half_width"], scene.mm_per_unit,
                                                           "operator.aperture_half_width")
        check_setting_keys(settings, MeshSceneSettings, "mesh_scene", extra=("elements", "supersample"))
        built = make_elements(elements, mm_per_unit=scene.mm_per_unit)
        def build(fine: Scene, given: dict[str, Any]) -> MeshSceneOperator:
            return cls(fine, built, MeshSceneSettings(photons=photons, seed=seed, **given))

        return build_supersampled(build, scene, settings, MeshSceneSettings)

    def variant(self, photons: int, seed: int, resolution: int) -> MeshSceneOperator:
        """The same scene with another sampling (:meth:`PhotonOperator.resampled`)."""
        scene, settings = self.resampled(photons, seed, resolution)
        return MeshSceneOperator(scene, self.elements, settings)

    def exact_variant(self, photons: int, seed: int, resolution: int) -> SupersampledOperator:
        """The references of synthetic data: ``photons`` photons with ``seed``'s pattern at their
        own cells' footprints, rendered :data:`EXACT_SUPERSAMPLE` times finer than the n =
        ``resolution`` receiver with a pixel filter of :data:`EXACT_FILTER_PX` fine pixels and
        block-averaged (operators/supersample.py): no footprint of the model's, pixels that
        integrate exactly."""
        scene, settings = self.resampled(photons, seed, resolution)
        settings = dataclasses.replace(settings, footprint_px=CELL_FOOTPRINT, min_footprint_px=EXACT_FILTER_PX,
                                       max_pixel_radius=settings.max_pixel_radius * EXACT_SUPERSAMPLE)
        fine = MeshSceneOperator(finer_scene(scene, EXACT_SUPERSAMPLE), self.elements, settings)
        return SupersampledOperator(fine, scene, EXACT_SUPERSAMPLE)

    def _element_within(self, top: float) -> OpticalElement | None:
        """The first element that reaches into the substrate's box, z 0 .. top over its square."""
        half = self.scene.substrate.half_width
        for element in self.elements:
            low, high = element.z_range
            corner_low, corner_high = element.mesh.bounds[0, :2], element.mesh.bounds[1, :2]
            if low < top and high > 0.0 and np.all(corner_low < half) and np.all(corner_high > -half):
                return element
        return None

    def _check(self, heights: torch.Tensor) -> None:
        checked_print_heights(heights, self.scene.substrate.thickness)
        top = self.scene.substrate.thickness + float(heights.max())
        inside = self._element_within(top)
        if inside is not None:
            raise PrintReachesElement(
                f"the print reaches z={top:.4g}, into element {inside.name} (from z={inside.z_range[0]:.4g})"
            )

    def render_irradiance(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """Splatted irradiance (c, n, n), W per scene unit^2, without a graph; :attr:`losses` holds
        the flux (W) each kind of loss took."""
        self._check(heights)
        if self.native is not None:
            image, self.losses = self.native.render(heights.detach().double().cpu().numpy())
            return image.div_(self.pixel_area)  # a new image: divided in place
        image = torch.zeros(self.output_shape, dtype=self.dtype)
        self.losses = dict.fromkeys(LOSSES, 0.0)
        with torch.no_grad():
            for start, stop in tqdm(self.chunks(), desc="photons", unit="chunk", disable=None if progress else True):
                pos, metric, flux, channel, losses = self.trace(heights.detach().to(self.dtype), start, stop)
                image += splat_photons(pos, metric, flux, channel, self.scene.channels, self.scene.receiver.resolution)
                for key, value in losses.items():
                    self.losses[key] += value
        return image / self.pixel_area

    def vjp_irradiance(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """The gradient (m, m) of <E(d), grad_image>, by autograd through each chunk's photons in turn."""
        self._check(heights)
        g = grad_image.detach().to(self.dtype) / self.pixel_area
        if self.native is not None:
            grad = self.native.vjp(heights.detach().double().cpu().numpy(), g.cpu())
            return torch.from_numpy(grad).to(dtype=heights.dtype, device=heights.device)
        leaf = heights.detach().to(self.dtype).requires_grad_(True)
        for start, stop in self.chunks():
            with torch.enable_grad():
                backward_through_splat(*self.trace(leaf, start, stop)[:4], g)
        grad = leaf.grad if leaf.grad is not None else torch.zeros_like(leaf)
        return grad.to(heights.dtype)

    # -- the photon paths ---------------------------------------------------------------------
    def trace(self, heights: torch.Tensor, start: int, stop: int
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, float]]:
        """Photons start .. stop-1 through the scene: receiver pixel positions (2, N), footprint
        metrics (3, N), flux (N,) (zero for lost photons), channel (N,), and the lost flux by kind.
        Each event is computed for the photons still under way only."""
        scene, dtype = self.scene, self.dtype
        batch = self.emitter.batch(start, stop)
        n = batch.direction.shape[1]
        ray = Rays(position=batch.origin.to(dtype).unsqueeze(-1).expand(3, n).clone(),
                    d_position=torch.zeros(2, 3, n, dtype=dtype), direction=batch.direction,
                    d_direction=batch.direction_diff, flux=batch.flux, medium=torch.full((n,), AIR, dtype=torch.int64))
        channel = batch.channel
        alive = torch.ones(n, dtype=torch.bool)
        landed = torch.zeros(n, dtype=torch.bool)
        losses = dict.fromkeys(LOSSES, 0.0)
        surface = Surface(HeightFieldGrid(scene.substrate.thickness, scene.substrate.half_width, heights.shape[0]),
                           heights, scene.substrate.thickness + float(heights.detach().max()) + 1e-9)
        for _ in range(self.settings.max_depth):
            index = alive.nonzero().squeeze(1)
            if index.numel() == 0:
                break
            moved, arrived, lost = self._step(ray.take(index), channel[index], surface, losses)
            ray = ray.put(index, moved)
            landed[index] |= arrived
            alive[index] = ~(arrived | lost)
        losses["max_depth"] += float(ray.flux[alive].detach().sum())
        position, flux = ray.position, ray.flux
        # Photons beside the receiver are splatted too (their footprints may reach it: the image
        # stays continuous in the heights); their flux is counted as having missed it.
        outside = landed & (position[:2].abs() > scene.receiver.half_width).any(0)
        losses["missed_receiver"] += float(flux[outside].detach().sum())
        flux = torch.where(landed, flux, torch.zeros_like(flux))
        footprint = torch.where(landed, ray.d_position[:, :2], torch.zeros_like(ray.d_position[:, :2]))
        pos, metric = self.receiver_pixels(position[:2], footprint)
        return pos, metric, flux, channel, losses

    def _step(self, ray: Rays, channel: torch.Tensor, surface: Surface, losses: dict[str, float]
              ) -> tuple[Rays, torch.Tensor, torch.Tensor]:
        """One event for photons under way: the moved rays, which reached the receiver, which were lost."""
        scene, dtype = self.scene, self.dtype
        position, d_position, direction, d_direction = ray.position, ray.d_position, ray.direction, ray.d_direction
        flux, medium = ray.flux, ray.medium
        n = direction.shape[1]
        substrate = len(self.elements)  # the substrate's medium id; elements are 0 .. K-1
        half, h = scene.substrate.half_width, scene.substrate.thickness
        in_air, in_sub = medium == AIR, medium == substrate
        in_element = (medium >= 0) & (medium < substrate)
        # Rays in air below every element and going down can meet only the receiver.
        past = in_air & (direction[2] < 0) & (position[2] < self._lowest_element)
        hits = self.intersector.intersect(position, direction, (in_air & ~past) | in_element)
        mesh_ok = (in_air | in_element) & torch.isfinite(hits.t) & (hits.t > MIN_FACE_DISTANCE)
        # The printed top from above: rays in air, going down, above the print, through the square.
        down = torch.where(direction[2] < 0, direction[2], -torch.ones_like(direction[2]))
        cross = position[:2] + ((h - position[2]) / down) * direction[:2]
        top_ok = in_air & (direction[2] < 0) & (position[2] > surface.top_max) & (cross.abs() <= half).all(0)
        t_top = torch.full((n,), math.inf, dtype=dtype)
        jet = torch.zeros(5, n, dtype=dtype)
        if bool(top_ok.any()):
            index = top_ok.nonzero().squeeze(1)
            t_sub, jet_sub = intersect_height_field(surface.heights, surface.grid, position[:, index].detach(),
                                                    direction[:, index].detach())
            t_top = t_top.index_copy(0, index, t_sub.to(dtype))
            jet = jet.index_copy(1, index, jet_sub.to(dtype))
        # The substrate's walls and bottom (planes; outward normals), from either side.
        t_box, box_normal = box_planes(position, direction, half, h, in_air, in_sub)
        # The receiver plane, reached in air going down.
        t_rec = torch.where(in_air & (direction[2] < 0), (scene.receiver.z - position[2]) / down,
                            torch.full_like(direction[2], math.inf))
        # The printed top from inside the glass: a path this operator does not follow.
        t_inside = torch.where(in_sub & (direction[2] > 0), (h - position[2]) / direction[2].clamp(min=1e-12),
                               torch.full_like(direction[2], math.inf))
        candidates = torch.stack([torch.where(mesh_ok, hits.t, torch.full_like(hits.t, math.inf)).detach(),
                                  t_top.detach(), t_box.detach(), t_rec.detach(), t_inside.detach()])
        nearest, kind = candidates.min(0)
        escaped = ~torch.isfinite(nearest)
        inside_top = torch.isfinite(nearest) & (kind == 4)
        losses["escaped"] += float(flux[escaped].detach().sum())
        losses["inside_top"] += float(flux[inside_top].detach().sum())
        going = ~escaped & ~inside_top
        is_mesh, is_top, is_box, is_rec = (going & (kind == k) for k in range(4))
        t = torch.where(is_mesh, hits.t, torch.where(is_top, t_top, torch.where(is_box, t_box, t_rec)))
        t = torch.where(going, t, torch.zeros_like(t))
        up = torch.tensor([0.0, 0.0, 1.0], dtype=dtype).unsqueeze(-1).expand(3, n)
        top_normal = height_field_normal(jet)
        plane = torch.where(is_mesh, hits.plane_normal,
                            torch.where(is_top, top_normal, torch.where(is_box, box_normal, up)))
        position, d_position = transfer(position, d_position, direction, d_direction, t, torch.where(going, plane, up))
        # Interfaces (photons not on the receiver): the outward normal, its differential, the
        # indices on both sides.
        refracting = going & ~is_rec
        d_mesh = torch.einsum("ijn,kjn->kin", hits.normal_gradient, d_position)
        d_top = height_field_normal_differential(jet, top_normal, d_position)
        outward = torch.where(is_mesh, hits.normal, torch.where(is_top, top_normal, box_normal))
        d_outward = torch.where(is_mesh, d_mesh, torch.where(is_top, d_top, torch.zeros_like(d_mesh)))
        entering = (direction * plane).sum(0) < 0
        solid = torch.where(is_mesh, hits.element, torch.full_like(medium, substrate))
        n_solid = self._index(solid, channel)
        facing = torch.where(entering, outward, -outward)
        d_facing = torch.where(entering, d_outward, -d_outward)
        eta = torch.where(entering, 1.0 / n_solid, n_solid)
        refracted, d_refracted, cos_i, cos_t, tir = refract(direction, d_direction, facing, d_facing, eta)
        reflected, d_reflected = reflect(direction, d_direction, facing, d_facing)
        through = refracting & ~tir
        direction_out = torch.where(through, refracted, torch.where(refracting, reflected, direction))
        d_direction_out = torch.where(through, d_refracted, torch.where(refracting, d_reflected, d_direction))
        if self.settings.fresnel:
            kept = torch.where(through, fresnel_transmittance(cos_i, cos_t, eta), torch.ones_like(flux))
            losses["fresnel_reflected"] += float((flux * (1 - kept)).detach().sum())
            flux = flux * kept
        medium = torch.where(through, torch.where(entering, solid, torch.full_like(medium, AIR)), medium)
        moved = Rays(position, d_position, direction_out, d_direction_out, flux, medium)
        return moved, is_rec, escaped | inside_top

    # -- the light path around the print (operators/light_paths.py) ------------------------------
    has_light_path = True

    def arrivals(self, photons: int) -> Arrivals:
        """``photons`` photons of this light, traced through the elements above the print, where
        they enter the flat print's top (z = h, inside the substrate's square): position, the
        direction they arrive along, flux. Photons that miss the top are left out (an extended
        light's from its centre, where a start reads the light path)."""
        aimed = self._aimed_scene()
        point = dataclasses.replace(aimed, light=aimed.light.at((0.0, 0.0)))
        emitter = LightEmitter(point, photons, self.settings.seed, self.settings.footprint_px, torch.float64)
        batch = emitter.batch(0, emitter.total)
        n = batch.direction.shape[1]
        ray = Rays(position=batch.origin.double().unsqueeze(-1).expand(3, n).clone(),
                    d_position=torch.zeros(2, 3, n, dtype=torch.float64), direction=batch.direction.double(),
                    d_direction=torch.zeros(2, 3, n, dtype=torch.float64), flux=batch.flux.double(),
                    medium=torch.full((n,), AIR, dtype=torch.int64))
        half = self.scene.substrate.half_width
        with torch.no_grad():
            no_jet = torch.zeros(2, 2, dtype=torch.float64)
            before, landed = self._follow(ray, batch.channel, no_jet, stop_on_entry=True)
        top = landed & (before.position[2] - self.scene.substrate.thickness).abs().lt(1e-9) \
            & (before.position[:2].abs() <= half).all(0)
        return Arrivals(before.position[:2, top].T.numpy(), before.direction[:, top].T.numpy(),
                        before.flux[top].numpy(), top.nonzero().squeeze(1).numpy())

    def land_from_bottom(self, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Receiver points (N, 2) of rays leaving the bottom at ``points`` along ``directions``,
        traced through the elements below the print (first wavelength); NaN where lost."""
        n = len(points)
        start = np.concatenate([points, np.full((n, 1), -1e-9)], axis=1)
        ray = Rays(position=torch.from_numpy(start.T.copy()), d_position=torch.zeros(2, 3, n, dtype=torch.float64),
                    direction=torch.from_numpy(np.ascontiguousarray(directions.T, dtype=np.float64)),
                    d_direction=torch.zeros(2, 3, n, dtype=torch.float64), flux=torch.ones(n, dtype=torch.float64),
                    medium=torch.full((n,), AIR, dtype=torch.int64))
        with torch.no_grad():
            end, landed = self._follow(ray, torch.zeros(n, dtype=torch.int64), torch.zeros(2, 2, dtype=torch.float64))
        out = end.position[:2].T.numpy().copy()
        out[~landed.numpy()] = np.nan
        return out

    def _follow(self, ray: Rays, channel: torch.Tensor, heights: torch.Tensor, stop_on_entry: bool = False
                ) -> tuple[Rays, torch.Tensor]:
        """Step rays (float64) until they reach the receiver or are lost, or with
        ``stop_on_entry`` until they enter the substrate: the rays as they were then (the state
        before that event, i.e. on the surface with the incident direction) and which got there."""
        scene = self.scene
        surface = Surface(HeightFieldGrid(scene.substrate.thickness, scene.substrate.half_width, heights.shape[0]),
                           heights, scene.substrate.thickness + float(heights.max()) + 1e-9)
        # The tracer's own dtype is the operator's; these paths are traced in float64.
        table, dtype = self.index_table, self.dtype
        self.index_table, self.dtype = self.index_table.double(), torch.float64
        n = ray.flux.shape[0]
        alive = torch.ones(n, dtype=torch.bool)
        reached = torch.zeros(n, dtype=torch.bool)
        kept = ray
        try:
            for _ in range(self.settings.max_depth):
                index = alive.nonzero().squeeze(1)
                if index.numel() == 0:
                    break
                part = ray.take(index)
                moved, arrived, lost = self._step(part, channel[index], surface, {k: 0.0 for k in LOSSES})
                if stop_on_entry:
                    entered = (moved.medium == len(self.elements)) & (part.medium == AIR)
                    at_top = entered.nonzero().squeeze(1)
                    surface_hit = Rays(moved.position, moved.d_position, part.direction, part.d_direction,
                                        part.flux, part.medium)
                    kept = kept.put(index[at_top], surface_hit.take(at_top))
                    reached[index[at_top]] = True
                    arrived = arrived | entered
                else:
                    reached[index] |= arrived
                ray = ray.put(index, moved)
                alive[index] = ~(arrived | lost)
        finally:
            self.index_table, self.dtype = table, dtype
        return (kept if stop_on_entry else ray), reached

    def _aimed_scene(self) -> Scene:
        """The scene with the substrate's square widened to the emitter's aperture."""
        aperture = self.settings.aperture_half_width or self.scene.substrate.half_width
        return dataclasses.replace(self.scene, substrate=dataclasses.replace(self.scene.substrate, half_width=aperture))

    def _index(self, solid: torch.Tensor, channel: torch.Tensor) -> torch.Tensor:
        """Refractive index (N,) of the solid (element k, or the substrate for k = K) per photon."""
        return self.index_table[solid.clamp(min=0), channel]
