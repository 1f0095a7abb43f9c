"""Which beads one photo leaves undecided, on every built-in scene and a held-out print of three
beads, with the check (framework/tracks/ambiguity.py) on and off in one sitting: the default run
(M2V1, one photo at 1.25 mm, 5% noise on exact caustics). Writes docs/results/ambiguity.md and
ambiguity.csv (docs/results.md, "Beads without a design").

    python -m experiments.paper.reproduce_ambiguity OUT
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from experiments.paper.tables import write_csv

SCENES = ("print_lines", "oblique_lines", "bump", "gaussian", "letter_a")
MM = 25.0  # mm per scene unit: the grid spans [-25, 25] mm
HELD_OUT = (((-15.0, -8.0), (15.0, -8.0), 1.0, 0.45),  # (start, end mm, chord width, height mm)
            ((-15.0, 6.0), (12.0, 14.0), 1.4, 0.6),
            ((-5.0, -18.0), (-5.0, 18.0), 2.5, 0.6))


def held_out_print(resolution: int = 128) -> np.ndarray:
    """(m, m) scene units: three straight beads of circular section (chord width, height), one
    diagonal, none of them a shape the model or the check was built on."""
    axis = np.linspace(-MM, MM, resolution)
    x, y = np.meshgrid(axis, axis)
    heights = np.zeros_like(x)
    for start, end, width, height in HELD_OUT:
        (x0, y0), (x1, y1) = start, end
        along = np.clip(((x - x0) * (x1 - x0) + (y - y0) * (y1 - y0)) / ((x1 - x0) ** 2 + (y1 - y0) ** 2), 0.0, 1.0)
        distance = np.hypot(x - x0 - along * (x1 - x0), y - y0 - along * (y1 - y0))  # to the segment, mm
        radius = (width**2 / 4.0 + height**2) / (2.0 * height)
        inside = distance < width / 2.0
        section = np.sqrt(np.clip(radius**2 - distance**2, 0.0, None)) - (radius - height)
        heights = np.maximum(heights, np.where(inside, section, 0.0))
    return heights / MM


def _run(out: Path, name: str, overrides: list[str]) -> dict:
    """One sfc-reconstruct run into out/name (kept where done): its metrics and wall seconds."""
    folder = out / name
    if not (folder / "metrics.json").is_file():
        began = time.perf_counter()
        subprocess.run([sys.executable, "-m", "experiments.apps.reconstruct", *overrides, f"hydra.run.dir={folder}",
                        f"tracking.store_dir={out / 'mlruns'}"], check=True)
        (folder / "wall_s.txt").write_text(f"{time.perf_counter() - began:.1f}")
    metrics = json.loads((folder / "metrics.json").read_text())
    metrics["wall_s"] = float((folder / "wall_s.txt").read_text())
    return metrics


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for the runs")
    parser.add_argument("--results", type=Path, default=Path("docs/results"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    held_out = args.out / "held_out.npy"
    np.save(held_out, held_out_print())
    cases = {scene: [f"scene={scene}"] for scene in SCENES}
    cases["three beads (held out)"] = ["scene=print_lines", f"height_field.path={held_out}"]
    rows = []
    for label, overrides in cases.items():
        on, off = (_run(args.out, f"{label.split(' ')[0]}_{state}", [*overrides, f"ambiguity.enabled={state}"])
                   for state in ("true", "false"))
        rows.append({"print": label, "rel_error": on["rel_error"], "rel_error_d": on["rel_error_d"],
                     "discrepancy_over_delta": on["rel_discrepancy"] / on["delta"], "solve_s_on": on["run_time_s"],
                     "solve_s_off": off["run_time_s"], "check_s": on.get("ambiguity_time_s", 0.0),
                     "wall_s_on": on["wall_s"], "wall_s_off": off["wall_s"],
                     "same_heights": on["rel_error_d"] == off["rel_error_d"], "check": on.get("ambiguity", "")})
    args.results.mkdir(parents=True, exist_ok=True)
    write_csv(args.results / "ambiguity.csv", rows)
    lines = ["| print | rel. err. | err. (d) | dis. / delta | solving s, on / off | check s | wall s, on / off | "
             "same heights | the check |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['print']} | {r['rel_error']:.4f} | {r['rel_error_d']:.3f} | {r['discrepancy_over_delta']:.2f} | "
              f"{r['solve_s_on']:.1f} / {r['solve_s_off']:.1f} | {r['check_s']:.1f} | {r['wall_s_on']:.0f} / "
              f"{r['wall_s_off']:.0f} | {'yes' if r['same_heights'] else 'no'} | {r['check']} |" for r in rows]
    (args.results / "ambiguity.md").write_text(
        "# Undecided beads\n\n`python -m experiments.paper.reproduce_ambiguity OUT`; one photo, exact caustics, "
        "5% noise (docs/results.md, \"Beads without a design\").\n\n" + "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
