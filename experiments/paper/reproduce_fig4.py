"""Renders of the paper's mesh scenes (Figs. 3 and 4): the two-lens scene and the prism +
lens-array scene with three wavelengths, each at a high and a low photon count, with the intrinsic
noise of every render (two renders with independent photons: ||b1 - b2|| / (sqrt(2) ||b||)),
logged to MLflow; the figure is rebuilt from the store.

    python -m experiments.paper.reproduce_fig4                        # render, log, then the figure
    python -m experiments.paper.reproduce_fig4 --table-only           # the figure from the latest runs
    python -m experiments.paper.reproduce_fig4 --high 33554432 --low 4194304

Writes fig4.png and fig4.md into --out (default docs/results). Wavelengths map to colour by order:
the shortest to blue, the longest to red.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.apps.configs import app_config
from experiments.paper.mlflow_store import TrackingStore, artifact, latest_runs, reproduction_parser, tracking_store
from framework.scene.scene_config import build_heights, build_operator, build_scene
from framework.tracking.mlflow_tracker import MlflowTracker

EXPERIMENT = "fig4"
SCENES = ("two_lenses", "prism_lens_array")


def render_pair(operator_name: str, photons: int, seed: int, overrides: list[str]) -> tuple[np.ndarray, float, float]:
    """The mean of two renders with independent photons (c, n, n), their intrinsic noise and seconds."""
    cfg = app_config("simulate", [f"operator={operator_name}", f"photons={photons}", *overrides])
    scene = build_scene(cfg)
    heights = build_heights(cfg)
    first = build_operator({**cfg, "seed": seed}, scene)
    second = first.variant(first.photons, seed + 1000, scene.receiver.resolution)
    start = time.perf_counter()
    images = [op.render(heights.to(op.dtype)).double().numpy() for op in (first, second)]
    seconds = time.perf_counter() - start
    mean = 0.5 * (images[0] + images[1])
    noise = float(np.linalg.norm(images[0] - images[1]) / (math.sqrt(2) * np.linalg.norm(mean)))
    return mean, noise, seconds


def to_rgb(image: np.ndarray, percentile: float = 99.5) -> np.ndarray:
    """(c, n, n) -> (n, n, 3): one channel is grey; three are blue, green, red by wavelength order."""
    channels = image if image.shape[0] == 3 else np.repeat(image[:1], 3, axis=0)
    scale = np.percentile(channels, percentile) or 1.0
    return np.clip(np.moveaxis(channels[::-1], 0, -1) / scale, 0.0, 1.0)


def run(store: TrackingStore, high: int, low: int, seed: int, overrides: list[str]) -> None:
    """Render every scene at both photon counts; one MLflow run each."""
    for name in SCENES:
        for photons in (high, low):
            image, noise, seconds = render_pair(name, photons, seed, overrides)
            with MlflowTracker(EXPERIMENT, run_name=f"{name}-{photons}", store_dir=store.directory,
                               tracking_uri=store.uri,
                               params={"operator": name, "photons": photons, "seed": seed},
                               tags={"scene": name, "photons": str(photons)}) as tracker:
                tracker.log_metrics({"intrinsic_noise": noise, "seconds": seconds, "photons": photons})
                with tempfile.TemporaryDirectory() as tmp:
                    path = Path(tmp) / "caustic.npy"
                    np.save(path, image.astype(np.float32))
                    tracker.log_artifact(path)
            print(
                f"{name}, {photons} photons: intrinsic noise {noise:.4f}, {seconds:.0f} s for two renders", flush=True
            )


def build(store: TrackingStore, out: Path) -> None:
    """fig4.png (every render in colour) and fig4.md (photons, intrinsic noise) from the store."""
    chosen, client = latest_runs(
        store, EXPERIMENT, key=lambda r: (r.data.tags.get("scene"), r.data.tags.get("photons"))
    )
    cases = sorted(chosen.items(), key=lambda item: (SCENES.index(item[0][0]), -int(item[0][1])))
    fig = Figure(figsize=(4.2 * len(cases), 4.4))
    lines = ["| scene | photons | intrinsic noise | seconds (two renders) |", "|---|---|---|---|"]
    for k, ((scene, photons), run_) in enumerate(cases):
        noise = run_.data.metrics["intrinsic_noise"]
        ax = fig.add_subplot(1, len(cases), k + 1)
        ax.imshow(to_rgb(artifact(client, run_, "caustic.npy")), origin="lower", extent=(-1, 1, -1, 1))
        ax.set_title(f"{scene}: {int(photons):,} photons, noise {noise:.2%}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        lines.append(f"| {scene} | {int(photons):,} | {noise:.4f} | {run_.data.metrics['seconds']:.0f} |")
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "fig4.png", dpi=110, bbox_inches="tight")
    (out / "fig4.md").write_text("\n".join(lines) + "\n")
    print((out / "fig4.md").read_text())


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument("--high", type=int, default=1 << 24, help="photons of the low-noise renders")
    parser.add_argument("--low", type=int, default=1 << 21, help="photons of the high-noise renders")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run(store, args.high, args.low, args.seed, args.overrides)
    build(store, args.out)


if __name__ == "__main__":
    main()
