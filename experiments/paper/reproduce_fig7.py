"""Reproduce the paper's Fig. 7: M2V1 reconstruction through two lenses (a biconvex lens above the
print, a meniscus below it: conf/operator/two_lenses.yaml), beside the same reconstruction with
no lenses and the receiver at the same distance, z = -1 (the height-field operator), for the
printed lines and a smooth bump. Runs the four cases as one Hydra multirun logged to MLflow, then
rebuilds the figure and the table from the store: errors, discrepancies, iterations and seconds
per iteration.

    python -m experiments.paper.reproduce_fig7                   # run both, then the figure
    python -m experiments.paper.reproduce_fig7 --table-only      # the figure from the latest runs
    python -m experiments.paper.reproduce_fig7 --overrides photons=4194304
    python -m experiments.paper.reproduce_fig7 --table-only --experiment starts   # from reproduce_starts --part fig7

Writes fig7.png, fig7.md and fig7.csv into --out (default docs/results).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.paper.mlflow_store import (TrackingStore, artifact, latest_runs, reproduction_parser, run_sweep,
                                      tracking_store)
from experiments.paper.tables import write_csv
from framework.files.plotting import show_panel

EXPERIMENT = "fig7"
RECEIVER_Z = -1.0
CASES = {"two_lenses": "two lenses", "height_field": "no lenses"}
SCENES = ("print_lines", "bump")
# The paper's Fig. 7: M2V1 through the two lenses, relative error 17.1%, run time 2.05 min
# without the lenses and 8.55 min with them.
PAPER_ERROR = 0.171


def case_of(run) -> tuple[str, str]:
    """Which case a run is, (optics, scene): the mesh-scene operator with elements is the two-lens scene."""
    params = run.data.params
    if params.get("operator.name") == "mesh_scene" and params.get("operator.elements", "[]") not in ("[]", "None"):
        optics = CASES["two_lenses"]
    else:
        optics = CASES["height_field"] if params.get("operator.name") == "height_field" else "other"
    return optics, run.data.tags.get("scene", "")


def collect(store: TrackingStore, experiment: str = EXPERIMENT) -> dict[tuple[str, str], dict]:
    """Per (optics, scene): the latest finished run's metrics and arrays in MLflow ``experiment``."""
    chosen, client = latest_runs(store, experiment, key=case_of)
    return {key: {name: artifact(client, chosen[key], f"{name}.{ext}") for name, ext in (
        ("metrics", "json"), ("height_field", "npy"), ("ground_truth", "npy"), ("caustic_target", "npy"),
        ("caustic_predicted", "npy"))}
        for key in ((optics, scene) for scene in SCENES for optics in CASES.values()) if key in chosen}


def write_table(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """fig7.csv and fig7.md: per case the errors, discrepancy, iterations and seconds per iteration."""
    rows = []
    for (optics, scene), case in cases.items():
        m = case["metrics"]
        rows.append({"case": optics, "scene": scene, "rel_dis": m["rel_discrepancy"], "rel_err": m["rel_error"],
                     "rel_err_d": m["rel_error_d"], "iterations": m["iterations"], "run_time_s": m["run_time_s"],
                     "s_per_iteration": m["run_time_s"] / max(m["iterations"], 1),
                     "photons": m["photons_per_iteration"], "photon_traces": m.get("photon_traces")})
    write_csv(out / "fig7.csv", rows)
    lines = ["| case | scene | photons at the end | rel. dis. | rel. err. | rel. err. (d) | #iter | photon-traces (G) "
             "| run time (s) | s / iteration |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [
        f"| {r['case']} | {r['scene']} | {r['photons']:,} | {r['rel_dis']:.4f} | {r['rel_err']:.4f} "
        f"| {r['rel_err_d']:.4f} "
        f"| {r['iterations']} | {'' if r['photon_traces'] is None else format(r['photon_traces'] / 1e9, '.3f')} "
        f"| {r['run_time_s']:.0f} | {r['s_per_iteration']:.2f} |"
        for r in rows
    ]
    lines.append(f"\nThe paper (Fig. 7): relative error {PAPER_ERROR} through the lenses, run time 2.05 min without "
                 "them and 8.55 min with them (4.2x).")
    (out / "fig7.md").write_text("\n".join(lines) + "\n")


def write_figure(cases: dict[tuple[str, str], dict], out: Path) -> None:
    """fig7.png: per case the input caustic, the reconstruction's caustic, the ground truth and the
    reconstruction (one height scale), and the centre slices y = 0."""
    fig = Figure(figsize=(17, 4.0 * len(cases)))
    fig.subplots_adjust(hspace=0.4)
    for row, ((optics, scene), case) in enumerate(cases.items()):
        label = f"{scene}, {optics}"
        top = max(float(case["ground_truth"].max()), float(case["height_field"].max()))
        panels = [("input caustic", case["caustic_target"].sum(axis=0), True),
                  ("reconstruction's caustic", case["caustic_predicted"].sum(axis=0), True),
                  ("ground truth", case["ground_truth"], False), ("M2V1", case["height_field"], False)]
        for col, (title, image, caustic) in enumerate(panels):
            ax = fig.add_subplot(len(cases), 5, 5 * row + col + 1)
            show_panel(ax, f"{label}: {title}", image, caustic, top)
        ax = fig.add_subplot(len(cases), 5, 5 * row + 5)
        for name, d, style in (("ground truth", case["ground_truth"], "k-"), ("M2V1", case["height_field"], "r-")):
            ax.plot(np.linspace(-1, 1, d.shape[1]), d[d.shape[0] // 2], style, label=name)
        ax.set_title(f"centre slice y = 0, error {case['metrics']['rel_error']:.3f}", fontsize=8)
        ax.set_xlabel("x (scene units)")
        ax.legend(fontsize=6)
    fig.savefig(out / "fig7.png", dpi=100, bbox_inches="tight")


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument(
        "--experiment",
        default=EXPERIMENT,
        help="the MLflow experiment of the runs (e.g. 'starts': the same cases run by reproduce_starts)",
    )
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run_sweep(
            store,
            args.experiment,
            ["experiment=m2v1", f"operator={','.join(CASES)}", f"scene={','.join(SCENES)}", f"receiver.z={RECEIVER_Z}"],
            args.overrides,
            args.launcher,
        )
    cases = collect(store, args.experiment)
    if not cases:
        raise SystemExit(f"no finished Fig. 7 runs in {store.uri or store.directory}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(cases, args.out)
    write_figure(cases, args.out)
    print((args.out / "fig7.md").read_text())


if __name__ == "__main__":
    main()
