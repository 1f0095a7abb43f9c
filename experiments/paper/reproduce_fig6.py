"""Reproduce the paper's Fig. 6: caustic design (Schwartzburg et al. 2014) against the regularised
reconstruction M2V1 on the "Lines" (print_lines) and "A" (letter_a) height fields, both from the
same noisy caustic (5% noise). The design runs with each transport source (the flat glass's
caustic, and the light's irradiance on the glass: framework/design/schwartzburg.py). Runs the
six cases as one Hydra multirun logged to MLflow, then rebuilds the figure and the table (h) from
the store.

    python -m experiments.paper.reproduce_fig6                   # run all six, then the figure
    python -m experiments.paper.reproduce_fig6 --table-only      # the figure from the latest runs
    python -m experiments.paper.reproduce_fig6 --overrides photons=2097152

Writes fig6.png, fig6.md and fig6.csv into --out (default docs/results).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.paper.mlflow_store import (TrackingStore, artifact, latest_runs, reproduction_parser, run_sweep,
                                      tracking_store)
from experiments.paper.tables import write_csv
from framework.files.plotting import show_panel

EXPERIMENT = "fig6"
SCENES = {"print_lines": "Lines", "letter_a": "A"}
METHODS = {"m2v1": "M2V1", "schwartzburg": "Schwartzburg", "schwartzburg_light": "Schwartzburg (light on glass)"}
# The paper's Fig. 6 (h): relative discrepancy and relative error (h + d) per scene; its design
# method stands beside both of our transport sources.
PAPER = {("Schwartzburg", "Lines"): (0.0693, 1.0217), ("Schwartzburg", "A"): (0.0862, 0.5596),
         ("M2V1", "Lines"): (0.0544, 0.0702), ("M2V1", "A"): (0.0548, 0.1760)}


def paper_numbers(method: str, label: str) -> tuple[float, float]:
    """The paper's (discrepancy, error) for our ``method`` (either design source: its design method)."""
    return PAPER[("M2V1" if method == "M2V1" else "Schwartzburg", label)]


def collect(store: TrackingStore) -> tuple[dict[tuple[str, str], dict], list[str]]:
    """Per (method, scene label): the run's metrics and arrays; and the cases that have no run."""
    chosen, client = latest_runs(store, EXPERIMENT, key=lambda run: (run.data.tags.get("method"),
                                                                      run.data.tags.get("scene")))
    cases, missing = {}, []
    for scene, label in SCENES.items():
        for method in METHODS.values():
            run = chosen.get((method, scene))
            if run is None:
                missing.append(f"{method} on {scene}")
                continue
            cases[(method, label)] = {name: artifact(client, run, f"{name}.{ext}") for name, ext in (
                ("metrics", "json"), ("height_field", "npy"), ("ground_truth", "npy"),
                ("caustic_target", "npy"), ("caustic_predicted", "npy"))}
    return cases, missing


def write_table(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """fig6.csv and fig6.md: ours beside the paper's, per method and scene."""
    rows = []
    for (method, label), case in sorted(cases.items()):
        m = case["metrics"]
        paper = paper_numbers(method, label)
        rows.append({"method": method, "scene": label, "rel_dis": m["rel_discrepancy"], "rel_err": m["rel_error"],
                     "rel_err_d": m["rel_error_d"], "iterations": m["iterations"],
                     "run_time_s": m["run_time_s"], "paper_rel_dis": paper[0], "paper_rel_err": paper[1]})
    write_csv(out / "fig6.csv", rows)
    lines = [
        "| method | scene | rel. dis. | rel. err. | rel. err. (d) | #iter | run time (s) | paper: dis. | paper: err. |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {r['method']} | {r['scene']} | {r['rel_dis']:.4f} | {r['rel_err']:.4f} | {r['rel_err_d']:.4f} "
              f"| {r['iterations']} | {r['run_time_s']:.1f} | {r['paper_rel_dis']:.4f} | {r['paper_rel_err']:.4f} |"
              for r in rows]
    (out / "fig6.md").write_text("\n".join(lines) + "\n")


def write_figure(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """fig6.png: per scene the input caustic, each method's predicted caustic, the ground truth and
    each method's surface (one height scale per scene), and the centre slices y = 0."""
    labels, methods = list(SCENES.values()), list(METHODS.values())
    columns = 2 * len(methods) + 3
    fig = Figure(figsize=(3.4 * columns, 3.6 * len(labels)))
    for row, label in enumerate(labels):
        present = [(name, cases[(name, label)]) for name in methods if (name, label) in cases]
        if not present:
            continue
        truth = present[0][1]["ground_truth"]
        panels = [("input caustic", present[0][1]["caustic_target"].sum(axis=0), True)]
        panels += [(f"{name} caustic", c["caustic_predicted"].sum(axis=0), True) for name, c in present]
        panels += [("ground truth", truth, False)] + [
            (f"{name} surface", c["height_field"], False) for name, c in present
        ]
        top = max(float(image.max()) for _, image, caustic in panels if not caustic)
        for col, (title, image, caustic) in enumerate(panels):
            ax = fig.add_subplot(len(labels), columns, columns * row + col + 1)
            show_panel(ax, f"{label}: {title}", image, caustic, top)
        ax = fig.add_subplot(len(labels), columns, columns * (row + 1))
        x = np.linspace(-1, 1, truth.shape[1])
        ax.plot(x, truth[truth.shape[0] // 2], "k-", lw=2, label="ground truth")
        for name, c in present:
            d = c["height_field"]
            ax.plot(np.linspace(-1, 1, d.shape[1]), d[d.shape[0] // 2], label=name)
        ax.set_title(f"{label}: centre slice y = 0", fontsize=8)
        ax.set_xlabel("x (scene units)")
        ax.legend(fontsize=6)
    fig.savefig(out / "fig6.png", dpi=100, bbox_inches="tight")


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run_sweep(store, EXPERIMENT, [f"experiment={','.join(METHODS)}", f"scene={','.join(SCENES)}"],
                  args.overrides, args.launcher)
    cases, missing = collect(store)
    if not cases:
        raise SystemExit(f"no finished Fig. 6 runs in {store.uri or store.directory}")
    if missing:
        print(f"warning: no finished run for {', '.join(missing)}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(cases, args.out)
    write_figure(cases, args.out)
    print((args.out / "fig6.md").read_text())


if __name__ == "__main__":
    main()
