"""The Hydra configs (YAML) of every ``sfc-*`` command and script, shipped inside the package so that
a wheel install composes the same configs as a checkout: ``DIRECTORY`` is their folder on disk."""

from pathlib import Path

DIRECTORY = str(Path(__file__).resolve().parent)
