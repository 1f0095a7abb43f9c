"""The defect benchmark: prints with defects of known kind, place and size made from every built-in
design (experiments/paper/defect_prints.py), and prints equal to their design, reconstructed with
``experiment=design`` (or ``--method tracks``: ``experiment=tracks``, the beads along each design's
skeleton) from their exact caustics (wavefront triangles, not the model's splats) at 2%, 5% and 10% noise,
as multiruns into one MLflow experiment; then the table and the figure from the store:
recall by kind and size, false alarms per print, the smallest defect found per kind and noise, the
errors of the found defects' places and sizes.

    python -m experiments.paper.reproduce_defects                      # everything (about 65 min on 2 cores)
    python -m experiments.paper.reproduce_defects --scenes print_lines --deltas 0.05
    python -m experiments.paper.reproduce_defects --table-only
    python -m experiments.paper.reproduce_defects --method tracks --deltas 0.05  # the designs of beads (about 25 min)

Writes defects.md, defects.csv and defects.png (defects_tracks.* with --method tracks) into --out
(default docs/results); the prints and
their planned defects into --prints (default outputs/defect_prints).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.apps.configs import reconstruct_config
from experiments.paper.defect_prints import apply_defect, feature_sites
from experiments.paper.mlflow_store import (TrackingStore, artifact, latest_runs, reproduction_parser, run_sweep,
                                      tracking_store)
from experiments.paper.tables import write_csv
from framework.scene.scene_config import build_heights

# --method: (MLflow experiment, the runs' preset, the outputs' file stem)
METHODS = {"design": ("defects", "experiment=design", "defects"),
           "tracks": ("defects_tracks", "experiment=tracks", "defects_tracks")}
BEAD_SCENES = ("print_lines", "oblique_lines", "gaussian", "letter_a")  # --method tracks: bump has no bead to follow
SCENES = ("print_lines", "oblique_lines", "bump", "gaussian", "letter_a")
MATCH_MM = 3.0  # a reported defect within this distance (plus half the planned length) of a planned one found it
SPACING_MM = 14.0  # planned defects of one print at least this far apart
# Each print: (kind, size, length in mm). The first two are also run at 2% and 10% noise.
PRINTS: tuple[tuple[tuple[str, float, float], ...], ...] = (
    (),
    (("interruption", 1.0, 1.0), ("too_low", 0.2, 3.0), ("excess", 0.3, 0.0)),
    (("interruption", 1.0, 2.0), ("displaced", 0.5, 6.0), ("too_high", -0.2, 6.0)),
    (),
    (("interruption", 1.0, 0.5), ("excess", 1.0, 0.0), ("too_wide", 0.3, 6.0)),
    (("displaced", 1.0, 6.0), ("too_narrow", -0.3, 6.0), ("too_low", 0.4, 10.0)),
    (("excess", 0.1, 0.0), ("too_high", -0.1, 2.0), ("interruption", 1.0, 3.0)),
    (("displaced", 0.2, 6.0), ("too_wide", 0.2, 6.0), ("too_low", 0.1, 2.0)),
)
SHORT = 2  # prints run at every noise level


def make_prints(scene: str, folder: Path, seed: int) -> list[Path]:
    """Write the prints of ``scene`` (``<scene>_<i>.npy``, scene units, with ``.json``: the planned defects)."""
    cfg = reconstruct_config([f"scene={scene}"])
    design = build_heights(cfg).numpy()
    mm = float(cfg["units"]["mm_per_unit"])
    cell_mm = 2.0 * float(cfg["substrate"]["half_width"]) / (design.shape[0] - 1) * mm
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for index, plan in enumerate(PRINTS):
        rng = np.random.default_rng(seed + 100 * index + SCENES.index(scene) if scene in SCENES else seed)
        sites = feature_sites(design, cell_mm, len(plan), SPACING_MM, rng)
        printed, planned = design.copy(), []
        for site, (kind, size, length) in zip(sites, plan):
            printed, defect = apply_defect(design, printed, site, kind, size, length, cell_mm, mm)
            planned.append(defect.as_dict())
        path = folder / f"{scene}_{index}.npy"
        np.save(path, printed)
        path.with_suffix(".json").write_text(json.dumps({"scene": scene, "defects": planned}, indent=1))
        files.append(path)
    return files


def case_of(run) -> tuple[str, str, float]:
    """(scene, print file, noise level) of a run."""
    params = run.data.params
    return run.data.tags.get("scene", ""), Path(params.get("data.printed", "")).name, float(params.get("data.delta", 0))


def collect(store: TrackingStore, prints: Path, experiment: str) -> dict[tuple[str, str, float], dict]:
    """Per case: the latest finished run's defects.json and metrics, and the planned defects."""
    chosen, client = latest_runs(store, experiment, key=case_of)
    out = {}
    for key, run in sorted(chosen.items()):
        plan = prints / Path(key[1]).with_suffix(".json").name
        if not plan.is_file():
            continue
        out[key] = {"report": artifact(client, run, "defects.json"), "metrics": artifact(client, run, "metrics.json"),
                    "planned": json.loads(plan.read_text())["defects"]}
    return out


def size_error(planned: dict, found: dict) -> float:
    """|found / planned - 1| of the kind's measure (interruptions: their length)."""
    if planned["kind"] == "interruption":
        return abs(found["length_mm"] / planned["length_mm"] - 1.0)
    return abs(abs(found["size"]) / abs(planned["size"]) - 1.0)


def match(case: dict) -> tuple[list[dict], int]:
    """Every planned defect with what was found of it, and the number of false alarms."""
    found = list(case["report"]["defects"])
    rows, used = [], set()
    for planned in case["planned"]:
        best, gap = None, MATCH_MM + 0.5 * planned["length_mm"]
        for i, defect in enumerate(found):
            distance = math.hypot(defect["x_mm"] - planned["x_mm"], defect["y_mm"] - planned["y_mm"])
            if i not in used and distance <= gap:
                best, gap = i, distance
        row = {**planned, "found": best is not None, "kind_found": None, "position_error_mm": None,
               "size_error": None}
        if best is not None:
            used.add(best)
            row.update(kind_found=found[best]["kind"], position_error_mm=gap,
                       size_error=size_error(planned, found[best]) if found[best]["kind"] == planned["kind"] else None)
        rows.append(row)
    return rows, len(found) - len(used)


def label(row: dict) -> str:
    """A planned defect's size in words: '1 mm', '-20% / 3 mm', '0.3 mm3', '0.5 mm', '+30%'."""
    kind, size, length = row["kind"], row["size"], row["length_mm"]
    if kind == "interruption":
        return f"{length:g} mm"
    if kind in ("too_low", "too_high"):
        return f"{-100 * size:+.0f}% / {length:g} mm"
    if kind == "excess":
        return f"{size:g} mm3"
    if kind == "displaced":
        return f"{size:g} mm"
    return f"{100 * size:+.0f}%"


def write_outputs(cases: dict, out: Path, method: str = "design") -> None:
    """<stem>.csv (one row per planned defect), <stem>.md (recall by kind and size per noise level,
    false alarms per print, errors of place and size, the heights' error) and <stem>.png."""
    _, preset, stem = METHODS[method]
    rows, alarms, heights = [], defaultdict(list), defaultdict(list)
    for (scene, name, delta), case in cases.items():
        matched, false = match(case)
        alarms[delta].append(false)
        heights[delta].append(float(case["metrics"].get("rel_error_d", float("nan"))))
        for row in matched:
            rows.append({"scene": scene, "print": name, "delta": delta, **row})
    write_csv(out / f"{stem}.csv", rows, empty_header=["scene"])
    lines = [
        "# Defects against the design: recall, false alarms, place and size",
        "",
        f"`python -m experiments.paper.reproduce_defects --method {method}`; `{preset}` on exact caustics "
        "(wavefront triangles) of "
        "prints with planned defects (experiments/paper/defect_prints.py). A planned defect counts as found when a "
        f"reported defect lies within {MATCH_MM:g} mm plus half its length of its centre; every reported defect "
        "that found none is a false alarm.",
        "",
    ]
    for delta in sorted({r["delta"] for r in rows} | set(alarms)):
        chosen = [r for r in rows if r["delta"] == delta]
        prints = len(alarms[delta])
        lines += [
            f"## {100 * delta:g}% noise: {prints} prints, {sum(alarms[delta])} false alarm(s) "
            f"({sum(alarms[delta]) / max(prints, 1):.2f} per print)",
            "",
            "| kind | size | planned | found, right kind | found, other kind "
            "| position error mm (mean) | size error (mean) |",
            "|---|---|---|---|---|---|---|",
        ]
        groups = defaultdict(list)
        for r in chosen:
            groups[(r["kind"], label(r))].append(r)
        for (kind, size), group in sorted(groups.items()):
            right = [r for r in group if r["found"] and r["kind_found"] == kind]
            other = [r for r in group if r["found"] and r["kind_found"] != kind]
            pos = np.mean([r["position_error_mm"] for r in right]) if right else float("nan")
            err = [r["size_error"] for r in right if r["size_error"] is not None]
            lines.append(f"| {kind} | {size} | {len(group)} | {len(right)} | "
                         f"{', '.join(sorted(r['kind_found'] for r in other)) or 0} | {pos:.2f} | "
                         f"{np.mean(err) if err else float('nan'):.2f} |")
        lines += ["", key_class_recall(chosen), smallest_found(chosen),
                  f"Heights' relative error (d) over the prints: median {np.nanmedian(heights[delta]):.3f}, "
                  f"largest {np.nanmax(heights[delta]):.3f}.", ""]
    (out / f"{stem}.md").write_text("\n".join(lines))
    write_figure(rows, out / f"{stem}.png")


KEY_CLASSES = {  # the defects a print engineer must not miss, as (name, test of a planned defect)
    "interruptions >= 1 mm": lambda r: r["kind"] == "interruption" and r["length_mm"] >= 1.0,
    "height errors >= 20% over >= 3 mm": lambda r: r["kind"] in ("too_low", "too_high") and abs(r["size"]) >= 0.2
    and r["length_mm"] >= 3.0,
    "drops >= 0.3 mm3": lambda r: r["kind"] == "excess" and r["size"] >= 0.3,
    "displacements >= 0.5 mm": lambda r: r["kind"] == "displaced" and r["size"] >= 0.5,
}


def key_class_recall(rows: list[dict]) -> str:
    """'Found with the right kind: interruptions >= 1 mm 5/5, ...' for one noise level."""
    parts = []
    for name, test in KEY_CLASSES.items():
        chosen = [r for r in rows if test(r)]
        parts.append(f"{name} {sum(r['found'] and r['kind_found'] == r['kind'] for r in chosen)}/{len(chosen)}")
    return "Found with the right kind: " + "; ".join(parts) + "."


def smallest_found(rows: list[dict]) -> str:
    """The smallest planned defect of each kind found with the right kind."""
    parts = []
    for kind in sorted({r["kind"] for r in rows}):
        found = [r for r in rows if r["kind"] == kind and r["found"] and r["kind_found"] == kind]
        if found:
            smallest = min(found, key=lambda r: abs(r["size"]) * r["length_mm"] if kind != "excess" else r["size"])
            parts.append(f"{kind} {label(smallest)}")
        else:
            parts.append(f"{kind} none")
    return "Smallest found: " + "; ".join(parts) + "."


def write_figure(rows: list[dict], path: Path) -> None:
    """Recall (right kind) by kind at each noise level."""
    kinds = sorted({r["kind"] for r in rows})
    deltas = sorted({r["delta"] for r in rows})
    fig = Figure(figsize=(9, 4))
    ax = fig.add_subplot()
    width = 0.8 / max(len(deltas), 1)
    for k, delta in enumerate(deltas):
        recall = []
        for kind in kinds:
            group = [r for r in rows if r["delta"] == delta and r["kind"] == kind]
            recall.append(sum(r["found"] and r["kind_found"] == kind for r in group) / max(len(group), 1))
        ax.bar(np.arange(len(kinds)) + k * width, recall, width, label=f"{100 * delta:g}% noise")
    ax.set_xticks(np.arange(len(kinds)) + 0.4 - width / 2, kinds, rotation=20)
    ax.set_ylabel("recall (right kind)")
    ax.set_ylim(0, 1.05)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> None:
    parser = reproduction_parser(__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=None, help="the designs (built-in scenes; default: all, "
                                                      f"with --method tracks {','.join(BEAD_SCENES)})")
    parser.add_argument("--deltas", default="0.02,0.05,0.1", help="noise levels; all prints run at 0.05, the first "
                                                                   f"{SHORT} at the others")
    parser.add_argument("--prints", type=Path, default=Path("outputs/defect_prints"), help="where the prints go")
    parser.add_argument("--seed", type=int, default=0, help="seed of the defects' places")
    parser.add_argument("--method", choices=sorted(METHODS), default="design",
                        help="design: M2D (experiment=design); tracks: M2T along each design's skeleton")
    args = parser.parse_args(argv)
    experiment, preset, stem = METHODS[args.method]
    scenes = args.scenes.split(",") if args.scenes else list(BEAD_SCENES if args.method == "tracks" else SCENES)
    store = tracking_store(args)
    prints = args.prints.resolve()
    if not args.table_only:
        deltas = [float(x) for x in args.deltas.split(",")]
        files = {scene: make_prints(scene, prints, args.seed) for scene in scenes}
        # every print at 5% noise first (the targets), then the first ones at the other levels
        for levels, count in (
            ([d for d in deltas if d == 0.05], len(PRINTS)),
            ([d for d in deltas if d != 0.05], SHORT),
        ):
            for scene, chosen in files.items():
                if levels:
                    run_sweep(store, experiment, [preset, f"scene={scene}",
                                                  f"data.printed={','.join(str(f) for f in chosen[:count])}",
                                                  f"data.delta={','.join(str(x) for x in levels)}"],
                              args.overrides, args.launcher)
    cases = collect(store, prints, experiment)
    if not cases:
        raise SystemExit(f"no finished runs of '{experiment}' in {store.uri or store.directory}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_outputs(cases, args.out, args.method)
    print((args.out / f"{stem}.md").read_text())


if __name__ == "__main__":
    main()
