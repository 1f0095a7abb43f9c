"""sfc-rig (experiments/apps/rig.py): the bench checked and saved once, then a print run with
``rig=<name>``, its photo and its design."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from experiments.apps.configs import app_config
from experiments.apps.rig import main
from framework.reconstruction.parts import Reconstruction
from framework.lab.synthetic_bench import SyntheticBench

# A smaller camera than the bench test's: the rig needs its markers found, not its accuracy.
BENCH = SyntheticBench(size=(1000, 750), camera_matrix=((1400.0, 0.0, 500.0), (0.0, 1400.0, 375.0), (0.0, 0.0, 1.0)))


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    BENCH.sheet.save(root / "sheet", dpi=406.4)
    inner = BENCH.receiver_pixels()
    np.save(root / "bare.npy", BENCH.photograph(BENCH.page(np.full((inner, inner), 0.5)), noise=0.005, seed=1))
    np.save(root / "flat.npy", BENCH.photograph(BENCH.page(None), noise=0.0025, seed=2))
    np.save(root / "dark.npy", np.zeros((1500, 2000)))
    return root


def _init(bench, *extra: str) -> list[str]:
    return ["init", "bench", "--markers", str(bench / "sheet.json"), "--marker-photo", str(bench / "bare.npy"),
            "--flat", str(bench / "flat.npy"), "--light-mm", "250", "--substrate-mm", "2.5", "--screen-mm", "1.25",
            "--screen-sigma-mm", "0.25", "--config-root", str(bench / "sfc_conf"), *extra]


def test_a_rig_is_written_once_and_a_print_needs_its_photo_and_design(bench, capsys, monkeypatch):
    main(_init(bench))
    out = capsys.readouterr().out
    assert "marker photo bare.npy: receiver corners from 12 of 12 markers" in out
    assert "flat field flat.npy: receiver corners from 12 of 12 markers" in out
    saved = yaml.safe_load((bench / "sfc_conf" / "rig" / "bench.yaml").read_text())
    assert saved["data"]["markers"] == str((bench / "sheet.json").resolve())
    monkeypatch.chdir(bench)  # sfc-reconstruct's search path: ./sfc_conf
    cfg = app_config("reconstruct", ["rig=bench", "data.photo=bare.npy", "data.volume=1.7mm3",
                                     "receiver.resolution=64", "height_field.resolution=32", "photons=20000"])
    assert cfg["data"]["name"] == "photo" and cfg["data"]["flat_kind"] == "uniform"
    assert cfg["light"]["position"] == [0, 0, "250mm"] and cfg["receiver"]["z"] == "-1.25mm"
    assert cfg["screen"] == {**cfg["screen"], "psf": "gaussian", "sigma": "0.25mm"}
    Reconstruction.from_config(cfg, bench).check(bench, bench / "run")  # every file, marker and setting checked


def test_a_bench_whose_photo_shows_no_markers_is_refused_in_one_line(bench, capsys):
    with pytest.raises(SystemExit) as stop:
        main(_init(bench, "--marker-photo", str(bench / "dark.npy")))
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "marker photo dark.npy: 0 of the 12 markers of DICT_4X4_50 found (ids none)" in err[0]
    with pytest.raises(SystemExit):
        main(_init(bench, "--mm-per-unit", "20"))
    assert "the sheet frames a 50 mm receiver but the scene's is 40 mm" in capsys.readouterr().err
