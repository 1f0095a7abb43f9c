"""The run-level settings of a reconstruction, read once from the config at the edge.

``RunSettings.parse(cfg)`` turns the composed (Hydra) config into plain values: the plugins'
length settings in scene units (``with_scene_lengths``), the unit, the seed, the method, the
checkpoint cadence, the tracking target, the run's tags and what the pipeline needs to know of
the plugin groups (whether the configured height field is a design, Morozov's factor). The pipeline passes
these down instead of the raw config; each plugin group still goes
to its plugin, which checks its own keys.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from framework.core.plugin_config import as_mapping, with_scene_lengths
from framework.core.units import mm_per_unit
from operators.values import checked_number, checked_seed, checked_whole

__all__ = ["PhotonBudgetSettings", "RunSettings", "TrackingSettings", "carries_design", "design_given", "stack_shots"]


def stack_shots(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The shots of a ``data=stack`` config group, each with the keys of ``data.common`` it does
    not set itself (framework/stack/stack_data.py)."""
    common = data.get("common") or {}
    return [{**common, **shot} for shot in data.get("shots") or [] if isinstance(shot, Mapping)]


def design_given(cfg: Mapping[str, Any]) -> bool:
    """Whether the configured height field is the design of a measured print: the user gave a
    height-field file (``height_field.path``), or declared it the design with ``data.mask=design``
    or ``initial=design``. Synthetic data always have their ground truth; a stack
    (framework/stack/stack_data.py) counts when one of its shots does."""
    data = cfg.get("data") or {}
    if data.get("name") == "stack":
        data = next((shot for shot in stack_shots(data) if shot.get("source", "synthetic") == "synthetic"
                     or shot.get("mask") == "design"), {})
        data = {**data, "name": data.get("source", "synthetic")} if data else {}
    if data.get("name") == "synthetic":
        return True
    initial = cfg.get("initial") or {}
    return bool((cfg.get("height_field") or {}).get("path")) or data.get("mask") == "design" or (
        isinstance(initial, Mapping) and initial.get("name") == "design")


def carries_design(cfg: Mapping[str, Any]) -> bool:
    """Whether the run's data will carry the print's design: synthetic data of another print
    (data.printed; for a stack, on a synthetic shot), or measured data with a design
    (framework/scene/run_settings.py)."""
    data = cfg.get("data") or {}
    if data.get("name") == "stack":
        synthetic = [shot for shot in stack_shots(data) if shot.get("source", "synthetic") == "synthetic"]
        if synthetic:
            return any(bool(shot.get("printed")) for shot in synthetic)
    elif data.get("name") == "synthetic":
        return bool(data.get("printed"))
    return design_given(cfg)


@dataclass(frozen=True)
class TrackingSettings:
    """Where the run is logged: the run log plugin ``name`` (kind ``tracker``), the ``experiment``,
    the local store directory ``store_dir`` (relative to the launch directory) or the tracking
    server ``uri``."""

    experiment: str
    store_dir: str
    uri: str | None
    name: str = "mlflow"

    @classmethod
    def parse(cls, spec: Any) -> TrackingSettings:
        tracking = as_mapping(spec, "tracking")
        store_dir = tracking.get("store_dir")
        if not isinstance(store_dir, str) or not store_dir:
            raise ValueError(f"tracking.store_dir={store_dir!r} must be a directory name for the local MLflow store")
        return cls(str(tracking.get("experiment", "shape-from-caustics")), store_dir, tracking.get("uri"),
                   str(tracking.get("name", "mlflow")))


@dataclass(frozen=True)
class PhotonBudgetSettings:
    """``photon_budget`` (framework/reconstruction/photon_budget.py): ``start`` photons of the first
    iterations (None: the configured ``photons`` throughout), the ``noise_share`` of Morozov's
    allowance (tau_dis^2 - 1) delta^2 that the render noise may take, and ``photons_resolution``: the
    receiver resolution n the configured ``photons`` are meant for (a finer receiver may trace
    photons x (n / photons_resolution)^2 where the noise level needs them; None: at most
    ``photons`` at any n)."""

    start: int | None
    noise_share: float
    photons_resolution: int | None = None

    @classmethod
    def parse(cls, spec: Any) -> PhotonBudgetSettings:
        budget = as_mapping(spec or {}, "photon_budget")
        unknown = sorted(set(budget) - {"start", "noise_share", "photons_resolution"})
        if unknown:
            raise ValueError(f"photon_budget has unknown key(s) {unknown}; its keys are start, noise_share and "
                             "photons_resolution")
        resolution = budget.get("photons_resolution")
        if resolution is not None:
            resolution = checked_whole(resolution, "photon_budget.photons_resolution", least=1,
                                       must="must be a receiver resolution >= 1 (pixels per side) or null",
                                       example="128")
        start = budget.get("start")
        share = budget.get("noise_share", 0.5)
        share = checked_number(share, "photon_budget.noise_share", most=1.0, above=0.0, must="must lie in (0, 1]",
                               example="0.5")
        return cls(None if start is None else checked_whole(start, "photon_budget.start", least=1), share, resolution)


@dataclass(frozen=True)
class RunSettings:
    """A reconstruction's config, parsed once.

    Attributes:
        cfg: The plain config, plugin lengths in scene units: logged as the run's params and the
            source of each plugin's group.
        mm_per_unit: Millimetres per scene unit.
        seed: The run's seed (every random number derives from it).
        method: The method's name in logs and tags (``custom`` when unnamed).
        checkpoint_every: Iterations between checkpoints.
        compile_in_background: Whether the operator may warm up (compile) while the data load.
        resume: The checkpoint to resume from as configured (a path, ``auto`` or None).
        tracking: The tracking target.
        tags: The run's MLflow tags: method, scene, data, operator, solver.
        design_given: Whether the configured height field is the print's design (a deviation
            report is then made against it): synthetic data, ``height_field.path``,
            ``data.mask=design`` or ``initial=design``.
        tau_dis: Morozov's factor tau_dis (1 without a Morozov rule), for the verdict.
        photon_budget: The photons of each iteration (framework/reconstruction/photon_budget.py).
    """

    cfg: dict[str, Any]
    mm_per_unit: float
    seed: int
    method: str
    checkpoint_every: int
    compile_in_background: bool
    resume: Any
    tracking: TrackingSettings
    tags: dict[str, str]
    design_given: bool
    tau_dis: float
    photon_budget: PhotonBudgetSettings

    @classmethod
    def parse(cls, cfg: Mapping[str, Any]) -> RunSettings:
        """The settings of ``cfg`` (a DictConfig or a mapping), every run-level value checked."""
        plain = dict(cfg)
        mm = mm_per_unit(plain)
        plain = with_scene_lengths(plain, mm)
        data = plain.get("data") or {}
        stopping = plain.get("stopping") or {}
        morozov = stopping.get("morozov") if isinstance(stopping, Mapping) else None
        morozov = morozov if isinstance(morozov, Mapping) else {}  # a bad group fails where it is built
        method = plain.get("method", "custom")
        tags = {"method": method, "scene": (plain.get("height_field") or {}).get("shape", "file"),
                "data": data.get("name"), "operator": (plain.get("operator") or {}).get("name"),
                "solver": (plain.get("solver") or {}).get("name")}
        seed = checked_seed(plain.get("seed", 0))
        return cls(plain, mm, seed, method,
                   checked_whole(plain.get("checkpoint_every"), "checkpoint_every", least=1),
                   bool(plain.get("compile_in_background", True)), plain.get("resume"),
                   TrackingSettings.parse(plain.get("tracking")), tags, design_given(plain),
                   checked_number(morozov.get("tau_dis", 1.0), "stopping.morozov.tau_dis", above=0.0),
                   PhotonBudgetSettings.parse(plain.get("photon_budget")))
