"""sfc-reconstruct: recover a printed height field from its caustic (Hydra app, conf/reconstruct.yaml).

Examples::

    sfc-reconstruct                                   # print_lines, M2V1, 5% noise
    sfc-reconstruct experiment=m3v1 scene=oblique_lines
    sfc-reconstruct -m experiment=m1,m2v0,m2v1,m3v0,m3v1 hydra/launcher=parallel
    sfc-reconstruct data=file data.image=caustic.npy data.mask=mask.png data.volume=0.0669
    sfc-reconstruct resume=outputs/<date>/<time>/checkpoint.pt

Writes height_field.npy, metrics.json, the target and predicted caustics (caustic_target.npy,
caustic_predicted.npy, (c, n, n)), the ground truth of synthetic data (ground_truth.npy), figures
and checkpoint.pt into the Hydra run directory
and logs the run to MLflow (conf/tracking/mlflow.yaml).
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from hydra.utils import get_original_cwd
from omegaconf import DictConfig

import conf
from experiments.apps.config_errors import checked_app
from experiments.apps.input_errors import one_line_input_errors
from experiments.apps.run_summary import reconstruction_summary
from framework.core.progress import Heartbeat
from framework.reconstruction.reconstruction import run_reconstruction
from experiments.apps.configs import to_plain


@hydra.main(version_base=None, config_path=conf.DIRECTORY, config_name="reconstruct")
@one_line_input_errors
def app(cfg: DictConfig) -> None:
    """Hydra entry point: one reconstruction per job; multirun jobs share an MLflow sweep id."""
    hydra_cfg = HydraConfig.get()
    output_dir = Path(hydra_cfg.runtime.output_dir)
    sweep_id = hydra_cfg.sweep.dir if hydra_cfg.mode == RunMode.MULTIRUN else None
    with Heartbeat("reconstruction: rendering the data"):
        metrics = run_reconstruction(to_plain(cfg), output_dir, Path(get_original_cwd()), sweep_id=sweep_id)
    if cfg.get("print_metrics", False):
        print(json.dumps(metrics, indent=2))
    print("\n".join(reconstruction_summary(metrics, output_dir)))


main = checked_app("reconstruct", app)  # the console script: mistyped overrides end in one line

if __name__ == "__main__":
    main()
