"""A caustic design's setup, read and checked from the config before any run opens: the target
scaled to the power that reaches the screen, the scene with the screen widened to flat glass's
shadow, the printing limits, the run's settings (framework/design/design_settings.py), the model's
own render noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from framework.core.data import ReconstructionData
from framework.design.print_constraints import DesignProblem, PrintConstraints
from framework.core.problem import HeightGrid, Problem
from framework.core.units import mm_per_unit, scene_length, scene_volume
from framework.design.design_screen import has_elements, lit_half_width
from framework.design.design_settings import DesignSettings
from framework.design.design_target import DesignTarget, load_target, paraxial_shadow, screen_reach
from framework.files.image_io import load_mask
from framework.scene.scene_config import SceneGroups
from operators.image_operator import ImageOperator
from operators.scene import Scene
from operators.values import checked_whole

__all__ = ["DesignSetup", "prepare_design"]

POWER_TOLERANCE = 0.01  # an absolute target within 1% of the power that reaches the screen is taken as is


@dataclass
class DesignSetup:
    """Everything a design run needs, checked before any run opens.

    Attributes:
        scene: The scene, its receiver the target's square on the screen.
        operator: The forward operator of the design (the configured plugin).
        target: The target image (1, n, n) scaled to the power that reaches the screen (W per scene unit^2).
        source: Where the target came from.
        constraints: The printing limits.
        grid: The height grid.
        notes: What the setup changed and why (e.g. an energy normalisation), one line each.
        model_noise: The relative discrepancy that the operator's own render noise explains: two
            renders of flat glass with photon seeds seed and seed + 1 differ by sqrt(2) times it.
        flat_discrepancy: ||F(0) - target|| / ||target||, flat glass's relative discrepancy.
        mesh_refine: Points per height spacing at which glass.stl/.obj sample the surface.
        settings: The run's settings.
        groups: The scene groups the scene and the operator were built from (the previews'
            operators on other screens).
    """

    scene: Scene
    operator: Any
    target: torch.Tensor
    source: str
    constraints: PrintConstraints
    grid: HeightGrid
    notes: list[str]
    model_noise: float
    flat_discrepancy: float
    settings: DesignSettings
    groups: SceneGroups
    mesh_refine: int = 1

    @property
    def mm(self) -> float:
        """Millimetres per scene unit."""
        return self.groups.mm_per_unit

    def operator_for(self, scene: Scene) -> ImageOperator:
        """The configured operator for ``scene`` (another screen, say)."""
        return self.groups.operator_for(scene)

    @property
    def problem(self) -> Problem:
        """The design as a :class:`Problem`; its noise level is the model's own render noise."""
        data = ReconstructionData(target=self.target, mask=torch.ones(self.grid.shape, dtype=torch.bool),
                                  volume=self.constraints.volume, delta=min(max(self.model_noise, 1e-9), 0.5),
                                  source=self.source)
        return DesignProblem(self.operator, data, self.grid, self.scene, self.constraints)


def _edge_unprinted(constraints: PrintConstraints) -> bool:
    """Whether the limits keep the top on the substrate along the whole edge of the square: the
    mask (``constraints.mask``, cut by ``constraints.edge_margin``) allows no sample there."""
    mask = constraints.mask
    return mask is not None and not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def _length(value: Any, mm: float, where: str) -> float | None:
    return None if value is None else scene_length(value, mm, where)


def _constraints(cfg: Mapping[str, Any], m: int, half_width: float, mm: float, base_dir: Path | None
                 ) -> PrintConstraints:
    spec = dict(cfg.get("constraints") or {})
    allowed = ("max_height", "max_slope", "min_feature", "volume", "mask", "edge_margin")
    unknown = [k for k in spec if k not in allowed]
    if unknown:
        raise ValueError(f"unknown key constraints.{unknown[0]}; allowed: {', '.join(allowed)}")
    mask = None
    if spec.get("mask") is not None:
        path = Path(str(spec["mask"])).expanduser()
        mask = load_mask(path if path.is_absolute() or base_dir is None else base_dir / path, m).numpy()
    margin = _length(spec.get("edge_margin"), mm, "constraints.edge_margin")
    if margin is not None and margin > 0.0:  # the top stays on the substrate within the margin of the square's edge
        s = np.linspace(-half_width, half_width, m)
        inner = np.abs(s) <= half_width - margin
        if not inner.any():
            raise ValueError(f"constraints.edge_margin={spec['edge_margin']!r} leaves no glass to print on (the "
                             f"square's half side is {half_width * mm:.3g} mm); give a smaller margin")
        band = inner[:, None] & inner[None, :]
        mask = band if mask is None else mask & band
    volume = spec.get("volume")
    constraints = PrintConstraints(
        max_height=_length(spec.get("max_height", "10 mm"), mm, "constraints.max_height"),
        max_slope=spec.get("max_slope", 0.5),
        min_feature=_length(spec.get("min_feature"), mm, "constraints.min_feature"),
        volume=None if volume is None else scene_volume(volume, mm, "constraints.volume"),
        mask=mask,
        spacing=2.0 * half_width / (m - 1),
    )
    constraints.check_grid(m)
    return constraints


def prepare_design(cfg: Mapping[str, Any], base_dir: Path | None = None) -> DesignSetup:
    """Read and check the target, the scene, the limits and the method's settings; render flat
    glass to scale the target to the power that reaches the screen."""
    mm = mm_per_unit(cfg)
    settings = DesignSettings.read(cfg)
    groups = SceneGroups.read(cfg, mm)
    spec = dict(cfg.get("target") or {})
    resolution = spec.get("resolution", 256)
    target = load_target(spec.get("image", "grace_hopper"), resolution, base_dir, spec.get("channel", "luminance"),
                         spec.get("text", "SfC"))
    scene = groups.scene()
    if scene.light.extended:
        raise ValueError(f"light.shape={scene.light.shape}: sfc-design designs for a point light (the light's "
                         "position); give light.shape=point (a flash's size blurs what the design casts)")
    if scene.receiver.resolution != resolution:
        raise ValueError(
            f"receiver.resolution={scene.receiver.resolution} differs from target.resolution={resolution}; "
            "set only target.resolution"
        )
    m = groups.resolution if "resolution" in groups.height_field else checked_whole(resolution, "target.resolution", 2)
    through_optics = has_elements(groups.operator_for(scene))
    shadow = (lit_half_width(groups.operator_for, scene, np.zeros((m, m)), settings.seed) if through_optics
              else paraxial_shadow(scene))
    width = _length(spec.get("width"), mm, "target.width")
    half = shadow if width is None else 0.5 * width
    if not half > 0:
        raise ValueError(f"target.width={spec.get('width')!r} must be a length > 0, e.g. '60 mm'")
    scene = replace(scene, receiver=replace(scene.receiver, half_width=half))
    grid = HeightGrid(m, scene.substrate.half_width, scene.substrate.thickness)
    constraints = _constraints(cfg, m, grid.half_width, mm, base_dir)
    if (cfg.get("substrate") or {}).get("edge_height") is None:  # every design the limits allow is lit to its edge
        raised = 0.0 if _edge_unprinted(constraints) else constraints.max_height
        scene = replace(scene, substrate=replace(scene.substrate, edge_height=raised))
    if not through_optics:  # through lenses the deflection's reach has no closed form: not checked
        _check_reach(target, scene, constraints.max_slope)
    image, scene = _padded_to_shadow(target.image, scene, shadow)
    operator = groups.operator_for(scene)
    zeros = torch.zeros(grid.shape, dtype=operator.dtype)
    flat = operator.render(zeros).detach().double()
    power = float(flat.sum())
    if not power > 0:
        raise ValueError("no light of flat glass reaches the screen; check light and receiver.z")
    notes = []
    if through_optics:
        notes.append("through the scene's optical elements the target's reach on the screen is not checked: light "
                     "the glass cannot send there shows as a misfit")
    if scene.receiver.resolution != resolution:
        notes.append(f"the screen is widened to {scene.receiver.resolution} x {scene.receiver.resolution} pixels "
                     f"({2 * scene.receiver.half_width * mm:.4g} mm) around the target to catch all the light "
                     "through the glass; outside the target it should be dark")
    ratio = float(image.sum()) / power
    if target.absolute and abs(ratio - 1.0) > POWER_TOLERANCE:
        notes.append(f"the target carries {ratio:.1%} of the power that reaches the screen through the glass; "
                     "scaled to it (a refractive design only moves light)")
    elif not target.absolute:
        notes.append("the target's brightness is relative: scaled to the power that reaches the screen through "
                     f"the glass ({power * operator.pixel_area:.4g} W)")
    image = image / ratio
    second = operator.variant(operator.photons, settings.seed + 1, scene.receiver.resolution)
    noise = float(torch.linalg.vector_norm(flat - second.render(zeros).double())) / (
        math.sqrt(2.0) * float(torch.linalg.vector_norm(image)))
    flat_discrepancy = float(torch.linalg.vector_norm(flat - image)) / float(torch.linalg.vector_norm(image))
    refine = checked_whole(cfg.get("mesh_refine", 1), "mesh_refine", 1, must="must be an integer >= 1 (points per "
                           "height spacing of the exported mesh's top)")
    return DesignSetup(scene, operator, image, target.source, constraints, grid, notes, noise, flat_discrepancy,
                       settings, groups, refine)


def _padded_to_shadow(image: np.ndarray, scene: Scene, shadow: float) -> tuple[torch.Tensor, Scene]:
    """The target (1, N, N) and the scene with the screen widened by whole pixels, black, until it
    holds flat glass's shadow: all the light through the glass then lands on it, and a design can
    gather all of it into a target smaller than the glass's shadow."""
    n, half = image.shape[0], scene.receiver.half_width
    pixel = 2.0 * half / n
    pad = max(0, math.ceil((shadow - half) / pixel - 1e-9))
    padded = np.pad(image, pad)
    receiver = replace(scene.receiver, resolution=n + 2 * pad, half_width=half + pad * pixel)
    return torch.from_numpy(padded)[None].double(), replace(scene, receiver=receiver)


def _check_reach(target: DesignTarget, scene: Scene, max_slope: float) -> None:
    """Refuse a target whose light lies beyond what the glass can light under the slope limit."""
    image, half = target.image, scene.receiver.half_width
    n = image.shape[0]
    lit = np.argwhere(image > 1e-3 * image.max())
    centres = (np.arange(n) + 0.5) / n * 2 * half - half
    extent = float(max(np.abs(centres[lit[:, 0]]).max(), np.abs(centres[lit[:, 1]]).max()))
    reach = screen_reach(scene, max_slope)
    if extent > reach:
        raise ValueError(f"the target's light reaches {extent:.3g} scene units from the axis but the glass can light "
                         f"only {reach:.3g} (flat glass's shadow plus the deflection of slope {max_slope:g}); lower "
                         "target.width, move the screen (receiver.z) or raise constraints.max_slope")
