"""Which beads the photos leave undecided (framework/tracks/ambiguity.py, framework/tracks/twins.py):
ridges side by side found with their distance and midline, the bead between them built with
their glass, and the verdict's three outcomes and advised screen from known discrepancies and
images."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from framework.tracks.ambiguity_stage import AmbiguitySettings
from framework.tracks.ambiguity import APART, BEAD_WIDTHS, SCREENED, bead_between, undecided_beads
from framework.tracks.from_design import skeleton_tracks
from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.tracks.track_set import Track, TrackSet
from framework.tracks.twins import twin_pairs

MM = 25.0  # mm per scene unit; the grid spans [-25, 25] mm
M = 128


def _line(y: float, height: float, width: float, x0: float = -12.0, x1: float = 12.0) -> Track:
    return Track(f"y={y}", np.array([[x0, y], [x1, y]]), np.array([height]), np.array([width]), np.array([0.0]))


def _drawn(*tracks: Track) -> np.ndarray:
    rep = TrackHeights(TrackSet(tracks), M, 1.0, MM, TrackSettings(residual_mm=0.0))
    return rep.heights(rep.initial()).numpy()


def test_two_ridges_side_by_side_are_twins_with_their_distance_and_midline() -> None:
    pairs = twin_pairs(TrackSet((_line(3.0, 0.3, 2.0), _line(8.0, 0.3, 2.0), _line(-15.0, 0.3, 2.0),
                                 Track("across", np.array([[15.0, -20.0], [15.0, 20.0]]), np.array([0.3]),
                                       np.array([2.0]), np.array([0.0])))))
    assert [(p.first, p.second) for p in pairs] == [(0, 1)]  # 18 mm apart is too far, a crossing line never
    pair = pairs[0]
    assert pair.separation_mm == pytest.approx(5.0, abs=1e-6)
    assert np.allclose(pair.midline[:, 1], 5.5)
    assert pair.midline[:, 0].min() == pytest.approx(-14.5, abs=0.3)  # carried on by half the distance
    assert pair.midline[:, 0].max() == pytest.approx(14.5, abs=0.3)


def test_twins_are_found_in_the_skeleton_of_drawn_ridges() -> None:
    d = _drawn(_line(3.0, 0.3, 2.0), _line(8.0, 0.3, 2.0))
    pairs = twin_pairs(skeleton_tracks(d, 1.0, MM))
    assert len(pairs) == 1
    assert pairs[0].separation_mm == pytest.approx(5.0, abs=0.4)


def test_the_bead_between_twins_holds_their_glass_and_leaves_the_rest() -> None:
    far = _line(-15.0, 0.5, 2.0)
    d = _drawn(_line(3.0, 0.3, 2.0), _line(8.0, 0.3, 2.0), far)
    tracks = skeleton_tracks(d, 1.0, MM)
    pair = twin_pairs(tracks)[0]
    out, bead = bead_between(d, tracks, pair, 1.0, 1.0, MM)
    assert out.sum() == pytest.approx(d.sum(), rel=0.01)  # the same glass
    axis = np.linspace(-25.0, 25.0, M)
    column = out[:, M // 2] * MM  # across the lines at x = 0
    assert axis[np.argmax(column)] == pytest.approx(5.5, abs=0.4)  # the bead on the midline ...
    assert float(np.mean(bead.height)) > 0.3  # ... taller than either ridge
    rows = np.abs(axis + 15.0) < 3.0
    assert np.allclose(out[rows], d[rows])  # the far line untouched


def _check(pair_discrepancy: float, bead_discrepancy: float, images_apart_at: float | None = None,
           finished: bool = True):
    d = torch.from_numpy(_drawn(_line(3.0, 0.3, 2.0), _line(8.0, 0.3, 2.0)))
    bead_heights = torch.full_like(d, 7.0)

    def discrepancy(h: torch.Tensor) -> float:
        return pair_discrepancy if torch.equal(h, d) else bead_discrepancy

    def refit(h: torch.Tensor) -> tuple[torch.Tensor, float, bool]:
        return bead_heights, bead_discrepancy, finished

    def render_at(screen_mm: float):
        differ = images_apart_at is not None and screen_mm >= images_apart_at
        return lambda h: torch.ones(4) * (1.0 + (0.2 if differ and h is bead_heights else 0.0))

    return undecided_beads(d, discrepancy, refit, render_at, 1.01 * 0.05, 0.05, 1.0, MM, 1.25, (2.5, 5.0, 10.0), 2)


def test_a_bead_at_the_noise_level_replaces_ridges_above_it() -> None:
    report = _check(0.06, 0.05)
    assert [h.outcome for h in report.checked] == ["bead"]
    assert float(report.heights.max()) == 7.0
    assert "decided for one bead" in report.lines()[0]


def test_ridges_at_the_noise_level_are_kept_against_a_bead_that_stalls_above_it() -> None:
    report = _check(0.0500, 0.0510)
    assert [h.outcome for h in report.checked] == ["pair"]
    assert "decided for two ridges" in report.lines()[0]
    capped = _check(0.0500, 0.0510, finished=False)  # a fit cut by solver.max_iter decides nothing
    assert [h.outcome for h in capped.checked] == ["undecided"]
    assert "ran out of iterations" in capped.lines()[0]


def test_two_fits_short_of_the_noise_level_decide_nothing() -> None:
    report = _check(0.08, 0.06, images_apart_at=10.0)
    (h,) = report.checked
    assert h.outcome == "undecided" and h.apart_mm == 10.0
    assert "both fall short of the photos' noise level" in report.lines()[0]


def test_pairs_beyond_the_budget_of_fits_are_named_not_fitted() -> None:
    d = torch.from_numpy(_drawn(_line(-20.0, 0.3, 2.0), _line(-15.0, 0.3, 2.0), _line(10.0, 0.3, 2.0),
                                _line(15.0, 0.3, 2.0)))
    fitted = []

    def refit(h: torch.Tensor) -> tuple[torch.Tensor, float, bool]:
        fitted.append(h)
        return h, 0.05, True

    report = undecided_beads(d, lambda h: 0.05, refit, lambda s: lambda h: torch.ones(4), 0.0505, 0.05, 1.0, MM,
                             1.25, (5.0,), 1)
    assert len(fitted) == 1 and sorted(h.outcome for h in report.checked) == ["unchecked", "undecided"]
    assert report.lines()[-1].startswith("Not fitted: 1 more pairs of ridges side by side")


def test_both_at_the_noise_level_is_undecided_with_the_nearest_screen_that_tells_them_apart() -> None:
    report = _check(0.0500, 0.0499, images_apart_at=5.0)
    (h,) = report.checked
    assert h.outcome == "undecided" and h.apart_mm == 5.0
    assert h.apart_ratio == pytest.approx(0.2 / 0.05) and h.apart_ratio >= APART
    assert "screen 5 mm below the glass tells them apart" in report.lines()[0]
    assert report.metrics()["ambiguity"] == " ".join(report.lines()) and report.metrics()["ridge_pairs_undecided"] == 1
    never = _check(0.0500, 0.0499, images_apart_at=None)
    assert never.checked[0].apart_mm is None
    assert "no screen distance tried tells them apart" in never.lines()[0]


def test_a_bead_far_off_before_its_fit_is_rejected_without_one() -> None:
    calls = []

    def refit(h: torch.Tensor) -> tuple[torch.Tensor, float, bool]:
        calls.append(h)
        return h, 0.0, True

    d = torch.from_numpy(_drawn(_line(3.0, 0.3, 2.0), _line(8.0, 0.3, 2.0)))
    report = undecided_beads(d, lambda h: 0.05 if torch.equal(h, d) else 0.5, refit, lambda s: lambda h: h,
                             0.0505, 0.05, 1.0, MM, 1.25, (5.0,), 2)
    assert not calls and report.checked[0].outcome == "pair"
    assert "1 more pairs of ridges side by side stay as they are" in report.lines()[-1]


def test_a_smooth_print_has_nothing_in_question() -> None:
    axis = np.linspace(-1.0, 1.0, M)
    bump = 0.02 * np.exp(-(axis[None] ** 2 + axis[:, None] ** 2) / 0.1)
    report = undecided_beads(torch.from_numpy(bump), lambda h: 0.05, lambda h: (h, 0.05, True), lambda s: lambda h: h,
                             0.0505, 0.05, 1.0, MM, 1.25, (5.0,), 2)
    assert report.checked == [] and report.lines() == [
        "No ridges side by side in the heights: no bead's basin is in question."]


@pytest.mark.parametrize("cfg, message", [({"pairs": -1}, "^ambiguity.pairs=-1"),
                                          ({"screens_mm": [5, 0]}, r"^ambiguity.screens_mm\[1\]=0"),
                                          ({"screens_mm": None}, "^ambiguity.screens_mm=None must be a list"),
                                          ({"enabled": "maybe"}, "^ambiguity.enabled='maybe'"),
                                          ({"pair": 1}, "^unknown key ambiguity.pair;"),
                                          ("on", "^ambiguity='on' must be a mapping")])
def test_bad_settings_name_the_key_in_one_line(cfg, message) -> None:
    with pytest.raises(ValueError, match=message) as error:
        AmbiguitySettings.parse(cfg)
    assert "\n" not in str(error.value)


def test_only_the_longest_pairs_are_rendered() -> None:
    lines = [_line(-20.0 + 5.0 * k, 0.3, 2.0, x0=-12.0 + k, x1=12.0 - k) for k in range(8)]  # 7 pairs, shorter up
    d = torch.from_numpy(_drawn(*lines))
    renders = []

    def discrepancy(h: torch.Tensor) -> float:
        renders.append(h)
        return 0.05 if torch.equal(h, d) else 0.5

    report = undecided_beads(d, discrepancy, lambda h: (h, 0.05, True), lambda s: lambda h: h, 0.0505, 0.05, 1.0, MM,
                             1.25, (5.0,), 1)
    assert len(renders) == 1 + SCREENED * len(BEAD_WIDTHS)
    assert report.unscreened == 1 and "1 shorter pairs of ridges side by side not checked" in " ".join(report.lines())
    skeleton = skeleton_tracks(d.numpy(), 1.0, MM)
    every = [min(skeleton.tracks[p.first].length, skeleton.tracks[p.second].length) for p in twin_pairs(skeleton)]
    checked = [min(h.pair[0].length, h.pair[1].length) for h in report.checked]
    assert len(every) == 7 and min(checked) > min(every)  # the shortest pair is the one left out


def test_the_check_joins_a_reconstruction_of_free_heights_and_reports_in_its_metrics(tmp_path) -> None:
    # The stage (framework/tracks/ambiguity_stage.py) on a free grid's run of synthetic print_lines,
    # whose data carry no design: its sentence joins the verdict, its figures the metrics; with
    # ambiguity.enabled=false the run has neither and the same heights.
    from framework.reconstruction.reconstruction import run_reconstruction
    from tests.experiments.conftest import SMALL, compose_reconstruct

    runs = {}
    for state in ("true", "false"):
        cfg = compose_reconstruct([*SMALL, "scene=print_lines", "solver.max_iter=3", "defects.enabled=off",
                                   f"ambiguity.enabled={state}"], tmp_path)
        runs[state] = run_reconstruction(cfg, tmp_path / state, tmp_path)
    on, off = runs["true"], runs["false"]
    assert on["ridge_pairs_checked"] >= 0 and on["ambiguity_time_s"] > 0 and on["ambiguity"]
    assert on["ambiguity"].split(".")[0] in on["verdict"]
    assert "ambiguity" not in off and "ridge_pairs_checked" not in off
    if on["ridge_pairs_bead"] == 0:  # nothing replaced: the check leaves the heights as they are
        assert on["rel_error_d"] == off["rel_error_d"]
