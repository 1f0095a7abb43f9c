"""Tool paths read from CSV and G-code: tracks, bead sizes from columns, slicer comments and the
fibre fed, travel moves and layer changes ending a track, layers merged, bad files refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from framework.tracks.toolpath import read_toolpath
from framework.tracks.track_set import DEFAULT_SHAPE, bead_area_factor


def test_a_csv_tool_path_gives_its_tracks_with_their_profiles(tmp_path) -> None:
    path = tmp_path / "print.csv"
    path.write_text("track,x_mm,y_mm,width_mm,height_mm,speed\n"
                    "a,-10,0,0.6,0.3,5\na,0,0,0.6,0.3,5\na,10,0,0.8,0.5,5\n"
                    "b,0,-10,0.5,0.4,5\nb,0,10,0.5,0.4,5\n"
                    "c,0,-10,0.5,0.4,5\nc,0,10,0.5,0.4,5\n")  # c: a second layer on b
    tracks = read_toolpath(path)
    assert [t.name for t in tracks.tracks] == ["track a", "track b"]
    a, b = tracks.tracks
    assert a.length == pytest.approx(20.0)
    assert np.interp(15.0, a.knot_arcs(), a.height) == pytest.approx(0.4)  # halfway along the second segment
    assert b.layers == 2 and np.allclose(b.height, 0.8) and np.allclose(b.width, 0.5)


def test_gcode_moves_that_extrude_become_tracks(tmp_path) -> None:
    path = tmp_path / "print.gcode"
    path.write_text("\n".join([
        "G21 ; mm", "G90", "M83 ; relative extrusion", "G1 Z0.3 F600",
        ";WIDTH:0.6", ";HEIGHT:0.3",
        "G0 X-10 Y0", "G1 X0 Y0 E1.0", "G1 X10 Y0 E1.0",    # track 1
        "G1 E-0.5 ; retract", "G0 X0 Y-10", "G1 E0.5",      # travel, no track
        ";WIDTH:0.5", "G1 X0 Y10 E2.0",                     # track 2
        "G1 Z0.6", "G1 X0 Y-10 E2.0",                       # track 3: the next layer on track 2, laid back
    ]))
    tracks = read_toolpath(path)
    assert len(tracks.tracks) == 2
    first, second = tracks.tracks
    assert first.length == pytest.approx(20.0) and np.allclose(first.width, 0.6) and np.allclose(first.height, 0.3)
    assert second.layers == 2 and np.allclose(second.height, 0.6) and np.allclose(second.width, 0.5)


def test_gcode_bead_width_from_the_fibre_fed(tmp_path) -> None:
    path = tmp_path / "fibre.gcode"
    path.write_text("G90\nM82\nG92 E0\nG0 X0 Y0 Z0.4\nG1 X10 Y0 E5\nG1 X20 Y0 E10\n")
    (track,) = read_toolpath(path, height_mm=0.4, fibre_diameter_mm=0.5).tracks
    area = math.pi * 0.5**2 / 4 * 0.5  # mm^2 of glass per mm of path: 0.5 mm of fibre per mm
    assert np.allclose(track.width, area / (0.4 * bead_area_factor(DEFAULT_SHAPE)))


@pytest.mark.parametrize("text, words", [
    ("track,x_mm,y_mm\na,0,0\n", "width_mm, height_mm are missing"),
    ("track,x_mm,y_mm,width_mm,height_mm\na,0,0,0.5,0.3\n", "two points at least"),
    ("track,x_mm,y_mm,width_mm,height_mm\na,0,zero,0.5,0.3\na,1,0,0.5,0.3\n", "line 2"),
])
def test_a_bad_csv_is_refused_in_one_line(tmp_path, text, words) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=words):
        read_toolpath(path)


def test_gcode_without_sizes_or_extrusion_is_refused(tmp_path) -> None:
    path = tmp_path / "bare.gcode"
    path.write_text("G90\nM83\nG0 X0 Y0\nG1 X10 Y0 E1\n")
    with pytest.raises(ValueError, match="width_mm and height_mm"):
        read_toolpath(path)
    path.write_text("G90\nG0 X0 Y0\nG0 X10 Y0\n")
    with pytest.raises(ValueError, match="extrudes along no path"):
        read_toolpath(path, 0.5, 0.3)
    other = tmp_path / "print.txt"
    other.write_text("")
    with pytest.raises(ValueError, match="unknown format"):
        read_toolpath(other)
