"""The start chosen by the data (plugin ``initial/auto``): the candidate starts are tried in
order, each run to its end by the run's own solver and stopping rules; the first run that
reaches the noise level (stopped by Morozov's rule) is kept, else the one that ended with the
lowest relative discrepancy (docs/method.md, "The start").

With ``zero`` first, a print whose caustic flat glass can explain is reconstructed exactly as
from flat glass, at the same cost; only a run that ends short of the noise level (the fit stalled
in the wrong basin) is followed by the next start."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.core.plugin_config import as_mapping, build_plugin

__all__ = ["AutoStart"]


class AutoStart(Start):
    """Starts tried in order until one reaches the noise level. Plugin ``initial/auto``.

    Args:
        candidates: ``{start name: {its config}}`` in the order they are tried (e.g. ``{zero: {},
            transport: {}}``); not ``auto`` itself.

    The reconstruction (framework/reconstruction/reconstruction.py) runs the solver from each of :meth:`phases`
    in turn. A candidate that cannot be computed from the data (a ValueError, e.g. no light within
    the mask's reach) is reported and skipped.
    """

    name = "auto"

    def __init__(self, candidates: Mapping[str, Any] | None = None) -> None:
        specs = as_mapping(candidates, "initial.candidates")
        if not specs:
            raise ValueError("initial.candidates is empty; give at least one start, e.g. {zero: {}, transport: {}}")
        if "auto" in specs:
            raise ValueError("initial.candidates may not contain auto itself")
        self.candidates: list[tuple[str, Any]] = [
            (name, build_plugin("initial", name, params, f"initial.candidates.{name}"))
            for name, params in specs.items()
        ]

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py): conf/initial/auto.yaml's."""
        return {"candidates": {"zero": {}, "transport": {}}}

    def phases(self) -> list[tuple[str, Any]]:
        """(name, start) of every candidate, in the order they are tried."""
        return list(self.candidates)

    def check(self, base_dir: Path) -> None:
        """Each candidate's own check (e.g. a start file exists)."""
        for _, start in self.candidates:
            start.check(base_dir)

    def __call__(self, request: StartRequest) -> StartResult:
        """The first candidate's start (a caller that does not run the phases gets that one)."""
        return self.candidates[0][1](request)
