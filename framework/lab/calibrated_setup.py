"""The setup that joint calibration (framework/lab/calibration.py) moves: its parameters by
name, renders with other values, and the change applied.

- :class:`CameraSetup`: one image seen through the camera (operators/imaging.py): ``gain``,
  ``screen_distance``, ``light_height``, ``light_x``, ``light_y``, the extended light's size
  ``light_size`` (its diameter or side, operators/scene.py) and the screen blur's width ``psf_sigma``.
- :class:`StackSetup`: a stack of shots (operators/stack.py), each seen through the camera: one
  gain per shot (``gain_0`` .. ``gain_<N-1>``), the shared geometry and the shared ``psf_sigma``
  (one screen). ``screen_distance`` and the light's position are those of the configured scene;
  every shot keeps its offset from them (a translation stage's or a lamp rail's known moves), so
  moving the configured distance moves every screen by the same amount.

Both give dG/dpsf_sigma = gain (dK/dsigma) F(d) analytically, from the render of G(d) itself
(:meth:`CameraSetup.render_and_psf_column`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from operators.imaging import ImagingOperator
from operators.scene import Scene
from operators.stack import StackOperator

__all__ = ["GEOMETRY", "PSF", "CameraSetup", "StackSetup", "is_gain", "setup_values", "with_setup"]

GEOMETRY = ("screen_distance", "light_height", "light_x", "light_y", "light_size")
PSF = "psf_sigma"  # the screen blur's standard deviation, scene units (operators/imaging.py)


def is_gain(name: str) -> bool:
    """Whether a parameter is a camera gain (``gain``, or a stack's ``gain_<i>``)."""
    return name == "gain" or name.startswith("gain_")


def setup_values(scene: Scene, gain: float) -> dict[str, float]:
    """Every calibration parameter's value for a scene and gain (scene units)."""
    x, y, z = scene.light.position
    return {"gain": gain, "screen_distance": -scene.receiver.z, "light_height": z, "light_x": x, "light_y": y,
            "light_size": scene.light.size}


def with_setup(scene: Scene, values: Mapping[str, float]) -> Scene:
    """``scene`` with the geometric calibration parameters in ``values`` replaced."""
    x, y, z = scene.light.position
    light = dataclasses.replace(scene.light, position=(values.get("light_x", x), values.get("light_y", y),
                                                       values.get("light_height", z)),
                                size=values.get("light_size", scene.light.size))
    receiver = dataclasses.replace(scene.receiver, z=-values.get("screen_distance", -scene.receiver.z))
    return dataclasses.replace(scene, light=light, receiver=receiver)


def _camera(operator: object, where: str) -> ImagingOperator:
    if not isinstance(operator, ImagingOperator):
        raise ValueError(f"joint calibration needs {where} built with imaging=True (framework/scene/scene_config.py)")
    return operator


class CameraSetup:
    """One image through the camera: G(d; p) = gain K(psf_sigma) F(d; geometry)."""

    def __init__(self, operator: ImagingOperator) -> None:
        self.operator = _camera(operator, "the operator")

    def names(self, requested: Sequence[str]) -> list[str]:
        """The parameters of the configured names (here: the names themselves)."""
        return list(requested)

    @property
    def scene(self) -> Scene:
        """The configured scene as calibrated so far."""
        return self.operator.scene

    @property
    def pixel_size(self) -> float:
        """The receiver's pixel size, scene units."""
        return float(self.operator.inner.scene.receiver.pixel_size)

    def values(self) -> dict[str, float]:
        """Every parameter's current value."""
        return {**setup_values(self.operator.scene, self.operator.gain), PSF: self.operator.psf_sigma}

    def render(self, d: Tensor, values: Mapping[str, float] | None = None) -> Tensor:
        """G(d) (c, n, n), float64, at the current values or at ``values`` (the setup unchanged)."""
        if values is None:
            return self.operator.render(d).double()
        scene = with_setup(self.operator.scene, values)
        return self.operator.render_with(scene, values.get("gain", self.operator.gain), d, values.get(PSF)).double()

    def render_and_psf_column(self, d: Tensor) -> tuple[Tensor, Tensor]:
        """(G(d), dG/dpsf_sigma) (c, n, n) each, float64, at the current values: one render."""
        image, column = self.operator.render_and_sigma_derivative(d)
        return image.double(), column.double()

    def gain_column(self, image: Tensor, name: str, values: Mapping[str, float]) -> Tensor:
        """dG/d(gain) = G / gain, exactly."""
        return image / values[name]

    def apply(self, values: Mapping[str, float]) -> None:
        """Move the setup to ``values``."""
        self.operator.set_setup(with_setup(self.operator.scene, values), values.get("gain", self.operator.gain),
                                values.get(PSF))


class StackSetup:
    """A stack's shots through their cameras: gains per shot, the geometry shared (module docstring).

    Args:
        stack: The stacked operator, every shot an :class:`ImagingOperator`.
        base: The configured scene the shots' offsets are taken from.
    """

    def __init__(self, stack: StackOperator, base: Scene) -> None:
        self.stack = stack
        self.shots = [_camera(shot, f"shot {i}'s operator") for i, shot in enumerate(stack.shots)]
        self.base = base
        self.base_values = setup_values(base, 1.0)
        self.shot_values = [setup_values(shot.scene, 1.0) for shot in self.shots]
        self.geometry = {k: self.base_values[k] for k in GEOMETRY}

    def names(self, requested: Sequence[str]) -> list[str]:
        """``gain`` stands for every shot's gain."""
        out: list[str] = []
        for name in requested:
            out += [f"gain_{i}" for i in range(len(self.shots))] if name == "gain" else [name]
        return out

    @property
    def scene(self) -> Scene:
        """The configured scene as calibrated so far."""
        return with_setup(self.base, self.geometry)

    @property
    def pixel_size(self) -> float:
        """The receiver's pixel size (the first shot's), scene units."""
        return float(self.shots[0].inner.scene.receiver.pixel_size)

    def values(self) -> dict[str, float]:
        """Every parameter's current value: the shared geometry and blur, and each shot's gain."""
        return {**self.geometry, PSF: self.shots[0].psf_sigma,
                **{f"gain_{i}": shot.gain for i, shot in enumerate(self.shots)}}

    def _shot_scene(self, i: int, values: Mapping[str, float]) -> Scene:
        """Shot i's scene with the configured geometry moved to ``values`` (its offsets kept)."""
        moved = {k: self.shot_values[i][k] + values.get(k, self.geometry[k]) - self.base_values[k] for k in GEOMETRY}
        return with_setup(self.shots[i].scene, moved)

    def render(self, d: Tensor, values: Mapping[str, float] | None = None) -> Tensor:
        """The stacked G(d) (N c, n, n), float64, at the current values or at ``values``."""
        if values is None:
            return self.stack.render(d).double()
        images = [shot.render_with(self._shot_scene(i, values), values.get(f"gain_{i}", shot.gain), d,
                                   values.get(PSF)) for i, shot in enumerate(self.shots)]
        return self.stack.stack(images).double()

    def render_and_psf_column(self, d: Tensor) -> tuple[Tensor, Tensor]:
        """The stacked (G(d), dG/dpsf_sigma) (N c, n, n) each, float64: one render per shot."""
        pairs = [shot.render_and_sigma_derivative(d) for shot in self.shots]
        return (self.stack.stack([p[0] for p in pairs]).double(), self.stack.stack([p[1] for p in pairs]).double())

    def gain_column(self, image: Tensor, name: str, values: Mapping[str, float]) -> Tensor:
        """dG/d(gain_i): shot i's part of G over its gain, zero elsewhere."""
        i = int(name.split("_")[1])
        column = torch.zeros_like(image)
        c = self.stack.channels_per_shot
        column[i * c:(i + 1) * c] = image[i * c:(i + 1) * c] / values[name]
        return column

    def apply(self, values: Mapping[str, float]) -> None:
        """Move every shot to ``values``."""
        self.geometry.update({k: v for k, v in values.items() if k in GEOMETRY})
        for i, shot in enumerate(self.shots):
            shot.set_setup(self._shot_scene(i, self.geometry), values.get(f"gain_{i}", shot.gain), values.get(PSF))
