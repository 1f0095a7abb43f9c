"""The parts of one reconstruction, each built by its registry key from the config and checked
before anything is rendered: the scene and operator, the data source, the solver's builder, the
stopping rules, the start, the calibration of the setup, the run's log and its stages.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from framework.core.contracts.calibration import SetupCalibration
from framework.core.contracts.data_source import DataRequest, DataSource, ShotStack
from operators.image_operator import ImageOperator
from framework.core.contracts.run_log import RunLog
from framework.core.contracts.solver import SolverBuilder
from framework.core.contracts.stage import RunStage
from framework.core.contracts.start import Start
from framework.core.contracts.stopping import StoppingRule
from framework.core.plugin_config import as_mapping, build_plugin, plugin_class, split_name
from framework.core.registry import available
from framework.core.problem import HeightGrid, Problem
from framework.files.image_io import resolve_path
from framework.reconstruction.coarse_to_fine import CoarseToFineSettings
from framework.reconstruction.run_checks import (check_volume, check_volume_known, checked_resume,
                                                 height_bounds, volume_needed_by)
from framework.reconstruction.run_identity import run_fingerprint
from framework.scene.run_settings import RunSettings, carries_design
from framework.scene.scene_config import SceneSetup
from operators.scene import Scene
from operators.values import checked_whole
from regularizers import PostStepUpdate

__all__ = ["Reconstruction", "build_stages", "build_start", "build_stopping"]


def build_start(spec: Any) -> Start:
    """The ``initial`` plugin (framework/reconstruction/starts/) of the config group ``spec``, checked:
    ``{name: zero | design | file | transport | auto, ...}`` (None: zero)."""
    spec = spec or {"name": "zero"}
    if isinstance(spec, str):
        raise ValueError(f"initial={spec!r}: choose a start by name (initial=zero|design|file|transport|auto); "
                         "a height-field file is initial=file initial.path=<file>")
    name, params = split_name(spec, "initial")
    return build_plugin("initial", name, params, "initial")


def build_stopping(groups: Mapping[str, Any]) -> list[StoppingRule]:
    """The plugins of the ``stopping`` groups (name -> settings), in config order (fresh ones for
    every run from a start)."""
    return [build_plugin("stopping", name, params, f"stopping.{name}") for name, params in groups.items()]


@dataclass
class Reconstruction:
    """Everything a reconstruction is built from, checked against the config before any render.

    Attributes:
        settings: The config, parsed once (framework/scene/run_settings.py).
        setup: The scene, height grid, operator and the scene groups they were built from
            (framework/scene/scene_config.py).
        data_source: The ``data`` plugin.
        make_solver: The solver plugin's builder: (problem, d0) -> solver.
        stopping: The ``stopping`` groups (name -> settings), in config order: each run from a
            start builds its rules afresh.
        height_bounds: The bounds (p1, p2) the solver's plugins impose on the heights (scene units).
        volume_needed_by: The solver's plugins that need the deposited volume (config keys).
        start: The ``initial`` plugin: computes the start d0 (m, m) once the data are loaded.
        max_iter: The solver's iteration cap.
        fingerprint: What determines the result (framework/reconstruction/run_identity.py), stored in checkpoints.
        run_log: The class of the run's log (``tracking.name``, framework/core/contracts/run_log.py).
        calibration: The calibration of the setup (``calibration.name``, framework/core/contracts/calibration.py),
            or None.
        stages: The run's stages after the solve (framework/core/contracts/stage.py), in order.
        coarse_to_fine: The coarser grids each start is solved on first
            (framework/reconstruction/coarse_to_fine.py).
    """

    settings: RunSettings
    setup: SceneSetup
    data_source: DataSource
    make_solver: SolverBuilder
    stopping: dict[str, Any]
    height_bounds: tuple[float, float | None]
    volume_needed_by: list[str]
    start: Start
    max_iter: int
    fingerprint: dict[str, str]
    run_log: type[RunLog]
    calibration: SetupCalibration | None = None
    stages: list[RunStage] = field(default_factory=list)
    coarse_to_fine: CoarseToFineSettings = field(default_factory=CoarseToFineSettings)
    _designs: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)

    @property
    def operator(self) -> ImageOperator:
        """The forward-operator plugin."""
        return self.setup.operator

    @property
    def scene(self) -> Scene:
        """The scene (light, substrate, receiver, material, wavelengths)."""
        return self.setup.scene

    @property
    def grid(self) -> HeightGrid:
        """The height grid."""
        return self.setup.grid

    def fresh_stopping(self, problem: Problem | None = None) -> list[StoppingRule]:
        """The configured stopping rules built afresh (each run from a start keeps its own best
        iterate), set up for ``problem`` if one is given."""
        stopping = build_stopping(self.stopping)
        if problem is not None:
            for rule in stopping:
                rule.setup(problem)
        return stopping

    def design(self, base_dir: Path) -> torch.Tensor:
        """The configured height field (m, m), float64, scene units: read or generated once per
        ``base_dir``, a copy handed out each time."""
        key = str(base_dir)
        if key not in self._designs:
            self._designs[key] = self.setup.heights(base_dir)
        return self._designs[key].clone()

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], base_dir: Path) -> Reconstruction:
        """Build every part by its registry key (scene, operator, data, solver, stopping rules) and
        the start; a bad value fails here, before anything is rendered."""
        settings = RunSettings.parse(cfg)
        cfg = settings.cfg
        calibration_cfg = as_mapping(cfg.get("calibration") or {}, "calibration")
        calibrated_by = plugin_class("calibration", str(calibration_cfg.pop("name", "joint")), SetupCalibration)
        data_name, data_params = split_name(cfg.get("data"), "data")
        data_source = build_plugin("data", data_name, data_params, "data")
        setup = SceneSetup.parse(cfg, settings.mm_per_unit, imaging=bool(calibration_cfg.get("params")),
                                 shots=data_source.setups if isinstance(data_source, ShotStack) else None)
        post_steps = dict(as_mapping(cfg.get("solver") or {}, "solver").get("post_steps") or {})
        volume_held = any(plugin_class("post_step", name, PostStepUpdate).holds_volume for name in post_steps)
        calibration = calibrated_by.from_config(setup.operator, calibration_cfg, setup.scene, setup.screen_sigma,
                                                volume_held)
        solver_name, solver_params = split_name(cfg.get("solver"), "solver")
        # the loop's cap, not the solver's
        max_iter = checked_whole(solver_params.pop("max_iter", None), "solver.max_iter", least=1)
        make_solver = build_plugin("solver", solver_name, solver_params, "solver")
        stopping = as_mapping(cfg.get("stopping"), "stopping")
        build_stopping(stopping)  # each rule's settings checked here, before anything is rendered
        start = build_start(cfg.get("initial"))
        start.check(base_dir)
        coarse_to_fine = CoarseToFineSettings.parse(cfg.get("coarse_to_fine"))
        if isinstance(data_source, ShotStack) and coarse_to_fine.resolutions(
                setup.grid.resolution, int(setup.operator.output_shape[-1])):
            raise ValueError(f"coarse_to_fine.levels={coarse_to_fine.levels} reads one photo; a stack of shots "
                             "runs on its own grid: set coarse_to_fine.levels=1")
        regularizers = (cfg.get("solver") or {}).get("regularizers") or {}
        if "l1_design" in regularizers and not carries_design(cfg):
            raise ValueError("solver.regularizers.l1_design (experiment=design) needs the print's design: give "
                             "height_field.path (the design) with data=file or data=photo, or data.printed (the print) "
                             "with synthetic data")
        stages = build_stages(cfg)
        if start.reads_design and len(start.phases()) == 1 and not carries_design(cfg):
            raise ValueError(f"initial={start.name} reads the print's design, and synthetic data of the configured "
                             "height field carry none (those heights are the answer): give data.printed=<print> "
                             "(the configured field is then its design), or choose initial=transport, zero or file")
        solver = cfg.get("solver") or {}
        return cls(settings, setup, data_source, make_solver, stopping, height_bounds(solver),
                   volume_needed_by(solver), start, max_iter,
                   run_fingerprint(cfg, base_dir), plugin_class("tracker", settings.tracking.name, RunLog),
                   calibration, stages, coarse_to_fine)

    def check(self, base_dir: Path, output_dir: Path) -> Path | None:
        """Everything a run needs that the plugins' configs alone do not show, checked without a
        render, before the tracker opens: the tracking target, the data's files and what they say
        of the print (the volume against the printed area and the height bounds), the design of a
        measured print, and the checkpoint to resume from (readable, of this run). Returns that
        checkpoint, or None for a fresh run."""
        tracking = self.settings.tracking
        self.run_log.check_target(tracking.uri, resolve_path(tracking.store_dir, base_dir))
        request = self.data_request(base_dir)
        facts = self.data_source.check(request)
        check_volume_known(self.volume_needed_by, facts)
        check_volume(facts.volume, facts.mask, self.grid.cell_area, self.height_bounds,
                     2.0 * float(self.scene.substrate.half_width))
        if self.settings.design_given:
            request.configured_heights()
        return checked_resume(self.settings.resume, output_dir, base_dir, self.fingerprint)

    def data_request(self, base_dir: Path, output_dir: Path | None = None) -> DataRequest:
        """What the data source may use: the operator, the grid, the configured heights, the seed,
        the run directory and the units."""
        return DataRequest(self.operator, self.grid, lambda: self.design(base_dir),
                           self.settings.seed, base_dir, output_dir, self.settings.mm_per_unit)


def build_stages(cfg: Mapping[str, Any]) -> list[RunStage]:
    """Every installed stage (kind ``stage``) that has something to do in a run of ``cfg``, by order."""
    built = [plugin_class("stage", name, RunStage).from_config(cfg) for name in available("stage")]
    return sorted((stage for stage in built if stage is not None), key=lambda stage: stage.order)
