"""Hydra's configs made plain at the commands' edge (the framework reads plain dicts and lists), and
the plain config of an app's Hydra config (conf/) with overrides, for scripts that run several
reconstructions in one process."""

from __future__ import annotations

from typing import Any

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, ListConfig, OmegaConf

import conf

def to_plain(cfg: Any) -> Any:
    """A resolved plain-Python copy of an OmegaConf node (dicts and lists); other values unchanged."""
    if isinstance(cfg, (DictConfig, ListConfig)):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def app_config(name: str, overrides: list[str]) -> dict[str, Any]:
    """The plain config of conf/<name>.yaml (reconstruct, design, simulate) with ``overrides``."""
    with initialize_config_dir(config_dir=conf.DIRECTORY, version_base=None):
        return to_plain(compose(name, overrides=overrides))


def reconstruct_config(overrides: list[str]) -> dict[str, Any]:
    """The plain config of conf/reconstruct.yaml with ``overrides``."""
    return app_config("reconstruct", overrides)


def chooses_start(overrides: list[str]) -> bool:
    """Whether ``overrides`` choose the start (``initial=...``, also with ``+``/``~``)."""
    return any(o.split("=")[0].lstrip("+~") == "initial" for o in overrides)


def known_print(overrides: list[str]) -> list[str]:
    """``overrides`` for a study whose configured height field is the print's truth given as its design
    (data.mask=design on a photo of a known print): no defect report, and ``initial=auto`` does not
    start from the design (the truth) unless a start is chosen in ``overrides``."""
    return [*overrides, "defects.enabled=off", *([] if chooses_start(overrides) else ["~initial.candidates.design"])]
