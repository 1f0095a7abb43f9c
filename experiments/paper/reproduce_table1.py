"""Reproduce the paper's Table 1 and Fig. 5: run the method presets (Hydra multirun), then build
the table from the MLflow store beside the paper's numbers.

    python -m experiments.paper.reproduce_table1                 # run all presets, then tabulate
    python -m experiments.paper.reproduce_table1 --table-only    # tabulate the latest run of each method
    python -m experiments.paper.reproduce_table1 --methods M1     # re-run one method, then tabulate
    python -m experiments.paper.reproduce_table1 --overrides photons=2097152

Writes table1.md, table1.csv and fig5_centre_slices.png into --out (default docs/results).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.paper.mlflow_store import artifact, latest_runs, reproduction_parser, run_sweep, tracking_store
from experiments.paper.tables import write_csv
from framework.scene.printed_shapes import make_shape

METHODS = ["M2V1", "M3V1", "M1", "M2V0", "M3V0", "M2V2", "M3V2"]
# Paper Table 1 (Titan RTX GPU): run time (min), rel. discrepancy, rel. error, iterations.
PAPER = {"M2V1": (2.95, 0.0504, 0.0648, 72), "M3V1": (2.77, 0.0505, 0.0658, 65), "M1": (6.62, 0.0549, 0.1800, 162),
         "M2V0": (4.72, 0.0600, 0.1086, 114), "M3V0": (4.38, 0.0598, 0.1065, 102)}
EXPERIMENT = "table1"


def final_metrics(run, client) -> dict:
    """The run's metrics.json artefact: the reported (returned) iterate. MLflow's latest value of a
    per-iteration metric is that of the last iteration, which differs after a stagnation stop."""
    return artifact(client, run, "metrics.json")


def write_table(runs: list, client, out: Path) -> list[dict]:
    rows = []
    for run in runs:
        method, metrics, params = run.data.tags["method"], final_metrics(run, client), run.data.params
        paper = PAPER.get(method, (None,) * 4)
        rows.append({
            "method": method, "run_time_min": metrics["run_time_s"] / 60.0,
            "rel_dis": metrics.get("rel_discrepancy"), "rel_err": metrics.get("rel_error"),
            "rel_err_d": metrics.get("rel_error_d"), "iter": int(metrics.get("iterations", 0)),
            "returned_iter": int(metrics.get("returned_iteration", metrics.get("iterations", 0))),
            "photon_traces": metrics.get("photon_traces"),
            "stop": str(metrics.get("stop_reason", "")).split(":")[0], "volume_ratio": metrics.get("volume_ratio"),
            "tau_dis": params.get("stopping.morozov.tau_dis"), "tau": params.get("solver.step_size.tau"),
            "paper_run_time_min": paper[0], "paper_rel_dis": paper[1], "paper_rel_err": paper[2],
            "paper_iter": paper[3]})
    write_csv(out / "table1.csv", rows)

    def fmt(v, spec):
        return "" if v is None else format(v, spec)

    lines = [
        "| method | stop | run time (min) | rel. dis. | rel. err. | rel. err. (d) | volume ratio | #iter (returned) "
        "| photon-traces (G) | tau_dis | paper: time | paper: dis. | paper: err. | paper: #iter |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['stop']} | {r['run_time_min']:.2f} | {r['rel_dis']:.4f} | {r['rel_err']:.4f} "
            f"| {r['rel_err_d']:.4f} | {fmt(r['volume_ratio'], '.3f')} | {r['iter']} ({r['returned_iter']}) "
            f"| {fmt(r['photon_traces'] and r['photon_traces'] / 1e9, '.3f')} | {r['tau_dis']} "
            f"| {fmt(r['paper_run_time_min'], '.2f')} "
            f"| {fmt(r['paper_rel_dis'], '.4f')} | {fmt(r['paper_rel_err'], '.4f')} "
            f"| {fmt(r['paper_iter'], 'd')} |"
        )
    (out / "table1.md").write_text("\n".join(lines) + "\n")
    return rows


def write_fig5(runs: list, client, out: Path) -> None:
    """Centre slices (y = 0) of the ground truth and each reconstruction, as in the paper's Fig. 5."""
    truth = make_shape("print_lines", 128)
    x = np.linspace(-1, 1, truth.shape[1])
    fig = Figure(figsize=(8, 4))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(x, truth[truth.shape[0] // 2], "k-", lw=2, label="ground truth")
    for run in runs:
        d = artifact(client, run, "height_field.npy")
        ax.plot(np.linspace(-1, 1, d.shape[1]), d[d.shape[0] // 2], label=run.data.tags["method"])
    ax.set_xlabel("x (scene units)")
    ax.set_ylabel("height d at y = 0 (scene units)")
    ax.legend(fontsize=8)
    fig.savefig(out / "fig5_centre_slices.png", dpi=120, bbox_inches="tight")


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="*", default=METHODS, choices=METHODS, help="methods to (re-)run")
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run_sweep(store, EXPERIMENT, [f"experiment={','.join(m.lower() for m in args.methods)}"], args.overrides,
                  args.launcher)
    chosen, client = latest_runs(store, EXPERIMENT, key=lambda run: run.data.tags.get("method"))
    runs = [chosen[m] for m in METHODS if m in chosen]
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(runs, client, args.out)
    write_fig5(runs, client, args.out)
    print((args.out / "table1.md").read_text())


if __name__ == "__main__":
    main()
