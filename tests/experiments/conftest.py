"""Compose sfc-reconstruct configs with Hydra's compose API for small, fast reconstructions."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

CONF = str(Path(__file__).resolve().parents[2] / "conf")

# A small problem: 32 x 32 heights, 64 x 64 receiver, few photons; still the real operator. The check of
# undecided beads (its own stage, half of such a run's time) is left to the tests that ask for it
# (tests/tracks/test_ambiguity.py).
SMALL = ["photons=60000", "receiver.resolution=64", "height_field.resolution=32", "data.reference_photons=200000",
         "data.reference_resolution=128", "operator.footprint_px=3", "checkpoint_every=2", "initial=zero",
         "ambiguity.enabled=false"]


def compose_reconstruct(overrides: list[str], tmp_path: Path) -> dict:
    """Plain dict of conf/reconstruct.yaml with ``overrides`` and an MLflow store under tmp_path."""
    if {"data=file", "data=photo", "data=stack"} & set(overrides):  # no reference renders of their own
        overrides = [o for o in overrides if not o.startswith("data.reference_")]
    with initialize_config_dir(config_dir=CONF, version_base=None):
        cfg = compose("reconstruct", overrides=[*overrides, f"tracking.store_dir={tmp_path / 'mlruns'}"])
    return OmegaConf.to_container(cfg, resolve=True)
