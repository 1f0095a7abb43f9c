"""The ``calibration`` config group read and checked for the joint calibration of the setup
(framework/lab/calibration.py): which parameters, how often, the damping, the prior, where the
screen blur's width starts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from framework.core.units import scene_length
from framework.lab.calibrated_setup import PSF
from operators.values import checked_number

__all__ = ["calibration_settings"]


def calibration_settings(settings: Mapping[str, Any], operator: Any, scene: Any = None,
                         screen_sigma: float = 0.0) -> dict[str, Any] | None:
    """The keyword arguments of :class:`framework.lab.calibration.JointCalibration` from the config
    group ``calibration`` (keys params, every, damping, prior, psf_sigma_start), checked, or None
    when ``params`` is empty; ``scene``: the configured scene (its mm per scene unit, else the
    operator's); ``screen_sigma``: the configured ``screen.sigma`` (scene units), where
    ``psf_sigma`` starts unless ``psf_sigma_start`` is given (0: one receiver pixel)."""
    keys = ("params", "every", "damping", "prior", "psf_sigma_start")
    unknown = [k for k in settings if k not in keys]
    if unknown:
        raise ValueError(f"unknown key calibration.{unknown[0]}; calibration takes {', '.join(keys)}")
    params = settings.get("params") or []
    if isinstance(params, str):
        params = [params]
    if not isinstance(params, (list, tuple)) or not all(isinstance(p, str) for p in params):
        raise ValueError(f"calibration.params={settings.get('params')!r} must be a list of names, e.g. "
                         "[gain, screen_distance], or [] for none")
    if not params:
        return None
    start = settings.get("psf_sigma_start")
    if start is not None and PSF not in params:
        raise ValueError(f"calibration.psf_sigma_start={start!r} is set but calibration.params={list(params)!r} "
                         f"lacks {PSF}: add it, or drop the start")
    if PSF in params:
        if start is not None:
            mm = scene.mm_per_unit if scene is not None else operator.scene.mm_per_unit
            given, start = start, scene_length(start, mm, "calibration.psf_sigma_start")
            if not (math.isfinite(start) and start > 0.0):  # scene_length gives a float: only its value is checked
                raise ValueError(f"calibration.psf_sigma_start={given!r} must be a length > 0 (scene units or "
                                 "e.g. '0.1 mm'), or null to start from screen.sigma")
        else:
            sigma = checked_number(screen_sigma, "screen.sigma", 0.0, must="cannot start calibration.params' "
                                   "psf_sigma: give a length >= 0 (scene units or e.g. '0.1 mm'; 0: one receiver "
                                   "pixel), or calibration.psf_sigma_start")
            if sigma > 0.0:
                start = sigma
    return {"params": list(params), "every": settings.get("every", 30), "damping": settings.get("damping", 1e-3),
            "prior": settings.get("prior", 0.1), "psf_sigma_start": start}

