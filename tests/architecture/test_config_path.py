"""The configuration is read at the edge: a reconstruction hands it to each module at most twice
(tests/architecture/config_path.py)."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir

from framework.pipeline.reconstruction import run_reconstruction
from tests.architecture.config_path import config_calls, stays

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_stays_are_counted_per_run_of_calls():
    calls = [("a", "f"), ("a", "g"), ("b", "h"), ("a", "f")]
    assert stays(calls) == {"a": 2, "b": 1}


def test_a_reconstruction_hands_its_config_to_each_module_at_most_twice(tmp_path):
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("reconstruct", overrides=["photons=20000", "receiver.resolution=64", "height_field.resolution=32",
                                                "solver.max_iter=2", "data.reference_photons=20000",
                                                "data.reference_resolution=64", f"tracking.store_dir={tmp_path}/mlruns",
                                                "initial=zero"])
    calls = config_calls(lambda: run_reconstruction(cfg, tmp_path / "run", tmp_path))
    visits = stays(calls)
    assert "framework.core.run_settings" in visits and "framework.core.scene_config" in visits  # it is traced
    assert max(visits.values()) <= 2, visits
