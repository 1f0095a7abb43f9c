"""Starts side by side: M2V1 from flat glass and from the data-chosen start on every built-in
height-field scene (print_lines, oblique_lines, bump, gaussian, letter_a) and on Fig. 7's four
cases (print_lines and bump with the receiver at z = -1, through the two lenses and without
them). Runs them as multiruns into one MLflow experiment, then rebuilds the table and the figure
from the store: error, discrepancy, error relative to d, iterations, stop reason, wall time.

    python -m experiments.paper.reproduce_starts                       # everything (about an hour on 2 cores)
    python -m experiments.paper.reproduce_starts --starts zero,transport --part scenes --scenes gaussian,bump
    python -m experiments.paper.reproduce_starts --starts auto --part fig7   # auto's first run is the flat-glass one
    python -m experiments.paper.reproduce_starts --table-only          # table and figure from the latest runs

Writes starts.md, starts.csv and starts.png into --out (default docs/results).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.paper.mlflow_store import (TrackingStore, artifact, latest_runs, reproduction_parser, run_sweep,
                                      tracking_store)
from experiments.paper.tables import write_csv
from framework.files.plotting import show_panel

EXPERIMENT = "starts"
SCENES = ("print_lines", "oblique_lines", "bump", "gaussian", "letter_a")
FIG7_SCENES = ("print_lines", "bump")
FIG7_RECEIVER_Z = -1.0


def parts(scenes: str, fig7_scenes: str) -> dict[str, list[str]]:
    """The sweeps: the height-field scenes at the default receiver, and Fig. 7's cases."""
    return {"scenes": ["experiment=m2v1", "operator=height_field", f"scene={scenes}"],
            "fig7": ["experiment=m2v1", "operator=two_lenses,height_field", f"scene={fig7_scenes}",
                     f"receiver.z={FIG7_RECEIVER_Z}"]}


def case_of(run) -> tuple[str, str, str]:
    """(setup, scene, start) of a run: the setup names the optics and the receiver distance."""
    params = run.data.params
    optics = "two lenses" if params.get("operator.elements", "[]") not in ("[]", "None", None) else "no lenses"
    setup = f"{optics}, z = {float(params.get('receiver.z', -0.05)):g}"
    return setup, run.data.tags.get("scene", ""), params.get("initial.name", "zero")


def collect(store: TrackingStore) -> dict[tuple[str, str, str], dict]:
    """Per (setup, scene, start): the latest finished run's metrics, heights and ground truth."""
    chosen, client = latest_runs(store, EXPERIMENT, key=case_of)
    return {key: {name: artifact(client, run, f"{name}.{ext}") for name, ext in (
        ("metrics", "json"), ("height_field", "npy"), ("ground_truth", "npy"))} for key, run in sorted(chosen.items())}


def runs_of(metrics: dict) -> str:
    """Each start an ``auto`` run tried: 'name: [error /] discrepancy (iterations, noise level reached?)'."""
    names = [k[len("start_"):-len("_reached_noise_level")] for k in metrics if k.endswith("_reached_noise_level")]
    error = {n: f"{metrics[f'start_{n}_rel_error']:.4f} / " if f"start_{n}_rel_error" in metrics else "" for n in names}
    return "; ".join(
        f"{n}: {error[n]}{metrics[f'start_{n}_rel_discrepancy']:.4f} ({metrics[f'start_{n}_iterations']} it., "
        f"{'noise level' if metrics[f'start_{n}_reached_noise_level'] else 'short of it'})"
        for n in names
    )


def write_table(cases: dict[tuple[str, str, str], dict], out: Path) -> None:
    """starts.csv and starts.md: one row per (setup, scene, start)."""
    rows = []
    for (setup, scene, start), case in cases.items():
        m = case["metrics"]
        rows.append({"setup": setup, "scene": scene, "start": start, "chosen": m.get("start", start),
                     "rel_err": m["rel_error"], "rel_dis": m["rel_discrepancy"], "rel_err_d": m["rel_error_d"],
                     "iterations": m["iterations"], "stopped_by": m["stopped_by"],
                     "volume_ratio": m.get("volume_ratio", float("nan")),
                     "wall_s": m.get("start_time_s", 0.0) + m["run_time_s"], "runs": runs_of(m)})
    write_csv(out / "starts.csv", rows)
    lines = [
        "| setup | scene | start (chosen) | rel. err. | rel. dis. | rel. err. (d) | #iter | stopped by "
        "| volume ratio | wall time (s) | runs of auto: [error /] dis. |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {r['setup']} | {r['scene']} | {r['start']}"
              + (f" ({r['chosen']})" if r["chosen"] != r["start"] else "")
              + f" | {r['rel_err']:.4f} | {r['rel_dis']:.4f} | {r['rel_err_d']:.4f} | {r['iterations']} "
              f"| {r['stopped_by']} | {r['volume_ratio']:.3f} | {r['wall_s']:.0f} | {r['runs']} |" for r in rows]
    (out / "starts.md").write_text("\n".join(lines) + "\n")


def write_figure(cases: dict[tuple[str, str, str], dict], out: Path) -> None:
    """starts.png: per (setup, scene) the ground truth and each start's reconstruction, one height
    scale, and their centre slices y = 0."""
    groups: dict[tuple[str, str], dict[str, dict]] = {}
    for (setup, scene, start), case in cases.items():
        groups.setdefault((setup, scene), {})[start] = case
    starts = sorted({start for (_, _, start) in cases})
    columns = len(starts) + 2
    fig = Figure(figsize=(3.4 * columns, 3.2 * len(groups)))
    fig.subplots_adjust(hspace=0.45)
    for row, ((setup, scene), runs) in enumerate(groups.items()):
        truth = next(iter(runs.values()))["ground_truth"]
        top = max([float(truth.max())] + [float(r["height_field"].max()) for r in runs.values()])
        show_panel(fig.add_subplot(len(groups), columns, columns * row + 1), f"{scene}, {setup}: truth", truth,
                   False, top)
        slices = fig.add_subplot(len(groups), columns, columns * (row + 1))
        x = np.linspace(-1, 1, truth.shape[1])
        slices.plot(x, truth[truth.shape[0] // 2], "k-", label="truth")
        for col, start in enumerate(starts):
            if start not in runs:
                continue
            d, error = runs[start]["height_field"], runs[start]["metrics"]["rel_error"]
            show_panel(fig.add_subplot(len(groups), columns, columns * row + col + 2),
                       f"start {start}: error {error:.3f}", d, False, top)
            slices.plot(x, d[d.shape[0] // 2], label=start)
        slices.set_title("centre slice y = 0", fontsize=8)
        slices.set_xlabel("x (scene units)")
        slices.legend(fontsize=6)
    fig.savefig(out / "starts.png", dpi=90, bbox_inches="tight")


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument("--starts", default="zero,auto", help="the starts compared (conf/initial/ names)")
    parser.add_argument("--part", choices=["scenes", "fig7", "all"], default="all", help="scenes, fig7 or all")
    parser.add_argument("--scenes", default=",".join(SCENES), help="the height-field scenes (a quick subset)")
    parser.add_argument("--fig7-scenes", default=",".join(FIG7_SCENES), help="the scenes of Fig. 7's cases")
    args = parser.parse_args(argv)
    store = tracking_store(args)
    if not args.table_only:
        sweeps = parts(args.scenes, args.fig7_scenes)
        for part in sweeps if args.part == "all" else [args.part]:
            run_sweep(store, EXPERIMENT, [*sweeps[part], f"initial={args.starts}"], args.overrides, args.launcher)
    cases = collect(store)
    if not cases:
        raise SystemExit(f"no finished runs of '{EXPERIMENT}' in {store.uri or store.directory}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(cases, args.out)
    write_figure(cases, args.out)
    print((args.out / "starts.md").read_text())


if __name__ == "__main__":
    main()
