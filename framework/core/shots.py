"""Where each shot of a stack was taken (framework/stack/stack_data.py): the setup keys of one
shot's config, read against the configured scene.

A shot's screen is the configured one moved by ``offset`` (or placed at ``screen_distance``),
its light the configured one moved by ``light_offset`` (or placed at ``light``): offsets are what
a translation stage or a lamp rail measures, so joint calibration (framework/lab/calibration.py)
may move the configured distance and light while the offsets between the shots stay fixed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from framework.core.units import scene_length
from operators.scene import Scene
from operators.values import checked_number

__all__ = ["SETUP_KEYS", "ShotSetup", "shot_setup"]

SETUP_KEYS = ("source", "screen_distance", "offset", "light", "light_offset", "receiver_half_width", "gain", "weight")


@dataclasses.dataclass(frozen=True)
class ShotSetup:
    """Where one shot was taken, relative to the configured scene.

    Attributes:
        offset: Screen distance minus the configured one, scene units (0: the configured screen).
        light_offset: Light position minus the configured one (x, y, z), scene units.
        receiver_half_width: The receiver's half width, scene units (None: the configured one).
        gain: The camera gain the model starts from.
        weight: Weight of this shot's squared misfit.
    """

    offset: float = 0.0
    light_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    receiver_half_width: float | None = None
    gain: float = 1.0
    weight: float = 1.0

    def scene(self, base: Scene, where: str) -> Scene:
        """The configured scene ``base`` moved to this shot's setup; a screen at or above the
        substrate's bottom, or a light at or below its top, is refused naming ``where``."""
        distance = -base.receiver.z + self.offset
        if not distance > 0.0:
            raise ValueError(f"{where}: the screen would lie {distance:.4g} below the substrate's bottom (configured "
                             f"{-base.receiver.z:.4g} + offset {self.offset:.4g}), i.e. inside or above the glass; "
                             "give an offset or screen_distance that keeps it below (> 0)")
        (x, y, z), (dx, dy, dz) = base.light.position, self.light_offset
        light = (x + dx, y + dy, z + dz)
        if not light[2] > base.substrate.thickness:
            raise ValueError(f"{where}: the light would sit at z = {light[2]:.4g}, not above the substrate's top "
                             f"(z = {base.substrate.thickness:.4g}); check light / light_offset")
        half_width = base.receiver.half_width if self.receiver_half_width is None else self.receiver_half_width
        receiver = dataclasses.replace(base.receiver, z=-distance, half_width=half_width)
        return dataclasses.replace(base, light=dataclasses.replace(base.light, position=light), receiver=receiver)


def _triple(value: Any, where: str, mm: float) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{where}={value!r} must be [x, y, z] (scene units or e.g. '2 mm')")
    x, y, z = (scene_length(v, mm, f"{where}[{i}]") for i, v in enumerate(value))
    return (x, y, z)


def shot_setup(spec: Mapping[str, Any], where: str, base: Scene, mm: float) -> ShotSetup:
    """The setup keys of one shot's config read against the configured scene ``base``."""
    if "screen_distance" in spec and "offset" in spec:
        raise ValueError(f"{where} gives both screen_distance and offset; give one (offset: from receiver.z)")
    offset = 0.0
    if spec.get("screen_distance") is not None:
        offset = scene_length(spec["screen_distance"], mm, f"{where}.screen_distance") + base.receiver.z
    elif spec.get("offset") is not None:
        offset = scene_length(spec["offset"], mm, f"{where}.offset")
    if "light" in spec and "light_offset" in spec:
        raise ValueError(f"{where} gives both light and light_offset; give one (light_offset: from light.position)")
    light_offset = (0.0, 0.0, 0.0)
    if spec.get("light") is not None:
        (x, y, z), (x0, y0, z0) = _triple(spec["light"], f"{where}.light", mm), base.light.position
        light_offset = (x - x0, y - y0, z - z0)
    elif spec.get("light_offset") is not None:
        light_offset = _triple(spec["light_offset"], f"{where}.light_offset", mm)
    half = spec.get("receiver_half_width")
    if half is not None:
        half = scene_length(half, mm, f"{where}.receiver_half_width")
        if not half > 0.0:
            raise ValueError(f"{where}.receiver_half_width={spec['receiver_half_width']!r} must be a length > 0")
    gain = checked_number(spec.get("gain", 1.0), f"{where}.gain")
    weight = checked_number(spec.get("weight", 1.0), f"{where}.weight")
    if not gain > 0.0 or not weight > 0.0:
        raise ValueError(f"{where}: gain={gain} and weight={weight} must both be > 0")
    return ShotSetup(offset, light_offset, half, gain, weight)
