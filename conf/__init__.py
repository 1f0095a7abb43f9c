"""The Hydra configs (YAML) of every ``sfc-*`` command and script, shipped inside the package so that
a wheel install composes the same configs as a checkout: ``DIRECTORY`` is their folder on disk.

conf/reconstruct.yaml puts ./sfc_conf (the user's rigs, written by sfc-rig) on the search path;
where a run starts without one, Hydra's warning that it is missing says nothing to act on and is
silenced here, before any command composes its config."""

import warnings
from pathlib import Path

DIRECTORY = str(Path(__file__).resolve().parent)
USER_CONFIGS = "sfc_conf"  # beside the run: rig/<name>.yaml (experiments/apps/rig.py)

warnings.filterwarnings("ignore", message=f"provider=hydra.searchpath in main, path={USER_CONFIGS} is not available")
