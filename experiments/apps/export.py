"""sfc-export: the heights, the glass mesh and the deviation from the design of a reconstruction run,
in millimetres (framework/files/mm_outputs.py, docs/export.md).

Examples::

    sfc-export outputs/2026-01-05/14-03-12                     # glass.stl; design from the run
    sfc-export RUN --format stl obj ply --out prints/sample_a
    sfc-export RUN --design design.png --mm-per-unit 20        # a design file in scene units
    sfc-export RUN --design none

Reads RUN/height_field.npy and RUN/.hydra/config.yaml (substrate.thickness, substrate.half_width,
height_field, units.mm_per_unit) and writes into RUN/export unless --out is given; a run with a defect
report (defects.json) has it copied there and its verdict printed. An input error
(a missing run directory or file, a corrupt or truncated heights file or config, heights that are not
a square array of finite numbers, an --out that cannot be a directory) ends in one line on stderr and
exit status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from omegaconf import OmegaConf

from experiments.apps.input_errors import run_command
from framework.core.units import mm_per_unit
from framework.defects.fit import Defect
from framework.defects.report import defect_lines
from framework.files.height_field_io import load_height_field, read_npy, validate_heights
from framework.files.mm_outputs import MESH_FORMATS, export_outputs
from framework.scene.run_settings import design_given
from experiments.apps.configs import to_plain
from framework.scene.scene_config import build_heights, build_scene

INPUT_ERROR_STATUS = 2
RUN_FIX = "re-run the reconstruction or pass another run directory"


def parser() -> argparse.ArgumentParser:
    """The command line of sfc-export."""
    p = argparse.ArgumentParser(prog="sfc-export", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="directory of an sfc-reconstruct run")
    p.add_argument("--design", default="config", metavar="PATH|config|none",
                   help="config (default): the run's ground_truth.npy, else the configured height field when "
                        "the run gave it as the print's design (height_field.path, data.mask=design or "
                        "initial=design); none; or a .npy/.png height field in scene units")
    p.add_argument("--format", nargs="+", default=["stl"], choices=MESH_FORMATS, dest="formats",
                   help="mesh formats of the glass (default: stl)")
    p.add_argument("--refine", type=int, default=1, metavar="K",
                   help="the mesh's top samples the surface K times per sample spacing (default 1: the samples; "
                        "finer facets cast less of their pattern on a far screen)")
    p.add_argument("--out", type=Path, help="output directory (default: RUN_DIR/export)")
    p.add_argument("--mm-per-unit", type=float, help="mm per scene unit (default: the run's units.mm_per_unit)")
    return p


def _file(path: Path, what: str) -> Path:
    if not path.is_file():
        raise FileNotFoundError(f"{what} {str(path)!r} does not exist; pass the directory of an sfc-reconstruct run")
    return path


def _heights(path: Path, fix: str = RUN_FIX) -> np.ndarray:
    """The heights (m, m) in the .npy ``path``, refused in one line naming the file when it is
    corrupt or truncated, or not a square array (m >= 2) of finite numbers."""
    d = read_npy(path, fix)
    validate_heights(path, d, fix, nonnegative=False)
    return d


def _run_config(path: Path) -> dict[str, Any]:
    """The run's resolved config (a mapping), refused in one line when it is not readable YAML."""
    try:
        cfg = to_plain(OmegaConf.load(path))
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ValueError(f"run config {str(path)!r} is not readable YAML{where}; {RUN_FIX}") from None
    if not isinstance(cfg, Mapping):
        raise ValueError(f"run config {str(path)!r} is not a mapping of config keys; {RUN_FIX}")
    return cfg


def _output_dir(out: Path, what: str) -> Path:
    """``out``, made a directory, or refused in one line naming it as ``what`` (``--out``, or the
    default output directory) when it cannot be one: it or a folder above it is a regular file, or
    it is not writable."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        blocker = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
        reason = f"{str(blocker)!r} is a file" if blocker is not None else error.strerror or str(error)
        raise ValueError(f"{what} {str(out)!r} cannot be made a directory ({reason}); pass --out a directory "
                         "path that is not a file or under one") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {str(out)!r} is not writable; pass --out a directory you can write to")
    return out


def _launch_dir(run_dir: Path) -> Path:
    """Where the run was started (Hydra's runtime.cwd), which the config's relative paths are
    relative to; the current directory when the run does not say."""
    hydra_file = run_dir / ".hydra" / "hydra.yaml"
    cwd = OmegaConf.select(OmegaConf.load(hydra_file), "hydra.runtime.cwd") if hydra_file.is_file() else None
    return Path(cwd) if cwd else Path.cwd()


def load_design(spec: str, run_dir: Path, cfg: Mapping[str, Any], m: int) -> tuple[np.ndarray | None, str]:
    """The design (m, m), scene units, and where it came from, for ``--design`` ``spec``."""
    if spec == "none":
        return None, "none"
    if spec != "config":
        if not Path(spec).is_file():
            raise FileNotFoundError(f"--design {spec!r} is not a file; pass a .npy/.png height field in scene "
                                    "units, config or none")
        return load_height_field(spec, resolution=m), spec
    if (cfg.get("data") or {}).get("printed"):  # synthetic data of another print: the config is its design
        return build_heights(
            cfg, base_dir=_launch_dir(run_dir)
        ).numpy(), "the run's height_field (data.printed's design)"
    truth = run_dir / "ground_truth.npy"
    if truth.is_file():
        return _heights(truth, f"{RUN_FIX}, or pass --design none or a design file"), str(truth)
    if design_given(cfg):
        return build_heights(cfg, base_dir=_launch_dir(run_dir)).numpy(), "the run's height_field"
    return None, ("none (the run has no ground truth, and its height field was not given as the print's design: "
                  "height_field.path, data.mask=design or initial=design)")


def export_run(args: argparse.Namespace) -> None:
    """Write the mm outputs of ``args.run_dir`` and print the files and the deviation metrics."""
    run_dir: Path = args.run_dir
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run directory {str(run_dir)!r} does not exist; pass the directory of an "
                                "sfc-reconstruct run (it holds height_field.npy and .hydra/config.yaml)")
    d = _heights(_file(run_dir / "height_field.npy", "heights"))
    cfg = _run_config(_file(run_dir / ".hydra" / "config.yaml", "run config"))
    substrate = build_scene(cfg).substrate
    scale = mm_per_unit(cfg) if args.mm_per_unit is None else args.mm_per_unit
    design, source = load_design(args.design, run_dir, cfg, d.shape[0])
    out = _output_dir(args.out, "--out") if args.out else _output_dir(run_dir / "export", "output directory")
    result = export_outputs(out, d, substrate.half_width, substrate.thickness, scale, design=design,
                            formats=args.formats, refine=args.refine)
    print(f"{scale:g} mm per scene unit; design: {source}")
    for path in result["files"]:
        print(f"wrote {path}")
    for key, value in result["deviation"].items():
        print(f"deviation {key} = {'n/a' if value is None else f'{value:.6g}'}")
    copy_defect_report(run_dir, out)


def copy_defect_report(run_dir: Path, out: Path) -> None:
    """The run's defect report (defects.json, .csv, .png; framework/defects/defect_stage.py) copied
    into ``out`` and its verdict printed; nothing when the run has none."""
    report = run_dir / "defects.json"
    if not report.is_file():
        return
    for name in ("defects.json", "defects.csv", "defects.png"):
        if (run_dir / name).is_file() and (run_dir / name).resolve() != (out / name).resolve():
            shutil.copyfile(run_dir / name, out / name)
            print(f"wrote {out / name}")
    saved = json.loads(report.read_text())
    defects = [Defect(**{**item, "params": tuple(item["params"])}) for item in saved["defects"]]
    settings = saved["settings"]
    for line in defect_lines(defects, float(saved.get("defects_evidence_needed", settings["min_evidence"])),
                             int(saved.get("defects_within_tolerance", 0)), float(settings.get("tolerance", 0.0)),
                             float(settings.get("tolerance_mm", 0.0))):
        print(f"verdict: {line}")


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: an input error ends in its one line (experiments/apps/input_errors.py) and
    exit status 2."""
    run_command(export_run, parser().parse_args(argv), INPUT_ERROR_STATUS)


if __name__ == "__main__":
    main()
