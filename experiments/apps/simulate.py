"""sfc-simulate: render the caustic of a printed height field (Hydra app, conf/simulate.yaml).

Examples::

    sfc-simulate                                   # print lines, official defaults
    sfc-simulate scene=gaussian photons=1000000 receiver.z=-0.1
    sfc-simulate height_field.path=my_heights.png height_field.scale=0.2 wavelengths=[0.475,0.5625,0.65]

Writes into the Hydra run directory: caustic.npy (float32 (c, n, n), W per scene unit^2),
caustic.png (+y up), height_and_caustic.png and heights.npy (float64 (m, m), scene units).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_original_cwd
from omegaconf import DictConfig

import conf
from experiments.apps.config_errors import checked_app
from experiments.apps.input_errors import one_line_input_errors
from framework.files.plotting import save_caustic_png, save_height_and_caustic_figure
from experiments.apps.configs import to_plain
from framework.scene.scene_config import build_heights, build_operator, build_scene

# Absolute, so that the installed console script finds the configs too (a relative
# "../conf" would be looked up as the package "conf", which is not installed).
def simulate(cfg: Mapping[str, Any], output_dir: Path, base_dir: Path | None = None) -> dict[str, float]:
    """Render the configured scene and write the outputs into ``output_dir``; returns run figures."""
    scene = build_scene(cfg)
    heights = build_heights(cfg, base_dir=base_dir)
    operator = build_operator(cfg, scene)
    start = time.perf_counter()
    image = operator.render(heights, progress=bool(cfg.get("progress", True)))
    seconds = time.perf_counter() - start
    caustic = image.detach().cpu().numpy().astype(np.float32)

    output_dir.mkdir(parents=True, exist_ok=True)
    np.save(output_dir / "caustic.npy", caustic)
    np.save(output_dir / "heights.npy", heights.numpy())
    figure = cfg.get("figure", {})
    percentile = float(figure.get("percentile", 99.9))
    save_caustic_png(caustic, output_dir / "caustic.png", scene.wavelengths, percentile)
    half, rh = scene.substrate.half_width, scene.receiver.half_width
    save_height_and_caustic_figure(heights.numpy(), caustic, output_dir / "height_and_caustic.png",
                                   height_extent=(-half, half, -half, half), receiver_extent=(-rh, rh, -rh, rh),
                                   percentile=percentile, dpi=int(figure.get("dpi", 150)),
                                   height_cmap=str(figure.get("height_cmap", "viridis")),
                                   caustic_cmap=str(figure.get("caustic_cmap", "inferno")))
    power = float(caustic.astype(np.float64).sum()) * operator.pixel_area
    return {"power_w": power, "seconds": seconds, "photons": operator.photons,
            "photons_per_s": operator.photons / max(seconds, 1e-12)}


@hydra.main(version_base=None, config_path=conf.DIRECTORY, config_name="simulate")
@one_line_input_errors
def app(cfg: DictConfig) -> None:
    """Hydra entry point: simulate, then report where the files went, the power and the speed."""
    output_dir = Path(HydraConfig.get().runtime.output_dir)
    stats = simulate(to_plain(cfg), output_dir, base_dir=Path(get_original_cwd()))
    print(f"wrote caustic.npy, caustic.png, height_and_caustic.png, heights.npy to {output_dir}")
    print(f"power on the receiver: {stats['power_w']:.6g} W; "
          f"{stats['photons']} photons in {stats['seconds']:.3g} s ({stats['photons_per_s']:.4g} photons/s)")


main = checked_app("simulate", app)  # the console script: mistyped overrides end in one line

if __name__ == "__main__":
    main()
