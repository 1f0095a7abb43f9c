"""Composing conf/design.yaml for small designs."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

CONF = str(Path(__file__).resolve().parents[2] / "conf")
# A small design: 32 x 32 screen and heights, 65k photons, short independent renders.
SMALL = ["target.resolution=32", "height_field.resolution=32", "photons=65536", "evaluation.photons=262144",
         "design_method.transport_resolution=32", "checkpoint_every=5"]


def compose_design(overrides: list[str], tmp_path: Path) -> dict:
    """Plain dict of conf/design.yaml with ``overrides`` and an MLflow store under tmp_path."""
    with initialize_config_dir(config_dir=CONF, version_base=None):
        cfg = compose("design", overrides=[*overrides, f"tracking.store_dir={tmp_path / 'mlruns'}"])
    return OmegaConf.to_container(cfg, resolve=True)
