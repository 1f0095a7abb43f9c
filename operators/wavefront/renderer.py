"""Exact irradiance of the caustic by wavefront triangles: an independent, blur-free forward renderer.

The light's wavefront is sampled by a K x K grid of aim points covering the substrate's top square
[-W, W]^2 on the plane z = h, aimed at as the photon emitter aims (docs/method.md, "Photon
emission"; :meth:`operators.emission.LightEmitter.photons_toward`); each grid cell is split
into two triangles. Every vertex ray is traced in float64 through the printed Catmull-Rom top, the
substrate and onto the receiver plane (docs/method.md, "Refraction through the glass") by the
fused native kernels' per-photon optics (:mod:`operators.heightfield.kernels_native`: the exact
hit on the interpolant, Snell at the top and at the face the ray leaves through, the bottom or a
side wall, total reflections at the walls, rays lost by total internal reflection at the bottom)
or, with ``tracer="torch"``, by
:func:`operators.heightfield.trace_reference.trace_substrate`: the same receiver points to ~1e-13
pixels, the native tracer about 10 times faster.

Aim triangle A of channel k carries the flux P / (4 pi c) Omega(A) (c channels: the light's
power split evenly, as the emitter splits it), Omega(A) its solid angle seen from the light in
closed form (Van Oosterom and Strackee 1983), so the emitted flux is exact; the mean of the three
vertex values of P / (4 pi c) cos(theta) / r^2 times |A| would err by O(Delta^2) relative (Delta
the grid step). With Fresnel weights the flux is multiplied by the mean of the vertices'
transmittances. The flux spreads evenly over the image triangle on the receiver, rasterised with
exact pixel coverage (:mod:`operators.wavefront.coverage`); the image is flux per pixel over the
pixel area, irradiance in W per scene unit^2 (c, n, n), as :meth:`CausticOperator.render` gives.

Paths: every vertex ray carries the code of the path it took (left through the bottom or a side
wall, mirrored by which walls' total reflections, or lost: an absorbing wall, total internal
reflection at the bottom; :mod:`operators.heightfield.side_walls`). Within a triangle whose three
vertices took one path the map is smooth; a triangle whose three vertices are lost is dropped;
one whose vertices took different paths is cut into 4 by its edge midpoints, the new vertices
traced, ``subdivisions`` times over, and only the sub-triangles whose vertices still took
different paths are dropped. What this drops is a band of width ~ Delta / 2^L along each edge
between paths: the edge of the lit region, and the lines on the top where the light starts to
meet a side wall (measured in tests/operators/test_wavefront.py and tests/operators/test_side_walls.py).

Error: the map from aim points to receiver points is replaced by its piecewise-linear
interpolant and the irradiance by a constant per image triangle; for a smooth height field the
pixel values err by O(Delta^2) (second-order terms of the map; the triangles tile the image
without gaps or overlaps wherever the map is one-to-one, so the flux is only redistributed near
pixel edges). At folds (caustics) the map folds over: flipped triangles count with their |area|
and overlapping sheets add, which is the exact irradiance in the limit Delta -> 0; the inverse
square-root singularity along a fold is integrable, so pixel values converge, more slowly there.
No smoothing footprint: unlike the splat renderer (docs/method.md, "Photon-differential
splatting") the result does not blur, which makes it the reference for synthetic data.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba as nb
import numpy as np
import torch

from operators.emission import LightEmitter
from operators.heightfield import trace_compiled
from operators.heightfield.kernels_native import hit_jet, optics_state
from operators.heightfield.side_walls import LOST
from operators.heightfield.trace_native import FusedTracer
from operators.heightfield.trace_reference import trace_substrate
from operators.kernels.numba_settings import jit_call, jit_parallel
from operators.optics.native import ZERO, fresnel
from operators.scene import Scene
from operators.values import checked_flag, checked_print_heights, checked_whole
from operators.wavefront.coverage import rasterize_grid, rasterize_triangles
from operators.wavefront.flux import grid_flux, grid_solid_angles, triangle_solid_angle

# Triangle vertices per receiver pixel side that the default grid gives over the printed square.
VERTICES_PER_PIXEL = 8
MAX_SUBDIVISIONS = 8
TRACERS = ("native", "torch")
# Children of a triangle (v0, v1, v2) cut at its edge midpoints m01, m12, m20, as indices into
# (v0, v1, v2, m01, m12, m20).
CHILDREN = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def wavefront_vertices(photons: int, channels: int) -> int:
    """Grid size K for a photon budget: (K - 1)^2 = photons / channels cells per channel, each
    of the emitter's cell area (2 W)^2 / photons-per-channel; about ``photons`` vertices in all."""
    photons = checked_whole(photons, "photons", channels,
                            must=f"must be an integer >= the number of wavelengths ({channels})")
    return int(round(math.sqrt(photons / channels))) + 1


@jit_call
def _trace_ray(d, sc, eta, ax, ay) -> tuple[float, float, float, float]:
    """One ray aimed at (ax, ay) on z = sc.base, by the fused kernels' per-photon optics
    (:func:`operators.heightfield.kernels_native.hit_jet`, :func:`~operators.heightfield.kernels_native.optics_state`
    with zero differentials): receiver position (x, y) in pixel corner units, transmittance
    (1, the Fresnel product with sc.fresnel, 0 if lost) and the path's code
    (:mod:`operators.heightfield.side_walls`, 0 if lost). A call, not inlined into the parallel
    loop (numba's parfor analysis trips over the inlined tuples)."""
    dx = ax - sc.light_x
    dy = ay - sc.light_y
    dz = sc.base - sc.light_z
    inv_r = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    w = (dx * inv_r, dy * inv_r, dz * inv_r)
    t, jet = hit_jet(d, sc, w)
    top, below, _, _ = optics_state(sc, w, ZERO, ZERO, t, jet, eta)
    p3 = below[11]
    x = (p3[0] + sc.receiver_half) * sc.to_px
    y = (p3[1] + sc.receiver_half) * sc.to_px
    transmittance = 1.0
    if sc.fresnel:
        transmittance = fresnel(top[9], top[10], 1.0 / eta) * fresnel(below[8], below[9], eta)
    good = not below[0] and math.isfinite(x) and math.isfinite(y) and transmittance > 0.0
    return x, y, transmittance if good else 0.0, float(below[17]) if good else 0.0


@jit_parallel
def _trace_native(d, sc, eta, aim, pos, ratio, path) -> None:
    """Rays aimed at ``aim`` (N, 2) through heights ``d`` (m, m) with glass index ``eta``
    (:func:`_trace_ray`): positions (N, 2) into ``pos``, transmittances (N,) into ``ratio``,
    path codes (N,) into ``path``."""
    for k in nb.prange(aim.shape[0]):
        pos[k, 0], pos[k, 1], ratio[k], path[k] = _trace_ray(d, sc, eta, aim[k, 0], aim[k, 1])


@dataclass
class FluxBudget:
    """Where the light of the last render went (W, all channels summed).

    emitted: P / (4 pi) times the solid angle of the top square (exact);
    dropped: emitted flux of the dropped (sub-)triangles (before Fresnel weights);
    rasterised: flux of the kept triangles (with Fresnel weights if on);
    received: flux that landed on the receiver's image (rasterised minus what fell off it).
    """

    emitted: float
    dropped: float
    rasterised: float
    received: float


class WavefrontRenderer:
    """Blur-free caustic irradiance of a height field by wavefront triangles (module docstring).

    ``vertices`` K: aim points per side of the grid (default: :meth:`default_vertices`, at
    least 8 triangle vertices per receiver pixel side over the printed square); ``fresnel``:
    Fresnel weights as in :class:`operators.heightfield.operator.OperatorSettings`;
    ``chunk_size``: rays traced at once (sets the peak memory, ~1 kB per ray); ``subdivisions``:
    levels of 4-way cuts of triangles at the edge of the lit region; ``tracer``: ``"native"``
    traces each ray with the fused numba kernels' optics (:func:`_trace_native`), ``"torch"``
    with :func:`operators.heightfield.trace_reference.trace_substrate` (the same rays to
    rounding, ~10x slower).
    """

    dtype = torch.float64
    deterministic = True  # no sampling noise: one render is the clean image (framework/data/sources.py)

    def __init__(self, scene: Scene, vertices: int | None = None, fresnel: bool = False,
                 chunk_size: int = 1 << 18, subdivisions: int = 3, tracer: str = "native") -> None:
        k = checked_whole(self.default_vertices(scene) if vertices is None else vertices, "vertices", 2,
                          must="must be an integer >= 2 (aim points per side)", example="2049")
        chunk_size = checked_whole(chunk_size, "chunk_size", 1, must="must be a positive integer", example="262144")
        subdivisions = checked_whole(subdivisions, "subdivisions", 0, MAX_SUBDIVISIONS,
                                     must=f"must be an integer in [0, {MAX_SUBDIVISIONS}]")
        if tracer not in TRACERS:
            raise ValueError(f"tracer={tracer!r} must be one of {', '.join(TRACERS)}")
        checked_flag(fresnel, "fresnel")
        if scene.light.extended:
            raise ValueError(f"light.shape={scene.light.shape}: the wavefront renderer traces a point light; render an "
                             "extended one by operators.wavefront.extended.ExtendedLightReference")
        self.scene = scene
        self.vertices = int(k)
        self.fresnel = fresnel
        self.chunk_size = int(chunk_size)
        self.subdivisions = int(subdivisions)
        self.tracer = tracer
        self.emitter = LightEmitter(scene, scene.channels, 0, 1.0, torch.float64)
        self.fused = FusedTracer(scene, self.emitter, 1.0, 20.0, fresnel, False)  # footprint settings unused
        self.glass_index = torch.tensor(scene.indices, dtype=torch.float64)
        self.last_budget: FluxBudget | None = None
        self._omega: np.ndarray | None = None
        # The aim grid covers the emitter's aim square (operators/emission.py) with ``vertices`` points
        # per side over the substrate's square and whole spacings beyond it, so that a grid line runs
        # along the square's edge, where rays part into those that enter the top and those beside it.
        half = float(scene.substrate.half_width)
        spacing = 2.0 * half / (self.vertices - 1)
        beyond = math.ceil((self.emitter.aim_half - half) / spacing - 1e-9)
        self.vertices += 2 * beyond
        self.aim_half = half + beyond * spacing

    @staticmethod
    def default_vertices(scene: Scene) -> int:
        """Smallest K with VERTICES_PER_PIXEL triangle vertices per receiver pixel side across the
        straight-line image of the top square (magnified by (l_z - s) / (l_z - h))."""
        lz, h, s = scene.light.position[2], scene.substrate.thickness, scene.receiver.z
        image_width = 2.0 * scene.substrate.half_width * (lz - s) / (lz - h)
        return int(math.ceil(VERTICES_PER_PIXEL * image_width / scene.receiver.pixel_size - 1e-9)) + 1

    @property
    def output_shape(self) -> tuple[int, int, int]:
        n = self.scene.receiver.resolution
        return self.scene.channels, n, n

    @property
    def pixel_area(self) -> float:
        """Area of one receiver pixel (scene units^2)."""
        return self.scene.receiver.pixel_size ** 2

    def _channel_scale(self) -> float:
        """P / (4 pi c): flux per steradian per channel (W / sr)."""
        return self.scene.light.power / (4.0 * math.pi * self.scene.channels)

    def grid_solid_angles(self) -> np.ndarray:
        """Solid angles (2, K-1, K-1) (sr) of the grid's aim triangles over the aim square
        [-A, A]^2 (A = :attr:`aim_half`; computed once)."""
        if self._omega is None:
            light = self.scene.light.position
            self._omega = grid_solid_angles(self.vertices, self.aim_half, float(self.scene.substrate.thickness),
                                            (float(light[0]), float(light[1]), float(light[2])))
        return self._omega

    def aim_coordinates(self, index: np.ndarray) -> np.ndarray:
        """Aim coordinates x_j = -A + 2 A j / (K - 1) (scene units) of grid indices ``index``, A =
        :attr:`aim_half`."""
        half = self.aim_half
        return -half + (2.0 * half) * index / (self.vertices - 1)

    def trace(self, heights: torch.Tensor, aim: np.ndarray, channel: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays of ``channel`` aimed at ``aim`` (N, 2) (x, y on z = h) traced onto the receiver:
        positions (N, 2) in pixel corner units (pixel p spans [p, p + 1]), transmittance
        (N,) = flux out / flux in (1 without Fresnel, 0 for a lost ray) and path codes (N,)
        (which face the ray left through, which walls mirrored it:
        :mod:`operators.heightfield.side_walls`; 0 for a lost ray)."""
        count = aim.shape[0]
        pos = np.empty((count, 2))
        ratio = np.empty(count)
        path = np.empty(count)
        if self.tracer == "native":
            d = np.ascontiguousarray(heights.numpy())
            sc = self.fused.constants(d)
            eta = float(self.scene.indices[channel])
            for start in range(0, count, self.chunk_size):
                stop = min(count, start + self.chunk_size)
                part = np.ascontiguousarray(aim[start:stop], dtype=np.float64)
                if trace_compiled.AVAILABLE:
                    trace_compiled.trace_aimed(d, sc, eta, part, pos[start:stop], ratio[start:stop], path[start:stop])
                else:
                    _trace_native(d, sc, eta, part, pos[start:stop], ratio[start:stop], path[start:stop])
            return pos, ratio, path
        scene = self.scene
        to_px = 1.0 / scene.receiver.pixel_size
        for start in range(0, count, self.chunk_size):
            stop = min(count, start + self.chunk_size)
            part = torch.from_numpy(np.ascontiguousarray(aim[start:stop].T))
            targets = torch.cat([part, torch.full((1, stop - start), scene.substrate.thickness, dtype=torch.float64)])
            batch = self.emitter.photons_toward(targets, torch.full((stop - start,), channel, dtype=torch.int64))
            hits = trace_substrate(heights, scene, batch, self.glass_index, self.fresnel)
            p = ((hits.position + scene.receiver.half_width) * to_px).numpy()
            r = (hits.flux / batch.flux).numpy()
            good = np.isfinite(r) & np.isfinite(p).all(axis=0) & (r > 0.0)
            pos[start:stop] = p.T
            ratio[start:stop] = np.where(good, r, 0.0)
            path[start:stop] = np.where(good, hits.path.numpy(), LOST)
        return pos, ratio, path

    def _trace_grid(self, heights: torch.Tensor, channel: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Receiver positions (K, K, 2) (pixel corner units), transmittances (K, K) and path
        codes (K, K) of the grid."""
        k = self.vertices
        pos = np.empty((k * k, 2))
        ratio = np.empty(k * k)
        path = np.empty(k * k)
        rows_per_chunk = max(1, self.chunk_size // k)
        cols = self.aim_coordinates(np.arange(k))
        for r0 in range(0, k, rows_per_chunk):
            r1 = min(k, r0 + rows_per_chunk)
            aim = np.empty((r1 - r0, k, 2))
            aim[:, :, 0] = cols[None, :]
            aim[:, :, 1] = self.aim_coordinates(np.arange(r0, r1))[:, None]
            rows = slice(r0 * k, r1 * k)
            pos[rows], ratio[rows], path[rows] = self.trace(heights, aim.reshape(-1, 2), channel)
        return pos.reshape(k, k, 2), ratio.reshape(k, k), path.reshape(k, k)

    def _subdivide(self, heights: torch.Tensor, channel: int, pos: np.ndarray, ratio: np.ndarray, path: np.ndarray,
                   mixed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cut the grid triangles flagged ``mixed`` (2, K-1, K-1) recursively at their edge
        midpoints; returns the sub-triangles whose vertices took one path: aim points (T, 3, 2)
        (scene units), receiver positions (T, 3, 2) (pixel corner units) and vertex
        transmittances (T, 3)."""
        t, i, j = np.nonzero(mixed)
        rows = np.stack([i, i + (t == 1), i + 1], axis=1)
        cols = np.stack([j, j + 1, j + (t == 0)], axis=1)
        aim = np.stack([self.aim_coordinates(cols), self.aim_coordinates(rows)], axis=-1)
        rec = pos[rows, cols]
        q = ratio[rows, cols]
        code = path[rows, cols]
        kept_aim, kept_rec, kept_q = [], [], []
        for _ in range(self.subdivisions):
            if aim.shape[0] == 0:
                break
            mid = 0.5 * (aim + aim[:, [1, 2, 0]])  # m01, m12, m20
            mid_rec, mid_q, mid_code = self.trace(heights, mid.reshape(-1, 2), channel)
            aim = np.concatenate([aim, mid], axis=1)[:, CHILDREN].reshape(-1, 3, 2)
            rec = np.concatenate([rec, mid_rec.reshape(-1, 3, 2)], axis=1)[:, CHILDREN].reshape(-1, 3, 2)
            q = np.concatenate([q, mid_q.reshape(-1, 3)], axis=1)[:, CHILDREN].reshape(-1, 3)
            code = np.concatenate([code, mid_code.reshape(-1, 3)], axis=1)[:, CHILDREN].reshape(-1, 3)
            one_path = (code[:, 0] == code[:, 1]) & (code[:, 0] == code[:, 2])
            keep = one_path & (code[:, 0] != LOST)
            kept_aim.append(aim[keep])
            kept_rec.append(rec[keep])
            kept_q.append(q[keep])
            again = ~one_path
            aim, rec, q, code = aim[again], rec[again], q[again], code[again]
        if not kept_aim:
            return np.empty((0, 3, 2)), np.empty((0, 3, 2)), np.empty((0, 3))
        return np.concatenate(kept_aim), np.concatenate(kept_rec), np.concatenate(kept_q)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """Irradiance (c, n, n) float64 (W per scene unit^2, [channel, row = y, col = x]) of the
        printed ``heights`` (m, m) (scene units), on their device; no autograd (traced on the CPU).
        Sets :attr:`last_budget`. ``progress`` is accepted as an operator's render takes it (a
        render takes seconds: nothing to show)."""
        checked_print_heights(heights, self.scene.substrate.thickness)
        self.scene.check_heights_below_light(float(heights.max()))
        d = heights.detach().to(device="cpu", dtype=torch.float64).contiguous()
        self.emitter.warn_dark_rim(d.numpy())
        n = self.scene.receiver.resolution
        scale = self._channel_scale()
        omega = self.grid_solid_angles()
        light = self.scene.light.position
        dz = self.scene.substrate.thickness - light[2]
        image = np.zeros(self.output_shape)
        budget = FluxBudget(0.0, 0.0, 0.0, 0.0)
        with torch.no_grad():
            for c in range(self.scene.channels):
                pos, ratio, path = self._trace_grid(d, c)
                flux, mixed = grid_flux(omega, ratio, path, scale)
                image[c] = rasterize_grid(pos, flux, n)
                kept_omega = float(omega[flux != 0.0].sum())
                rasterised = float(flux.sum())
                if self.subdivisions and mixed.any():
                    aim, rec, q = self._subdivide(d, c, pos, ratio, path, mixed)
                    sub_omega = triangle_solid_angle(aim[:, 0, 0] - light[0], aim[:, 0, 1] - light[1],
                                                     aim[:, 1, 0] - light[0], aim[:, 1, 1] - light[1],
                                                     aim[:, 2, 0] - light[0], aim[:, 2, 1] - light[1], float(dz))
                    sub_flux = scale * sub_omega * q.mean(axis=1)
                    image[c] += rasterize_triangles(rec, sub_flux, n)
                    kept_omega += float(sub_omega.sum())
                    rasterised += float(sub_flux.sum())
                total_omega = float(omega.sum())
                budget.emitted += scale * total_omega
                budget.dropped += scale * (total_omega - kept_omega)
                budget.rasterised += rasterised
                budget.received += float(image[c].sum())
        self.last_budget = budget
        return torch.from_numpy(image / self.pixel_area).to(heights.device)

    def describe(self) -> dict[str, float]:
        """Sampling figures for logs: grid, triangles, vertices per receiver pixel side and the
        flux budget (W) of the last render, if any."""
        k = self.vertices
        info: dict[str, float] = {
            "vertices": k, "triangles": 2 * (k - 1) ** 2,
            "vertices_per_pixel": (k - 1) * self.scene.receiver.pixel_size / (2.0 * self.scene.substrate.half_width),
            "subdivisions": self.subdivisions, "fresnel": self.fresnel, "chunk_size": self.chunk_size,
            "tracer": self.tracer}
        if self.last_budget is not None:
            info.update({f"flux_{key}": value for key, value in asdict(self.last_budget).items()})
        return info
