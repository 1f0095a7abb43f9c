"""Mistyped overrides are explained in one line with the likely fix (experiments/apps/config_errors.py)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from experiments.apps.config_errors import override_error

MISTYPED = [
    ("design", ["target=my.png"], "target is a section of keys", "e.g. target.image=my.png"),
    ("design", ["design_method=magic"], "design_method=magic is not an option of design_method",
     "options: adam, schwartzburg, sfc"),
    ("design", ["constraints.max_slop=0.3"], "unknown key constraints.max_slop", "did you mean constraints.max_slope?"),
    ("reconstruct", ["scene=print_line"], "scene=print_line is not an option of scene", "did you mean print_lines?"),
    ("reconstruct", ["solver=landweber_pixl"], "not an option of solver", "did you mean landweber_pixel?"),
    ("reconstruct", ["receiver.resolutoin=256"], "unknown key receiver.resolutoin",
     "did you mean receiver.resolution?"),
    ("reconstruct", ["stoping.morozov.tau_dis=1.1"], "stoping does not exist", "did you mean stopping?"),
    ("reconstruct", ["solver.step_size=0.1"], "solver.step_size is a section of keys", "e.g. solver.step_size.tau=0.1"),
    ("reconstruct", ["experiment=m1,m2v9"], "experiment=m2v9 is not an option of experiment", "did you mean m2v2?"),
    ("reconstruct", ["hydra/launcher=paralel"], "not an option of hydra/launcher", "did you mean parallel?"),
    ("simulate", ["scene=gausian"], "scene=gausian is not an option of scene", "did you mean gaussian?"),
    ("reconstruct", ["data=photos"], "data=photos is not an option of data", "did you mean photo?"),
    ("reconstruct", ["solver.max_iter"], "solver.max_iter has no value", "give it as solver.max_iter=<value>"),
    ("reconstruct", ["data.reference_photons=1", "data.reference_resolution=64", "data=stack"],
     "unknown key data.reference_photons; data takes: common", "unknown too: data.reference_resolution"),
]


@pytest.mark.parametrize("config, overrides, names, fix", MISTYPED)
def test_a_mistyped_override_is_named_with_its_fix(config, overrides, names, fix):
    problem = override_error(config, overrides)
    assert problem is not None and "\n" not in problem
    assert names in problem and fix in problem, problem


@pytest.mark.parametrize("config, overrides", [
    ("reconstruct", ["scene=gaussian", "receiver.resolution=64", "experiment=m1,m3v1", "hydra/launcher=parallel"]),
    ("reconstruct", ["solver.step_size.tau=0.1", "+solver.note=mine", "data=file", "data.image=null"]),
    ("design", ["target.image=my.png", "design_method=adam", "constraints.max_slope=0.3"]),
    ("simulate", ["scene=letter_a", "wavelengths=[0.475,0.65]"]),
])
def test_overrides_that_compose_pass(config, overrides):
    assert override_error(config, overrides) is None


def test_hydras_own_flags_are_left_to_hydra():
    from experiments.apps.config_errors import _overrides

    assert _overrides(["-m", "scene=a,b", "--cfg", "job", "x=1"]) is None  # prints the config, runs nothing
    assert _overrides(["-m", "scene=a,b", "--config-dir", "/mine", "x=1"]) is None  # a config of one's own
    assert _overrides(["-m", "scene=a,b", "--experimental-rerun", "pickle", "x=1"]) == ["scene=a,b", "x=1"]


def test_the_command_exits_with_the_one_line_before_any_run(tmp_path):
    done = subprocess.run([sys.executable, "-m", "experiments.apps.reconstruct", "scene=print_line",
                           f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        "error: scene=print_line is not an option of scene; did you mean print_lines? options: bump, flat, "
        "gaussian, letter_a, oblique_lines, print_lines, print_lines_mm"]
    assert not (tmp_path / "run").exists()
