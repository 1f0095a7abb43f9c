"""Bad input ends before a run opens: exit status 1, one ``error:`` line naming the key and the fix,
no render, no MLflow run, nothing written; a resume only from a checkpoint of the same run; a
sweep with one bad job starts none; random corruptions of a valid config never end in a
traceback."""

from __future__ import annotations

import copy
import http.server
import json
import math
import random
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from PIL import Image

from experiments.apps.input_errors import INPUT_ERRORS, one_line_input_errors
from experiments.apps.start_checks import CheckBeforeStart, check_launcher, sweep_jobs
from framework.core.checkpoint import save_checkpoint
from framework.lab.photo_synthesis import synthesize_photo
from framework.reconstruction.reconstruction import run_reconstruction
from framework.reconstruction.parts import Reconstruction
from framework.reconstruction.run_identity import run_fingerprint
from operators.heightfield.operator import CausticOperator
from operators.mesh.operator import MeshSceneOperator
from tests.experiments.conftest import SMALL, compose_reconstruct

REPO = Path(__file__).resolve().parents[2]
SHAPE = (160, 200)  # photo rows, columns
CORNERS = "[[20,140],[180,140],[180,20],[20,20]]"
PHOTO = ["data=photo", "data.photo=photo.png", f"data.corners={CORNERS}"]


def _png(path: Path, array: np.ndarray) -> None:
    Image.fromarray(array).save(path)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A directory of good and bad input files, never written to by the runs."""
    root = tmp_path_factory.mktemp("inputs")
    image = np.fromfunction(lambda i, j: 1.2 + np.sin(i / 5.0) * np.cos(j / 7.0), (64, 64))
    corners = json.loads(CORNERS)
    photo = synthesize_photo(image, corners, SHAPE, 1.0, gain=0.4)
    _png(root / "photo.png", photo)
    _png(root / "saturated.png", np.full(SHAPE, 65535, dtype=np.uint16))
    _png(root / "black.png", np.zeros(SHAPE, dtype=np.uint16))
    _png(root / "small_dark.png", np.zeros((80, 100), dtype=np.uint16))
    _rgb16(root / "rgb16.png")
    (root / "photo.jpg").write_bytes(b"\xff\xd8\xff")
    (root / "a_directory").mkdir()
    np.save(root / "caustic.npy", np.ones((1, 64, 64)))
    np.save(root / "mask.npy", np.pad(np.ones((16, 16)), 8))
    (root / "truncated.npy").write_bytes(np.lib.format.magic(1, 0) + b"\x00\x10{'descr': '<f8'")
    return root


def _rgb16(path: Path) -> None:
    """A 16-bit RGB PNG (Pillow cannot write one; its raw bytes are enough for the reader)."""
    import zlib
    height, width = 4, 4
    raw = b"".join(b"\x00" + b"\x00" * (6 * width) for _ in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    header = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([16, 2, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))


def _no_render(*args, **kwargs):
    raise AssertionError("rendered before the inputs were checked")


@pytest.fixture()
def refused(tmp_path, inputs, monkeypatch):
    """Run sfc-reconstruct's task in-process with ``overrides``; return its one error line after
    asserting exit, no render, no store and nothing written."""
    monkeypatch.setattr(CausticOperator, "render", _no_render)
    monkeypatch.setattr(MeshSceneOperator, "render", _no_render)
    before = sorted(p.name for p in inputs.iterdir())

    def run(overrides: list[str]) -> str:
        cfg = compose_reconstruct([*SMALL, *overrides], tmp_path)
        store = [o.split("=", 1)[1] for o in overrides if o.startswith("tracking.store_dir=")]
        cfg["tracking"]["store_dir"] = store[0] if store else cfg["tracking"]["store_dir"]
        task = one_line_input_errors(lambda c: run_reconstruction(c, tmp_path / "run", inputs))
        with pytest.raises(SystemExit) as exit_:
            task(cfg)
        message = str(exit_.value.code)
        assert message.startswith("error: ") and "\n" not in message, message
        assert list(tmp_path.iterdir()) == [], "something was written before the input was refused"
        assert sorted(p.name for p in inputs.iterdir()) == before
        return message

    return run


@pytest.mark.parametrize("overrides, named", [
    # data=photo: files
    (["data.photo=missing.png"], "missing.png"),
    (["data.photo=a_directory"], "is a directory"),
    (["data.photo=photo.jpg"], "unsupported suffix '.jpg'"),
    (["data.photo=rgb16.png", "data.corners=[[0,3],[3,3],[3,0],[0,0]]"], "16-bit RGB"),
    (["data.photo=saturated.png"], "saturated"),
    (["data.photo=black.png"], "all zero"),
    (["data.flat=black.png"], "flat field black.png"),
    (["data.dark=small_dark.png"], "dark frame small_dark.png is 100 x 80"),
    (["data.photo=truncated.npy"], "truncated.npy is corrupt or truncated"),
    # data=photo: corners
    (["data.corners=[[20,140],[180,140],[180,20],[20,500]]"], "outside the 200 x 160 photo"),
    (["data.corners=[[20,140],[180,20],[180,140],[20,20]]"], "self-intersecting"),
    (["data.corners=[[20,140],[20,140],[180,20],[20,20]]"], "degenerate"),
    (["data.corners=[[20,140],[180,140],[60,60],[20,20]]"], "not convex"),
    (["data.corners=[[20,140],[180,140],[180,20]]"], "data.corners"),
    (["data.pixel_centre=0.3"], "data.pixel_centre=0.3"),
    # data=photo: settings
    (["data.black_level=-5"], "data.black_level=-5"),
    (["data.response=gamma", "data.gamma=0"], "data.gamma=0"),
    (["data.channel=purple"], "data.channel='purple'"),
    (["data.response=log"], "data.response='log'"),
    (["data.saturation=2"], "data.saturation=2"),
    (["data.bit_depth=12"], "data.bit_depth=12"),
    (["data.supersample=1000"], "data.supersample=1000"),
    (["data.delta=auto"], "data.repeat"),
    (["data.flat_kind=screen"], "data.flat_kind='screen'"),
    (["wavelengths=[0.45,0.55,0.65]"], "set wavelengths=[<the filter's wavelength>]"),
    # what is known of the print
    (["data.volume='abc mm3'"], "data.volume='abc mm3'"),
    (["data.volume=100"], "data.volume=100 scene units^3 needs a mean height of"),
    (["data.volume=100", "solver.regularizers.l1_bounds.p2=1000"], "data.volume=100 scene units^3"),
    (["data.volume=0.5", "data.mask=mask.npy", "height_field.resolution=32"], "above the height bound p2=0.3"),
    (["data.mask=missing_mask.npy"], "missing_mask.npy"),
    (["data.mask=7"], "data.mask=7"),
    (["data.brightness=bright"], "data.brightness='bright'"),
])
def test_bad_photo_input_is_refused_before_the_run_opens(refused, overrides, named) -> None:
    assert named in refused([*PHOTO, *overrides])


@pytest.mark.parametrize(
    "overrides, named",
    [
        (["data=file", "data.image=a_directory"], "is a directory"),
        (
            ["data=file", "data.image=caustic.npy"],
            "solver.post_steps.volume_v1 and solver.post_steps.volume_hold need the deposited volume",
        ),
        (["data=file", "data.image=truncated.npy"], "truncated.npy is corrupt or truncated"),
        (["data=file", "data.image=caustic.npy", "wavelengths=[0.5,0.6]"], "set wavelengths"),
        (["tracking.uri=foo://bar"], "unknown scheme 'foo'"),
        (["tracking.store_dir=caustic.npy/mlruns"], "is a file, not a directory"),
        (["resume=missing.pt"], "resume='missing.pt'"),
        (["height_field.path=3"], "height_field.path=3"),
        (["height_field.resolution=100000"], "height_field.resolution=100000"),
        (["receiver.resolution=100000"], "receiver.resolution=100000"),
        (["seed=-1"], "seed=-1"),
        (["calibration.params=5"], "calibration.params=5"),
        (["solver.regularizers.l1_bounds.p2=7.5kg"], "solver.regularizers.l1_bounds.p2='7.5kg' must be a number"),
    ],
)
def test_bad_input_elsewhere_is_refused_before_the_run_opens(refused, overrides, named) -> None:
    assert named in refused(overrides)


def test_plugin_lengths_are_taken_in_millimetres_too(inputs, tmp_path) -> None:
    cfg = compose_reconstruct(
        [
            *SMALL,
            "solver.regularizers.l1_bounds.p2=7.5mm",
            "solver.preconditioner.length=[3mm,0.06]",
            "data.mask_threshold=0.025mm",
            "initial=transport",
            "initial.p2=5mm",
        ],
        tmp_path,
    )
    parts = Reconstruction.from_config(cfg, inputs)  # 25 mm per scene unit
    assert parts.settings.cfg["solver"]["regularizers"]["l1_bounds"]["p2"] == pytest.approx(0.3)
    assert parts.settings.cfg["solver"]["preconditioner"]["length"] == pytest.approx([0.12, 0.06])
    assert parts.settings.cfg["data"]["mask_threshold"] == pytest.approx(0.001)
    assert parts.settings.cfg["initial"]["p2"] == pytest.approx(0.2) and parts.start.p2 == pytest.approx(0.2)


def test_a_tracking_server_that_is_not_mlflow_is_refused(refused, tmp_path_factory) -> None:
    empty = tmp_path_factory.mktemp("www")
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(empty), **k)  # noqa: E731
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        uri = f"http://127.0.0.1:{server.server_address[1]}"
        assert "is not an MLflow server (/health: HTTP 404)" in refused([f"tracking.uri={uri}"])
    finally:
        server.shutdown()


def test_a_launcher_whose_engine_is_absent_is_refused(monkeypatch) -> None:
    monkeypatch.setattr("shutil.which", lambda name: None)
    with pytest.raises(ValueError, match="needs SLURM \\(the sbatch command\\)"):
        check_launcher("hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher")
    check_launcher("hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher")  # nothing to need


def test_a_run_directory_under_a_file_is_refused(tmp_path) -> None:
    (tmp_path / "notes.txt").write_text("")
    config = OmegaConf.create({"hydra": {"run": {"dir": str(tmp_path / "notes.txt" / "run")}}})
    with pytest.raises(SystemExit, match="error: hydra.run.dir=.*notes.txt is a file, not a directory"):
        CheckBeforeStart().on_run_start(config)


def test_sweep_jobs_follow_the_basic_sweepers_order() -> None:
    assert sweep_jobs(["seed=0,1", "data.delta=0.05,0.1", "photons=7"]) == [
        ["seed=0", "data.delta=0.05", "photons=7"], ["seed=0", "data.delta=0.1", "photons=7"],
        ["seed=1", "data.delta=0.05", "photons=7"], ["seed=1", "data.delta=0.1", "photons=7"]]


@pytest.mark.slow
def test_a_sweep_with_one_bad_value_starts_no_job(tmp_path) -> None:
    done = subprocess.run([sys.executable, "-m", "experiments.apps.reconstruct", "-m", *SMALL, "seed=0,1",
                           "data.delta=0.05,1.5", f"hydra.sweep.dir={tmp_path / 'sweep'}",
                           f"tracking.store_dir={tmp_path / 'mlruns'}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    line = done.stderr.strip().splitlines()[-1]
    assert line.startswith("error: sweep job 1 (") and "data.delta=1.5" in line and "no job was started" in line
    assert list(tmp_path.iterdir()) == []  # no job directory, no store


# --- resume -----------------------------------------------------------------------------------------

class _State:
    def state_dict(self) -> dict:
        return {"iteration": 3}


def _checkpoint(path: Path, overrides: list[str] | None, inputs: Path, tmp_path: Path) -> Path:
    run = None if overrides is None else run_fingerprint(compose_reconstruct([*SMALL, *overrides], tmp_path), inputs)
    return save_checkpoint(_State(), path, run)


@pytest.mark.parametrize("other, named", [
    (["height_field.resolution=64"], "its height_field differs"),
    (["experiment=m3v1"], "its solver differs"),
    ([*PHOTO, "receiver.resolution=64"], "its data differs"),
    (["seed=5"], "its seed differs"),
    (None, "does not record which run wrote it"),
])
def test_a_checkpoint_of_another_run_is_refused(refused, inputs, tmp_path_factory, other, named) -> None:
    path = _checkpoint(tmp_path_factory.mktemp("other") / "checkpoint.pt", other, inputs, tmp_path_factory.mktemp("s"))
    message = refused([f"resume={path}"])
    assert named in message and "resume=null" in message


def test_a_truncated_or_foreign_checkpoint_is_refused(refused, inputs, tmp_path_factory) -> None:
    folder = tmp_path_factory.mktemp("broken")
    whole = _checkpoint(folder / "whole.pt", [], inputs, folder).read_bytes()
    (folder / "truncated.pt").write_bytes(whole[: len(whole) // 2])
    torch.save({"weights": torch.zeros(3)}, folder / "foreign.pt")
    assert "not a readable checkpoint" in refused([f"resume={folder / 'truncated.pt'}"])
    assert "is not a checkpoint of format" in refused([f"resume={folder / 'foreign.pt'}"])


def test_a_checkpoint_of_the_same_run_is_taken(inputs, tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "solver.max_iter=999", "operator.chunk_size=4096"], tmp_path)
    path = _checkpoint(tmp_path / "checkpoint.pt", [], inputs, tmp_path)  # another cap and chunk: same run
    cfg["resume"] = str(path)
    assert Reconstruction.from_config(cfg, inputs).check(inputs, tmp_path / "run") == path


# --- random corruptions ----------------------------------------------------------------------------

BAD_VALUES = [None, "abc", -1, 0, math.nan, 1e30, [1, 2], {"a": 1}, True, "3 mm", "", -0.5, 2 ** 40]


def _leaves(node, path=()):
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _leaves(value, (*path, key))
    else:
        yield path


@pytest.mark.parametrize(
    "extra",
    [[], PHOTO + ["data.volume=0.01", "data.mask=mask.npy", "height_field.resolution=32"]],
    ids=["synthetic", "photo"],
)
def test_random_corruptions_never_end_in_a_traceback(inputs, tmp_path, monkeypatch, extra) -> None:
    monkeypatch.setattr(CausticOperator, "render", _no_render)
    valid = compose_reconstruct([*SMALL, *extra], tmp_path)
    leaves = list(_leaves(valid))
    rng = random.Random(2026)
    refused = 0
    for _ in range(100):
        cfg = copy.deepcopy(valid)
        path = rng.choice(leaves)
        node = cfg
        for key in path[:-1]:
            node = node[key]
        if rng.random() < 0.15:
            del node[path[-1]]
        else:
            node[path[-1]] = rng.choice(BAD_VALUES)
        try:
            Reconstruction.from_config(cfg, inputs).check(inputs, tmp_path / "run")
        except INPUT_ERRORS as error:
            refused += 1
            assert "\n" not in str(error).strip(), f"{'.'.join(map(str, path))}: {error}"
    assert refused >= 40  # most corruptions are refused; the rest are values the run can take
