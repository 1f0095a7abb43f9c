"""sfc-design: a printable piece of glass whose caustic is a target image (Hydra app, conf/design.yaml;
docs/design.md).

Examples::

    sfc-design                             # grace_hopper, the default method (sfc), 5 minutes
    sfc-design target.image=logo.png target.width="60 mm" receiver.z="-200 mm"
    sfc-design design_method=schwartzburg  # a baseline: the transport design alone
    sfc-design design_method=adam          # a baseline: Adam from flat glass (Mitsuba 3 tutorial)

Writes into the Hydra run directory: height_field.npy (scene units), height_field_mm.npy/.png,
glass.stl and glass.obj (mm), caustic.npy/target.npy, preview_<f>x.npy/.png, design.png,
metrics.json, verdict.txt, checkpoint.pt; logs to MLflow.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_original_cwd
from omegaconf import DictConfig

import conf
from experiments.apps.config_errors import checked_app
from experiments.apps.input_errors import one_line_input_errors
from framework.core.progress import Heartbeat
from framework.design.design_run import run_design
from framework.design.design_setup import prepare_design
from experiments.apps.configs import to_plain


@hydra.main(version_base=None, config_path=conf.DIRECTORY, config_name="design")
@one_line_input_errors
def app(cfg: DictConfig) -> None:
    """Hydra entry point: check everything, design, print the verdict and where the files went."""
    output_dir = Path(HydraConfig.get().runtime.output_dir)
    plain = to_plain(cfg)
    with Heartbeat("design: checking the target and the limits"):
        setup = prepare_design(plain, Path(get_original_cwd()))
        result = run_design(plain, output_dir, setup=setup)
    print("\n".join(result.verdict))
    print(f"wrote height_field.npy, glass.stl, glass.obj, design.png, previews and metrics.json to {output_dir}")


main = checked_app("design", app)  # the console script: mistyped overrides end in one line

if __name__ == "__main__":
    main()
