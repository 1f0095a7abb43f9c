"""Photon emission from the light (a point, or emission points over a disc or a square) toward the
substrate's top square.

Photons of channel k aim at points q_j (j = 0 .. N_c - 1) of the square [-A, A]^2 at z = h,
placed by the R2 low-discrepancy sequence (Roberts 2018; generator 1/g, 1/g^2 with g the plastic
number) shifted by a random offset per channel (Cranley-Patterson rotation, drawn from the seed):
any photon count, any chunking, and lower noise than independent random points. A is fixed by
the scene: the substrate's half width W, unless ``substrate.edge_height`` says the top may stand
raised at the square's edge. The rays aimed at the square's edge then meet the raised top inside
it, and the rim beyond them would be dark, so A reaches far enough that rays from every emission
point cover a top that high (:func:`aim_half_width`); a ray that passes beside the block is lost
(docs/method.md, "The substrate's side walls"). :meth:`LightEmitter.dark_rim` measures the rim a
top higher than that leaves dark.

Each photon carries the flux of its cell of the square, Phi = P / (4 pi c) * A_cell cos(theta) / r^2
(P the light power split evenly over the c channels), and direction differentials that map the
unit disk onto a disk of radius ``footprint_radius`` around q_j in that plane:
Dw_u = radius (e_x - w w_x) / r, Dw_v = radius (e_y - w w_y) / r (positional differentials are zero
for a point light). ``footprint_radius`` follows from ``footprint_px``:

- ``"cell"`` (the default of both operators): the photon's own cell, the disk of area A_cell,
  radius sqrt(A_cell / pi); the optics then carry it to the receiver, so every footprint is the
  image of the cell it stands for and the model adds no blur of its own beyond the pixel filter
  (docs/method.md, "Photon emission");
- a number: that many receiver pixels for light that went straight through (the paper's
  "smoothing", independent of the photon count so that renders with different counts blur alike).

An extended light (operators/scene.py, ``light.shape: disc | square``) emits each channel's
photons from its K emission points (:func:`source_points`: the R2 sequence shifted by the seed,
put onto the source by operators/light_source.py) in K consecutive segments of the same aim sequence: photon j
of a channel leaves source
point floor(j K / N_c). Every segment covers the square (a stretch of a Kronecker sequence is
itself evenly spread); each photon carries a point light's photon's flux (cell A / N_c) and, with
``footprint_px: cell``, the footprint of its segment's cell (area K A / N_c: each segment's
photons tile the square), and the photons of all segments together are the point light's, each
from its own point of the source. Photons of one segment share their origin:
:meth:`LightEmitter.segments` gives the index ranges, and a batch never spans two. The patch of
the source each emission point stands for blurs the caustic by ``source_blur_sigma``
(operators/light_source.py, ``patch_variance``, carried to the receiver by the flat glass's
spread), which the operators apply to their images (a Gaussian integrated over each pixel).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from operators.light_source import moment_matched, onto_source, patch_variance, receiver_spread
from operators.scene import Light, Scene
from operators.values import checked_number, checked_whole

LOG = logging.getLogger(__name__)
PLASTIC_NUMBER = 1.324717957244746
CELL_FOOTPRINT = "cell"  # footprint_px setting: footprints the size of the photon's emission cell
R2_STEP = (1.0 / PLASTIC_NUMBER, 1.0 / PLASTIC_NUMBER ** 2)


def source_points(light: Light, count: int, shift: tuple[float, float]) -> np.ndarray:
    """The photon operators' ``count`` emission points over an extended ``light``: the R2 sequence
    with the Cranley-Patterson ``shift`` (in [0, 1)^2) put onto the source, centred and scaled so
    that with the patches' blur (operators/light_source.py, ``patch_variance``) they keep the
    source's mean and second moment; offsets (count, 2) float64 from its centre. A point light:
    one point at 0."""
    if not light.extended:
        return np.zeros((1, 2))
    k = np.arange(count, dtype=np.float64)
    u, v = np.mod(shift[0] + k * R2_STEP[0], 1.0), np.mod(shift[1] + k * R2_STEP[1], 1.0)
    return moment_matched(onto_source(light, u, v), light, patch_variance(light, count))


AIM_QUANTUM = 1.0 / 1024.0  # the aim square's growth is rounded up to this share of W
NARROW_RIM = 0.1  # a dark rim narrower than this share of the height grid's spacing goes unreported


def crossing_reach(scene: Scene, x: np.ndarray, y: np.ndarray, d: np.ndarray, offsets: np.ndarray) -> float:
    """The farthest |x| or |y| (scene units) at which rays from every emission point (the light's
    position plus ``offsets`` (K, 2)) through the top points (x, y, h + d) (arrays of one shape)
    cross the plane z = h: a point raised by d is met by the ray aimed (l_z - h) / (l_z - h - d)
    times as far from the emission point; at least W."""
    half, h = scene.substrate.half_width, scene.substrate.thickness
    lx, ly, lz = scene.light.position
    stretch = (lz - h) / (lz - h - d)
    reach = half
    for sx in (lx + float(offsets[:, 0].min()), lx + float(offsets[:, 0].max())):
        reach = max(reach, float(np.abs(sx + (x - sx) * stretch).max()))
    for sy in (ly + float(offsets[:, 1].min()), ly + float(offsets[:, 1].max())):
        reach = max(reach, float(np.abs(sy + (y - sy) * stretch).max()))
    return reach


def aim_half_width(scene: Scene, offsets: np.ndarray) -> float:
    """The half width A >= W of the square on z = h the photons aim at: W where
    ``substrate.edge_height`` is 0; else twice as far beyond W as the rays that reach a top
    standing ``edge_height`` above the substrate along the whole edge of the square, from every
    emission point (``offsets`` (K, 2) from the light's position), rounded up to AIM_QUANTUM W (the
    margin covers the interpolated surface between samples)."""
    half, raised = scene.substrate.half_width, scene.substrate.edge_height
    if raised <= 0.0:
        return half
    edge = np.array([-half, half])
    reach = crossing_reach(scene, edge, edge, np.full(2, raised), offsets)
    return half * (1.0 + math.ceil(2.0 * (reach - half) / (AIM_QUANTUM * half)) * AIM_QUANTUM)


def check_footprint(value: object) -> float | str:
    """``operator.footprint_px`` checked: ``"cell"`` or a positive number of receiver pixels."""
    if value == CELL_FOOTPRINT:
        return CELL_FOOTPRINT
    return checked_number(value, "operator.footprint_px", above=0.0, example="3", must="must be 'cell' (the "
                          "photon's own emission cell) or a positive number of receiver pixels")


@dataclass
class PhotonBatch:
    """A chunk of photons leaving the light.

    origin (3,) (the photons' emission point), direction (3, N) unit vectors, direction_diff (2, 3, N) the differentials
    Dw_u and Dw_v, flux (N,) in W, channel (N,) int64 wavelength index.
    """

    origin: torch.Tensor
    direction: torch.Tensor
    direction_diff: torch.Tensor
    flux: torch.Tensor
    channel: torch.Tensor


class LightEmitter:
    """Deterministic photon source: the same seed gives the same photons, chunk by chunk."""

    def __init__(self, scene: Scene, photons: int, seed: int, footprint_px: float | str,
                 dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> None:
        photons = checked_whole(photons, "photons", scene.channels, must="must be an integer >= the number of "
                                f"wavelengths ({scene.channels}); typical values are 1e6 - 1e8")
        footprint_px = check_footprint(footprint_px)
        self.scene = scene
        self.per_channel = int(photons) // scene.channels
        self.dtype = dtype
        self.device = torch.device(device)
        rng = np.random.default_rng(seed)
        self.shifts = torch.from_numpy(rng.random((scene.channels, 2)))
        self.sources = scene.light.source_count
        if self.sources > self.per_channel:
            raise ValueError(f"light.points={self.sources} exceeds the photons per wavelength ({self.per_channel}); "
                             "lower light.points or raise photons")
        # Emission points over the source (K, 2), offsets from the light's centre (one at 0 for a
        # point), and the blur of the patch each stands for (module docstring).
        self.offsets = source_points(scene.light, self.sources, tuple(rng.random(2)))
        residual = patch_variance(scene.light, self.sources) if scene.light.extended else 0.0
        spread = receiver_spread(
            scene.light, scene.substrate.thickness, float(np.mean(scene.indices)), -scene.receiver.z
        )
        # The patches' blur on the receiver: standard deviation per axis, scene units.
        self.source_blur_sigma = math.sqrt(residual) * spread
        self.footprint_px = footprint_px
        self.aim_half = aim_half_width(scene, self.offsets)
        self.cell_area = (2.0 * self.aim_half) ** 2 / self.per_channel
        if footprint_px == CELL_FOOTPRINT:
            self.footprint_radius = math.sqrt(self.sources * self.cell_area / math.pi)
        else:
            lz = scene.light.position[2]
            drop = (lz - scene.substrate.thickness) / (lz - scene.receiver.z)
            self.footprint_radius = footprint_px * scene.receiver.pixel_size * drop

    def dark_rim(self, heights: np.ndarray) -> tuple[float, float]:
        """The top of ``heights`` (m, m) over [-W, W]^2 that no photon's ray reaches: the rim's
        width beyond the aim square's rays and the ``substrate.edge_height`` that would light it
        (scene units); (0, 0) for a rim narrower than NARROW_RIM of the grid's spacing."""
        heights = np.asarray(heights, dtype=np.float64)
        raised = heights > 0.0
        if not raised.any():
            return 0.0, 0.0
        half, m = self.scene.substrate.half_width, heights.shape[0]
        rows, cols = np.nonzero(raised)
        coords = np.linspace(-half, half, m)
        reach = crossing_reach(self.scene, coords[cols], coords[rows], heights[rows, cols], self.offsets)
        rim = (reach - self.aim_half) * half / reach  # its width on the top: rays fan out by reach / W
        if rim <= NARROW_RIM * 2.0 * half / (m - 1):
            return 0.0, 0.0
        drop = self.scene.light.position[2] - self.scene.substrate.thickness
        return rim, drop * (1.0 - half / reach)  # a top this high along the edge is met out to ``reach``

    def warn_dark_rim(self, heights: np.ndarray) -> bool:
        """Log one line where ``heights`` (m, m) leave a dark rim (:meth:`dark_rim`), naming the
        fix; True if it did."""
        rim, needed = self.dark_rim(heights)
        if rim > 0.0:
            mm = self.scene.mm_per_unit
            LOG.warning("the top stands raised at the square's edge: a rim %.3g mm wide there gets no light "
                        "(substrate.edge_height=%.4g covers %.3g mm); give substrate.edge_height=%.4g or more",
                        rim * mm, self.scene.substrate.edge_height, self.scene.substrate.edge_height * mm, needed)
        return rim > 0.0

    @property
    def total(self) -> int:
        """Photons emitted in all channels."""
        return self.per_channel * self.scene.channels

    @property
    def smoothing(self) -> float:
        """Footprint radius over the radius at which footprints just tile the square."""
        return self.footprint_radius / math.sqrt(self.cell_area / math.pi)

    def source_of(self, index: int) -> int:
        """The emission point (0 .. K - 1) of photon ``index`` (channel-major order)."""
        return (index % self.per_channel) * self.sources // self.per_channel

    def segments(self) -> list[tuple[int, int]]:
        """The index ranges of photons that share an emission point, in order: all photons for a
        point light, one range per channel and emission point for an extended one."""
        if self.sources == 1:
            return [(0, self.total)]
        bounds = [-(-k * self.per_channel // self.sources) for k in range(self.sources + 1)]
        return [(c * self.per_channel + a, c * self.per_channel + b)
                for c in range(self.scene.channels) for a, b in zip(bounds[:-1], bounds[1:])]

    def origin(self, source: int) -> tuple[float, float, float]:
        """Emission point ``source``'s position (x, y, z), scene units."""
        x, y, z = self.scene.light.position
        return (x + float(self.offsets[source, 0]), y + float(self.offsets[source, 1]), z)

    def batch(self, start: int, stop: int) -> PhotonBatch:
        """Photons with global indices start .. stop-1 (channel-major order), all from one
        emission point (within one of :meth:`segments`), aimed at the square [-A, A]^2 on z = h
        (A = :attr:`aim_half`)."""
        source = self.source_of(start)
        last = stop - 1
        if self.sources > 1 and stop > start and (self.source_of(last) != source
                                                  or last // self.per_channel != start // self.per_channel):
            raise ValueError(f"photons {start} .. {stop - 1} leave different emission points; split the range at "
                             "LightEmitter.segments()")
        idx = torch.arange(start, stop, dtype=torch.int64)
        channel = idx // self.per_channel
        j = (idx - channel * self.per_channel).to(torch.float64)
        shift = self.shifts[channel]
        u = torch.frac(shift[:, 0] + j * R2_STEP[0])
        v = torch.frac(shift[:, 1] + j * R2_STEP[1])
        half = self.aim_half
        cast = dict(dtype=self.dtype, device=self.device)
        targets = torch.stack([(2.0 * half) * u.to(**cast) - half, (2.0 * half) * v.to(**cast) - half,
                               torch.full_like(u, self.scene.substrate.thickness, **cast)])
        return self.photons_toward(targets, channel.to(self.device), source)

    def photons_toward(self, targets: torch.Tensor, channel: torch.Tensor, source: int = 0) -> PhotonBatch:
        """Photons from emission point ``source`` aimed at ``targets`` (3, N) on the plane z = h,
        each standing for one cell of area ``cell_area`` there; flux and direction differentials as
        in the module docstring."""
        scene = self.scene
        light = torch.tensor(self.origin(source), dtype=targets.dtype, device=targets.device)
        to_target = targets - light.unsqueeze(-1)
        r = torch.sqrt((to_target * to_target).sum(0))
        direction = to_target / r
        inv_r = 1.0 / r
        flux = (scene.light.power / (4.0 * math.pi * scene.channels) * self.cell_area
                * (light[2] - scene.substrate.thickness)) * inv_r ** 3
        scale = self.footprint_radius * inv_r
        diff = -direction * direction[:2].unsqueeze(1) * scale  # (2, 3, N): -w w_k radius / r
        diff[0, 0] += scale
        diff[1, 1] += scale
        return PhotonBatch(origin=light, direction=direction, direction_diff=diff, flux=flux, channel=channel)
