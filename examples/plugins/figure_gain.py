"""A figure script written as a plugin package would write one: how well one exact step recovers
the bump through the ``shadow`` operator at two gains (examples/plugins/shadow_operator.py).

    python -m examples.plugins.figure_gain --store mlruns --out figures      # sweep, then tabulate
    python -m examples.plugins.figure_gain --table-only                      # tabulate the latest runs

The pattern of every reproduction script (docs/plugins.md, "Adding a figure script"): one Hydra
multirun of sfc-reconstruct into an MLflow store (``run_sweep``), the latest finished run of each
case read back (``latest_runs``, ``artifact``), then a table and a figure from those runs alone.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from experiments.paper.mlflow_store import artifact, latest_runs, reproduction_parser, run_sweep, tracking_store

EXPERIMENT = "shadow-gain"
GAINS = (1.0, 4.0)
SEARCH_PATH = f"hydra.searchpath=[file://{Path(__file__).resolve().parent / 'conf'}]"
CASE = ["operator=shadow", "solver=exact_step", "~experiment", "+method=exact_step", "scene=bump",
        "height_field.resolution=16", "receiver.resolution=32", "data.delta=0.002", "data.reference_resolution=64"]


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        run_sweep(store, EXPERIMENT, [f"operator.gain={','.join(str(g) for g in GAINS)}"],
                  [SEARCH_PATH, *CASE, *args.overrides], args.launcher)
    chosen, client = latest_runs(store, EXPERIMENT, key=lambda run: float(run.data.params["operator.gain"]))
    rows = [(gain, artifact(client, chosen[gain], "metrics.json")) for gain in sorted(chosen)]
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ["| gain | rel. discrepancy | rel. error of d |", "|---|---|---|"]
    lines += [f"| {gain:g} | {m['rel_discrepancy']:.5f} | {m['rel_error_d']:.5f} |" for gain, m in rows]
    (args.out / "shadow_gain.md").write_text("\n".join(lines) + "\n")
    fig = Figure(figsize=(4, 3))
    ax = fig.add_subplot()
    ax.loglog([g for g, _ in rows], [m["rel_error_d"] for _, m in rows], "o-")
    ax.set_xlabel("operator gain")
    ax.set_ylabel("relative error of d")
    fig.savefig(args.out / "shadow_gain.png", dpi=100, bbox_inches="tight")
    print((args.out / "shadow_gain.md").read_text())


if __name__ == "__main__":
    main()
