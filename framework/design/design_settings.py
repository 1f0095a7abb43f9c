"""sfc-design's run settings, read and checked once from the config before any render: the method
(config group ``design_method``), the time budget, the seed, the stopping factor, the checkpoint
cadence, the independent renders, the previews and the tracking target. The run reads these,
never the config (framework/design/design_run.py)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from framework.core.plugin_config import as_mapping, build_plugin, split_name
from framework.scene.run_settings import TrackingSettings
from operators.values import checked_number, checked_seed, checked_whole, is_number

__all__ = ["DesignMethod", "DesignSettings", "STARTS"]

STARTS = ("transport", "flat")
METHOD_KEYS = ("name", "start", "solver", "transport_resolution", "transport_iterations", "transport", "max_iter")


@dataclass(frozen=True)
class DesignMethod:
    """The ``design_method`` group: its ``name``, its ``start`` (one of :data:`STARTS`), the
    ``solver`` group (a ``design`` plugin), the transport start's screen (``transport_resolution``
    pixels per side; None: the design's), outer iterations and settings, and the iteration cap."""

    name: str
    start: str
    solver: dict[str, Any]
    transport_resolution: int | None
    transport_iterations: int
    transport: dict[str, Any]
    max_iter: int

    @classmethod
    def read(cls, spec: Any) -> DesignMethod:
        """The group ``spec``, checked (the solver plugin built once to check its settings)."""
        method = as_mapping(spec or {}, "design_method")
        for key in ("name", "start", "solver"):
            if key not in method:
                raise ValueError(f"design_method.{key} is missing; choose one with design_method=sfc|schwartzburg|adam")
        unknown = sorted(set(method) - set(METHOD_KEYS))
        if unknown:
            raise ValueError(f"unknown key design_method.{unknown[0]}; design_method takes {', '.join(METHOD_KEYS)}")
        if method["start"] not in STARTS:
            raise ValueError(f"design_method.start={method['start']!r} must be one of {', '.join(STARTS)}")
        solver = dict(as_mapping(method["solver"], "design_method.solver"))
        name, params = split_name(solver, "design_method.solver")
        build_plugin("design", name, params, "design_method.solver")
        transport = dict(as_mapping(method.get("transport") or {}, "design_method.transport"))
        coarse = method.get("transport_resolution")
        return cls(str(method["name"]), str(method["start"]), solver,
                   None if coarse is None else checked_whole(coarse, "design_method.transport_resolution", 2),
                   checked_whole(method.get("transport_iterations", 3), "design_method.transport_iterations", 1),
                   transport, checked_whole(method.get("max_iter", 100000), "design_method.max_iter", 0))


@dataclass(frozen=True)
class DesignSettings:
    """What a design run reads of its config.

    Attributes:
        method: The method (:class:`DesignMethod`).
        seconds: The method's time budget (s), its start included.
        seed: The photon pattern; the independent renders use seed + 1000 and + 2000.
        model_noise_factor: The run stops once its discrepancy is within this factor of the
            operator's own render noise.
        checkpoint_every: Iterations between checkpoints.
        evaluation_photons: Aim points of the independent renders of the result (None: four times
            the design operator's photons).
        previews: Factors > 0 of the screen distance at which the caustic is also rendered.
        tracking: Where the run is logged (experiment ``caustic-design`` unless configured).
        params: The config as logged with the run.
    """

    method: DesignMethod
    seconds: float
    seed: int
    model_noise_factor: float
    checkpoint_every: int
    evaluation_photons: int | None
    previews: tuple[float, ...]
    tracking: TrackingSettings
    params: dict[str, Any]

    @classmethod
    def read(cls, cfg: Mapping[str, Any]) -> DesignSettings:
        """The settings of the plain config ``cfg``; a bad value fails here, naming its key."""
        factors = cfg.get("previews", [0.5, 2.0]) or []
        if not isinstance(factors, (list, tuple)) or not all(is_number(f) and f > 0 for f in factors):
            raise ValueError(f"previews={factors!r} must be a list of factors > 0 of the screen distance, "
                             "e.g. [0.5, 2.0]")
        photons = as_mapping(cfg.get("evaluation") or {}, "evaluation").get("photons")
        tracking = TrackingSettings.parse({"experiment": "caustic-design", "store_dir": "mlruns",
                                           **as_mapping(cfg.get("tracking") or {}, "tracking")})
        method = DesignMethod.read(cfg.get("design_method"))
        return cls(method,
                   checked_number(cfg.get("seconds"), "seconds", above=0.0,
                                  must="must be the design's time budget in seconds > 0", example="300"),
                   checked_seed(cfg.get("seed", 0)),
                   checked_number(cfg.get("model_noise_factor", 1.25), "model_noise_factor", above=0.0),
                   checked_whole(cfg.get("checkpoint_every", 10), "checkpoint_every", 1),
                   None if photons is None else checked_whole(photons, "evaluation.photons", 1),
                   tuple(float(f) for f in factors), tracking, dict(cfg))
