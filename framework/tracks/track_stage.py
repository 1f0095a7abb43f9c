"""The run's stage for fitted tracks (a stage of the run: framework/core/contracts/stage.py): what
the run fitted, in one sentence, with the tracks written as tracks.json, and their defect report
(framework/tracks/track_report.py) unless ``defects.enabled=off``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from framework.core.contracts.stage import RunStage, SolvedRun, StageReport
from framework.core.progress import report
from framework.defects.defect_stage import DefectSettings
from framework.tracks.track_report import fitted_tracks, report_tracks, track_tolerances, tracks_verdict

__all__ = ["TrackStage"]


class TrackStage(RunStage):
    """Reports a run whose solver fitted tracks; nothing for any other run."""

    order = 20

    def __init__(self, defects: DefectSettings) -> None:
        self.defects = defects

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> TrackStage:
        return cls(DefectSettings.parse(cfg.get("defects")))

    def report(self, run: SolvedRun) -> StageReport:
        tracks = fitted_tracks(run.fitted)
        if tracks is None:
            return StageReport()
        lines = tracks_verdict(tracks[0], tracks[1], run.output_dir)
        for line in lines:
            print(f"verdict: {line}", flush=True)
        if self.defects.enabled == "off":
            return StageReport(lines=lines)
        report("reconstruction: the defects read from the tracks")
        found = report_tracks(run.problem, tracks[0], tracks[1], track_tolerances(self.defects), run.output_dir)
        return StageReport(found.metrics(), [*lines, *found.lines])
