"""Caustic design, side by side: every built-in target (grace_hopper, logo, ring, text "SfC") through
each method (sfc: the transport design refined by L-BFGS on the operator; schwartzburg: the
transport design alone; adam: Adam from flat glass, the Mitsuba 3 tutorial's method) with the
same time budget, as one Hydra multirun of sfc-design logged to MLflow; then the table and the
figure from the store.

    python -m experiments.paper.reproduce_design                      # 4 targets x 3 methods, 300 s each
    python -m experiments.paper.reproduce_design --seconds 120        # a shorter budget for every method
    python -m experiments.paper.reproduce_design --table-only         # the table and figure from the latest runs
    python -m experiments.paper.reproduce_design --targets ring text --overrides operator=two_lenses receiver.z=-1.0

Writes design.md, design.csv and design.png into --out (default docs/results).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.paper.mlflow_store import artifact, latest_runs, reproduction_parser, run_sweep, tracking_store
from experiments.paper.tables import write_csv

EXPERIMENT = "design"
TARGETS = ("grace_hopper", "logo", "ring", "text")
METHODS = ("sfc", "schwartzburg", "adam")


def collect(store, experiment: str = EXPERIMENT) -> dict[tuple[str, str], dict]:
    """Per (target, method): the latest finished run's metrics, target and caustic."""
    chosen, client = latest_runs(store, experiment,
                                 key=lambda run: (run.data.params.get("target.image"), run.data.tags.get("method")))
    return {key: {name: artifact(client, chosen[key], f"design/{name}.{ext}") for name, ext in (
        ("metrics", "json"), ("target", "npy"), ("caustic", "npy"))}
        for key in ((t, m) for t in TARGETS for m in METHODS) if key in chosen}


def write_table(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """design.csv and design.md: per target and method the match (relative L2, SSIM), the time, the
    printed figures."""
    rows = [{"target": t, "method": m, "relative_l2": c["metrics"]["relative_l2"], "ssim": c["metrics"]["ssim"],
             "seconds": c["metrics"]["design_seconds"], "iterations": c["metrics"]["iterations"],
             "max_slope": c["metrics"]["printed_max_slope"], "max_height_mm": 25.0 * c["metrics"]["printed_max_height"]}
            for (t, m), c in cases.items()]
    write_csv(out / "design.csv", rows)
    lines = ["| target | method | rel. L2 | SSIM | seconds | iterations | max slope | max height (mm) |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['target']} | {r['method']} | {r['relative_l2']:.3f} | {r['ssim']:.3f} | {r['seconds']:.0f} | "
              f"{r['iterations']} | {r['max_slope']:.3f} | {r['max_height_mm']:.2f} |" for r in rows]
    (out / "design.md").write_text("\n".join(lines) + "\n")


def write_figure(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """design.png: per target the target and each method's caustic (energy-normalised, one scale)."""
    targets = [t for t in TARGETS if any((t, m) in cases for m in METHODS)]
    fig = Figure(figsize=(3.2 * (1 + len(METHODS)), 3.3 * len(targets)), layout="constrained")
    for row, t in enumerate(targets):
        first = next(cases[(t, m)] for m in METHODS if (t, m) in cases)
        target = first["target"].sum(axis=0)
        top = float(np.percentile(target, 99.9)) or 1.0
        ax = fig.add_subplot(len(targets), 1 + len(METHODS), row * (1 + len(METHODS)) + 1)
        ax.imshow(np.clip(target / top, 0, 1), origin="lower", cmap="gray")
        ax.set_title(f"{t}: target", fontsize=9)
        ax.set_axis_off()
        for col, m in enumerate(METHODS):
            ax = fig.add_subplot(len(targets), 1 + len(METHODS), row * (1 + len(METHODS)) + col + 2)
            ax.set_axis_off()
            if (t, m) not in cases:
                continue
            caustic = cases[(t, m)]["caustic"].sum(axis=0)
            caustic = caustic * float(target.sum()) / max(float(caustic.sum()), 1e-300)
            ax.imshow(np.clip(caustic / top, 0, 1), origin="lower", cmap="gray")
            metrics = cases[(t, m)]["metrics"]
            ax.set_title(f"{m}: rel. L2 {metrics['relative_l2']:.3f}, SSIM {metrics['ssim']:.2f}", fontsize=9)
    fig.savefig(out / "design.png", dpi=90)


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="every method's time budget (s)")
    parser.add_argument("--targets", nargs="+", choices=TARGETS, default=list(TARGETS), help="the targets to design")
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run_sweep(
            store,
            EXPERIMENT,
            [
                f"design_method={','.join(METHODS)}",
                f"target.image={','.join(args.targets)}",
                f"seconds={args.seconds:g}",
            ],
            args.overrides,
            args.launcher,
            app="experiments.apps.design",
        )
    cases = collect(store)
    if not cases:
        raise SystemExit(f"no finished design runs in {store.uri or store.directory}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(cases, args.out)
    write_figure(cases, args.out)
    print((args.out / "design.md").read_text())


if __name__ == "__main__":
    main()
