"""Build the scene, the heights, their grid and the forward operator from a plain config (the
commands turn Hydra's into one at their edge, experiments/apps/configs.py).

Config layout (top-level keys; see conf/scene/*.yaml and conf/operator/*.yaml)::

    light:        {position: [x, y, z], power: W, shape: point | disc | square, size: a, points: K}
    substrate:    {thickness: h, half_width: W}
    receiver:     {z: s, resolution: n, half_width: W}
    material:     {kind: fused_silica | sellmeier | cauchy | constant, ...coefficients}
    wavelengths:  [um, ...]                       # one image channel each
    height_field: {shape, resolution, path, scale, params}
    photons: N
    seed: int
    operator:     {name: <operator plugin>, ...its own settings}
    screen:       {psf: none | gaussian, sigma: s}  # the screen's blur (operators/imaging.py)
                                                    # (sigma: also where calibrating psf_sigma starts)
    units:        {mm_per_unit: 25.0}               # framework/core/units.py

Lengths are in scene units, or strings with a unit such as "2.5 mm" (framework/core/units.py). Groups
may omit keys (dataclass defaults apply); unknown keys in a group are refused with an error
naming the key. The operator plugin checks its own settings.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from operators.image_operator import ImageOperator
from framework.core.plugin_config import build_plugin, split_name
from framework.core.problem import HeightGrid
from framework.core.shots import ShotSetup
from framework.core.units import mm_per_unit, scene_length
from framework.files.height_field_io import load_height_field
from framework.scene.design_mesh import MESH_SUFFIXES, heights_from_mesh
from framework.scene.printed_shapes import make_shape
from operators.imaging import PSF_KINDS, ImagingOperator
from operators.scene import Scene, Substrate, scene_from_groups
from operators.stack import StackOperator
from operators.values import checked_seed, checked_whole

__all__ = [
    "SceneSetup",
    "build_scene",
    "build_heights",
    "build_operator",
    "heights_from_spec",
    "height_grid",
    "screen_sigma",
    "SceneGroups",
]

SCENE_KEYS: dict[str, tuple[str, ...]] = {
    "light": ("position", "power", "shape", "size", "points"),
    "substrate": ("thickness", "half_width", "walls", "edge_height"),
    "receiver": ("z", "resolution", "half_width"),
}
SCREEN_KEYS = ("psf", "sigma")
HEIGHT_FIELD_KEYS = ("shape", "resolution", "path", "scale", "params")
DEFAULT_RESOLUTION = 128


def _group(cfg: Mapping[str, Any], name: str, allowed: tuple[str, ...]) -> dict[str, Any]:
    """The mapping ``cfg[name]`` (empty if absent) with its keys checked against ``allowed``."""
    value = cfg.get(name)
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{name}={value!r} must be a mapping with keys {', '.join(allowed)}")
    for key in value:
        if key not in allowed:
            raise ValueError(f"unknown key {name}.{key}; allowed keys of {name}: {', '.join(allowed) or 'none'}")
    return dict(value)


MAX_RESOLUTION = 8192  # height samples per side: 8192^2 float64 is 0.5 GB per copy


@dataclass(frozen=True)
class SceneGroups:
    """The scene's config groups, read and checked once, before anything is built.

    Attributes:
        light, substrate, receiver: Their groups (keys checked; lengths converted where the
            scene is built, operators/scene.py).
        material: A name or a dispersion (operators/materials.py); None: fused silica.
        wavelengths: The wavelengths (um) as configured.
        height_field: The ``height_field`` group, keys checked.
        resolution: ``height_field.resolution`` m, in [2, MAX_RESOLUTION].
        psf: ``screen.psf``. screen_sigma: ``screen.sigma`` in scene units, whatever the psf.
        operator: The ``operator`` group: the plugin's name and its own settings, which the
            plugin checks, as it checks ``photons`` (photons per render).
        seed: The operator's seed.
        mm_per_unit: Millimetres per scene unit.
    """

    light: dict[str, Any]
    substrate: dict[str, Any]
    receiver: dict[str, Any]
    material: Any
    wavelengths: Any
    height_field: dict[str, Any]
    resolution: int
    psf: str
    screen_sigma: float
    operator: Any
    photons: Any
    seed: int
    mm_per_unit: float

    @classmethod
    def read(cls, cfg: Mapping[str, Any], mm: float | None = None) -> SceneGroups:
        """The groups of ``cfg`` with ``mm`` millimetres per scene unit (None: ``units.mm_per_unit``);
        a bad key or value fails here, naming it."""
        groups = {name: _group(cfg, name, keys) for name, keys in SCENE_KEYS.items()}
        height_field = _group(cfg, "height_field", HEIGHT_FIELD_KEYS)
        screen = _group(cfg, "screen", SCREEN_KEYS)
        psf = screen.get("psf", "none")
        if psf not in PSF_KINDS:
            raise ValueError(f"screen.psf={psf!r}; use {' or '.join(PSF_KINDS)}")
        mm = mm_per_unit(cfg) if mm is None else mm
        sigma = scene_length(screen.get("sigma", 0.0), mm, "screen.sigma")
        resolution = checked_whole(height_field.get("resolution", DEFAULT_RESOLUTION), "height_field.resolution",
                                   2, MAX_RESOLUTION, must=f"must lie in [2, {MAX_RESOLUTION}] (samples per side; "
                                   "128 is the default)")
        seed = checked_seed(cfg.get("seed", 0))
        return cls(groups["light"], groups["substrate"], groups["receiver"], cfg.get("material") or None,
                   cfg.get("wavelengths", [0.633]), height_field, resolution, psf, sigma, cfg.get("operator"),
                   cfg.get("photons"), seed, mm)

    @property
    def psf_sigma(self) -> float:
        """The screen's Gaussian spot (standard deviation, scene units); 0 for none."""
        if self.psf == "gaussian" and not (math.isfinite(self.screen_sigma) and self.screen_sigma > 0.0):
            raise ValueError("screen.psf=gaussian needs a finite screen.sigma > 0 (scene units or e.g. '0.1 mm'), "
                             f"got {self.screen_sigma}")
        return self.screen_sigma if self.psf == "gaussian" else 0.0

    def scene(self) -> Scene:
        """Light, substrate, receiver, material and wavelengths (operators/scene.py)."""
        return scene_from_groups(self.light, self.substrate, self.receiver, self.material, self.wavelengths,
                                 self.mm_per_unit)

    def grid(self, scene: Scene) -> HeightGrid:
        """The grid of the reconstructed heights: ``resolution`` samples over the substrate."""
        return HeightGrid(self.resolution, scene.substrate.half_width, scene.substrate.thickness)

    def operator_for(self, scene: Scene, imaging: bool = False, gain: float = 1.0) -> ImageOperator:
        """The operator plugin for ``scene``, seen through the screen (operators/imaging.py) when
        ``screen.psf`` is set, or always with ``imaging`` (a setup that joint calibration may
        change) or a ``gain`` other than 1."""
        sigma = self.psf_sigma
        name, params = split_name(self.operator, "operator")

        def build(for_scene: Scene) -> ImageOperator:
            return build_plugin("operator", name, dict(params), "operator", scene=for_scene, photons=self.photons,
                                seed=self.seed)

        if sigma > 0.0 or imaging or gain != 1.0:
            return ImagingOperator(build, scene, psf_sigma=sigma, gain=gain)
        return build(scene)

    def stack_for(self, scene: Scene, shots: Sequence[ShotSetup], imaging: bool = False) -> StackOperator:
        """The stacked operator (operators/stack.py) of the shots' setups (framework/stack/stack_data.py)
        around ``scene``, each shot's operator as :meth:`operator_for` builds it."""
        operators = [self.operator_for(shot.scene(scene, f"data.shots[{i}]"), imaging, shot.gain)
                     for i, shot in enumerate(shots)]
        return StackOperator(operators, [shot.weight for shot in shots])

    def heights(self, base_dir: str | Path | None = None, substrate: Substrate | None = None) -> torch.Tensor:
        """The configured heights (m, m), float64, scene units (:func:`build_heights`); a glass mesh
        is read over ``substrate`` (None: the configured one)."""
        path = self.height_field.get("path")
        mesh = isinstance(path, str) and Path(path).suffix.lower() in MESH_SUFFIXES
        if mesh and substrate is None:
            substrate = self.scene().substrate
        return heights_from_spec(self.height_field, self.resolution, self.mm_per_unit, base_dir, substrate)


def build_scene(cfg: Mapping[str, Any], mm: float | None = None) -> Scene:
    """Scene (light, substrate, receiver, material, wavelengths in um) from the config's top-level
    keys; lengths in scene units or with a unit (framework/core/units.py), ``mm`` millimetres per
    scene unit (None: the config's ``units.mm_per_unit``)."""
    return SceneGroups.read(cfg, mm).scene()


def build_heights(cfg: Mapping[str, Any], base_dir: str | Path | None = None) -> torch.Tensor:
    """Heights d (m, m), float64, scene units, from ``height_field``.

    ``path`` (a .npy or 8/16-bit .png/.tif, resolved against ``base_dir`` when relative) overrides
    ``shape``; ``resolution`` m defaults to 128; ``scale`` multiplies the heights (for images:
    the height of full white, in scene units or e.g. "0.4 mm"); ``params`` go to the shape function.
    """
    return SceneGroups.read(cfg).heights(base_dir)


def heights_from_spec(spec: Mapping[str, Any], resolution: int, mm: float, base_dir: str | Path | None = None,
                      substrate: Substrate | None = None) -> torch.Tensor:
    """:func:`build_heights` of the checked ``height_field`` group ``spec`` at ``resolution`` with
    ``mm`` millimetres per scene unit; a glass mesh (.stl/.obj/.ply, framework/scene/design_mesh.py)
    is read over ``substrate``."""
    scale = scene_length(spec.get("scale", 1.0), mm, "height_field.scale")
    path = spec.get("path")
    if path is not None and not isinstance(path, str):
        raise ValueError(f"height_field.path={path!r} must be a file name (.npy/.png/.tif/.stl/.obj/.ply) or null")
    if path:
        path = Path(path)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if path.suffix.lower() in MESH_SUFFIXES:
            substrate = substrate or Substrate()
            heights = heights_from_mesh(path, resolution, substrate.half_width, substrate.thickness, mm) * scale
        else:
            heights = load_height_field(path, resolution=resolution, scale=scale)
    else:
        shape = spec.get("shape")
        if not shape:
            raise ValueError("height_field needs a shape (e.g. height_field.shape=print_lines) or a path")
        params = spec.get("params") or {}
        if not isinstance(params, Mapping):
            raise ValueError(f"height_field.params={params!r} must be a mapping of shape parameters")
        if not scale >= 0.0:
            raise ValueError(f"height_field.scale={scale} must be >= 0, e.g. 1.0")
        heights = scale * make_shape(str(shape), resolution, **dict(params))
    return torch.from_numpy(np.ascontiguousarray(heights, dtype=np.float64))


def height_grid(cfg: Mapping[str, Any], scene: Scene) -> HeightGrid:
    """The grid of the reconstructed heights: ``height_field.resolution`` samples over the substrate."""
    return SceneGroups.read(cfg).grid(scene)


def screen_sigma(cfg: Mapping[str, Any], mm: float | None = None) -> float:
    """The screen's Gaussian spot (standard deviation, scene units) from ``screen``; 0 for none."""
    return SceneGroups.read(cfg, mm).psf_sigma


def build_operator(cfg: Mapping[str, Any], scene: Scene, imaging: bool = False, mm: float | None = None,
                   gain: float = 1.0) -> ImageOperator:
    """The operator plugin of ``cfg`` for ``scene`` (:meth:`SceneGroups.operator_for`)."""
    return SceneGroups.read(cfg, mm).operator_for(scene, imaging, gain)


@dataclass(frozen=True)
class SceneSetup:
    """The scene groups of a reconstruction's config, read once: the scene, the height grid, the
    forward operator, and the ``height_field`` group the configured heights are made from.

    Attributes:
        scene: Light, substrate, receiver, material, wavelengths.
        grid: The grid of the reconstructed heights.
        operator: The operator plugin (seen through the screen when ``screen.psf`` is set, or with
            ``imaging``).
        groups: The scene groups it was built from.
    """

    scene: Scene
    grid: HeightGrid
    operator: ImageOperator
    groups: SceneGroups

    @classmethod
    def parse(cls, cfg: Mapping[str, Any], mm: float, imaging: bool = False,
              shots: Callable[[Scene, float], Sequence[ShotSetup]] | None = None) -> SceneSetup:
        """Read the scene groups of ``cfg`` (:class:`SceneGroups`) with ``mm`` millimetres per scene
        unit, then build the scene, grid and operator; with ``shots`` (a stack's setups for the
        configured scene and ``mm``), the stacked operator."""
        groups = SceneGroups.read(cfg, mm)
        scene = groups.scene()
        operator = (groups.operator_for(scene, imaging) if shots is None
                    else groups.stack_for(scene, shots(scene, mm), imaging))
        return cls(scene, groups.grid(scene), operator, groups)

    @property
    def mm_per_unit(self) -> float:
        """Millimetres per scene unit."""
        return self.groups.mm_per_unit

    @property
    def screen_sigma(self) -> float:
        """``screen.sigma`` in scene units, whatever ``screen.psf`` (where joint calibration of the
        blur's width starts, framework/lab/calibration.py)."""
        return self.groups.screen_sigma

    def heights(self, base_dir: str | Path | None = None) -> torch.Tensor:
        """The configured heights (m, m), float64, scene units (:func:`build_heights`)."""
        return self.groups.heights(base_dir, self.scene.substrate)
