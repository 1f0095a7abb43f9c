"""Physical description of the caustic setup (docs/method.md, "Setup and units"); lengths in scene units.

The substrate occupies [-W, W]^2 with its flat bottom at z = 0 and its top at z = h + d(x, y);
a light (a point, a disc or a square) shines on it from above and the receiver plane at z = receiver.z < 0 records the
caustic. Arrays follow [row, col] = [y, x]. :func:`scene_from_groups` reads a scene from the
plain config groups (light, substrate, receiver, material, wavelengths), lengths given in scene
units or with a unit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from operators.lengths import DEFAULT_MM_PER_UNIT, scene_length
from operators.materials import FUSED_SILICA, DispersionCurve, material_from_config, refractive_indices
from operators.values import checked_number, checked_whole, is_number


WALLS = ("clear", "absorbing")  # Substrate.walls
MAX_RECEIVER_RESOLUTION = 16384  # pixels per side: one float64 image of 16384^2 is 2 GB


LIGHT_SHAPES = ("point", "disc", "square")  # Light.shape
MAX_SOURCE_POINTS = 4096  # Light.points: emission points of an extended light at most


@dataclass(frozen=True)
class Light:
    """The light: ``position`` (x, y, z) of its centre and ``power`` in W over the full sphere.

    ``shape``: ``point`` (an isotropic point), or an extended source facing the glass (a flash
    behind a diffuser, docs/method.md, "The extended light"): a ``disc`` of diameter ``size`` or a
    ``square`` of side ``size`` (scene units) in the plane z = position z, of uniform brightness.
    The photon operators emit each photon from one of ``points`` emission points spread evenly
    over the source (:func:`operators.emission.source_points`).
    """

    position: tuple[float, float, float] = (0.0, 0.0, 10.0)
    power: float = 1.0
    shape: str = "point"
    size: float = 0.0
    points: int = 64

    def __post_init__(self) -> None:
        if len(self.position) != 3:
            raise ValueError(f"light.position={self.position} must have three coordinates (x, y, z)")
        for axis, v in zip("xyz", self.position):
            checked_number(v, f"light.position.{axis}")
        checked_number(self.power, "light.power", above=0.0, unit="W")
        if self.shape not in LIGHT_SHAPES:
            raise ValueError(f"light.shape={self.shape!r} must be one of {', '.join(LIGHT_SHAPES)}")
        checked_number(self.size, "light.size", least=0.0, must="must be >= 0", unit="scene units or e.g. '50 mm'")
        if self.shape == "point" and self.size != 0.0:
            raise ValueError(f"light.size={self.size} is set for light.shape=point; use light.shape=disc or square, "
                             "or light.size=0")
        if self.shape != "point" and self.size == 0.0:
            raise ValueError(f"light.shape={self.shape} needs light.size > 0 (its diameter or side, e.g. '50 mm'), "
                             "or light.shape=point")
        checked_whole(self.points, "light.points", 1, MAX_SOURCE_POINTS,
                      must=f"must be an integer in [1, {MAX_SOURCE_POINTS}] (emission points over an extended light)")

    @property
    def extended(self) -> bool:
        """Whether the light has a size (a disc or a square)."""
        return self.shape != "point"

    @property
    def source_count(self) -> int:
        """Emission points the photon operators use: ``points`` for an extended light, else 1."""
        return int(self.points) if self.extended else 1

    def at(self, offset: tuple[float, float], power: float | None = None) -> Light:
        """A point light moved by ``offset`` (dx, dy) within the source's plane, with ``power``
        (None: this light's)."""
        x, y, z = self.position
        return Light(position=(x + offset[0], y + offset[1], z), power=self.power if power is None else power)


@dataclass(frozen=True)
class Substrate:
    """Glass plate of ``thickness`` h below the printed height field, spanning [-half_width, half_width]^2.

    ``walls``: ``clear`` (a cut block: light that meets a side wall refracts out of it or is
    totally reflected back in, docs/method.md, "The substrate's side walls") or ``absorbing``
    (blackened or frosted edges: that light is lost, the paper's assumption).

    ``edge_height``: how high (scene units, above the substrate) the top may stand at the square's
    edge with all of it lit. The photons aim at a square just wide enough (operators/emission.py,
    ``aim_half_width``); 0 aims at the substrate's own square, right for prints that leave the edges
    flat, while a top raised at the edge keeps a dark rim there."""

    thickness: float = 0.1
    half_width: float = 1.0
    walls: str = "clear"
    edge_height: float = 0.0

    def __post_init__(self) -> None:
        checked_number(self.thickness, "substrate.thickness", above=0.0, unit="scene units")
        checked_number(self.half_width, "substrate.half_width", above=0.0, unit="scene units")
        checked_number(self.edge_height, "substrate.edge_height", least=0.0, unit="scene units above the substrate")
        if self.walls not in WALLS:
            raise ValueError(f"substrate.walls={self.walls!r} must be one of {', '.join(WALLS)}")


@dataclass(frozen=True)
class Receiver:
    """Sensor plane at height ``z`` (below the substrate), n x n pixels over [-half_width, half_width]^2."""

    z: float = -0.05
    resolution: int = 512
    half_width: float = 1.0

    def __post_init__(self) -> None:
        checked_number(self.z, "receiver.z", below=0.0, must="must lie below the substrate bottom (z < 0)",
                       example="-0.05")
        checked_whole(self.resolution, "receiver.resolution", 2, MAX_RECEIVER_RESOLUTION,
                      must=f"must be an integer in [2, {MAX_RECEIVER_RESOLUTION}] (pixels per side)")
        checked_number(self.half_width, "receiver.half_width", above=0.0, unit="scene units")

    @property
    def pixel_size(self) -> float:
        """Edge length of one pixel (scene units)."""
        return 2.0 * self.half_width / self.resolution

    def pixel_centres(self) -> list[float]:
        """Pixel-centre coordinates (2p + 1) / n - 1, scaled to the half width."""
        return [-self.half_width + (p + 0.5) * self.pixel_size for p in range(self.resolution)]


@dataclass(frozen=True)
class Scene:
    """Light, substrate, receiver, material, the wavelengths (um, one image channel each) and the
    length of one scene unit in mm (``units.mm_per_unit``: lengths the operators read, e.g. the
    optical elements' sizes, may be given in mm)."""

    light: Light = field(default_factory=Light)
    substrate: Substrate = field(default_factory=Substrate)
    receiver: Receiver = field(default_factory=Receiver)
    material: DispersionCurve = FUSED_SILICA
    wavelengths: tuple[float, ...] = (0.633,)
    mm_per_unit: float = DEFAULT_MM_PER_UNIT

    def __post_init__(self) -> None:
        checked_number(self.mm_per_unit, "units.mm_per_unit", above=0.0, unit="mm per scene unit")
        if not self.wavelengths:
            raise ValueError("wavelengths is empty; give at least one, e.g. [0.633] (micrometres)")
        refractive_indices(self.material, self.wavelengths)
        if self.light.position[2] <= self.substrate.thickness:
            raise ValueError(f"light.position z={self.light.position[2]} must lie above the substrate top "
                             f"(z > thickness {self.substrate.thickness})")

    @property
    def indices(self) -> tuple[float, ...]:
        """Refractive index of the glass per channel."""
        return tuple(refractive_indices(self.material, self.wavelengths))

    @property
    def channels(self) -> int:
        return len(self.wavelengths)

    def check_heights_below_light(self, max_height: float) -> None:
        """Refuse a height field that reaches the light."""
        top = self.substrate.thickness + max_height
        if self.light.position[2] <= top:
            raise ValueError(f"light.position z={self.light.position[2]} is not above the glass top "
                             f"z={top:.4g}; raise the light or lower the heights")


def scene_from_groups(light: Mapping[str, Any], substrate: Mapping[str, Any], receiver: Mapping[str, Any],
                      material: Any, wavelengths: Any, mm: float) -> Scene:
    """The scene of the plain config groups (their keys checked by the caller): lengths in scene
    units or as strings with a unit ('2.5 mm', ``mm`` millimetres per scene unit), ``material`` a
    name or a dispersion (operators/materials.py; None: fused silica), ``wavelengths`` in um."""
    light = dict(light)
    if "position" in light:
        position = light["position"]
        if not isinstance(position, (list, tuple)) or len(position) != 3:
            raise ValueError(f"light.position={position!r} must be [x, y, z], e.g. light.position=[0,0,10]")
        light["position"] = tuple(scene_length(v, mm, f"light.position[{i}]") for i, v in enumerate(position))
    if "power" in light:
        light["power"] = checked_number(light["power"], "light.power", must="must be a number")
    if "size" in light:
        light["size"] = scene_length(light["size"], mm, "light.size")
    if "points" in light:
        light["points"] = checked_whole(light["points"], "light.points")
    glass = {k: v if k == "walls" else scene_length(v, mm, f"substrate.{k}") for k, v in substrate.items()
             if not (k == "edge_height" and v is None)}  # null: the command's own choice (sfc-design's limit)
    screen = {k: checked_whole(v, f"receiver.{k}") if k == "resolution" else scene_length(v, mm, f"receiver.{k}")
              for k, v in receiver.items()}
    if is_number(wavelengths):
        wavelengths = [wavelengths]
    if not isinstance(wavelengths, (list, tuple)):
        raise ValueError(f"wavelengths={wavelengths!r} must be a list in micrometres, e.g. [0.633]")
    return Scene(light=Light(**light), substrate=Substrate(**glass), receiver=Receiver(**screen),
                 material=material_from_config(material),
                 wavelengths=tuple(checked_number(v, f"wavelengths[{i}]", must="must be a number")
                                   for i, v in enumerate(wavelengths)),
                 mm_per_unit=mm)
