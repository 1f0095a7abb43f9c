"""sfc-rig: the lab's bench saved once as a config (``rig=<name>``), so that a print needs only its
photo and design (docs/photo_import.md, "The rig").

Examples::

    sfc-rig init my_bench --markers screen_markers.json --marker-photo bare.dng --flat flat.dng \\
        --lens lens.json --light-mm 250 --substrate-mm 2.5 --screen-mm 1.25 --screen-sigma-mm 0.25
    sfc-reconstruct rig=my_bench data.photo=print.dng height_field.path=design.png data.volume=1.7mm3

``init`` checks every file (the markers are found in the marker photo and in the flat field, the
lens fits their size, the sheet frames the scene's receiver) and writes sfc_conf/rig/<name>.yaml
with absolute paths; sfc-reconstruct finds it there when run from the same directory (its config
search path, conf/reconstruct.yaml). An input error ends in one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

import yaml

import conf
from experiments.apps.configs import reconstruct_config
from experiments.apps.input_errors import run_command
from framework.lab.lens import LensModel
from framework.lab.photo_import import read_photo
from framework.lab.screen_markers import MarkerSheet, detect_receiver

INPUT_ERROR_STATUS = 2
CONFIG_ROOT = Path(conf.USER_CONFIGS)  # on the config search path of conf/reconstruct.yaml


def parser() -> argparse.ArgumentParser:
    """The command line of sfc-rig."""
    p = argparse.ArgumentParser(prog="sfc-rig", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = p.add_subparsers(dest="command", required=True)
    init = commands.add_parser("init", help="check the bench's files and write its rig config")
    init.add_argument("name", help="the rig's name, used as rig=<name>")
    init.add_argument("--markers", type=Path, required=True, help="the marker sheet's layout (sfc-markers)")
    init.add_argument("--marker-photo", type=Path, help="a photo of the screen on the bench: its markers are checked")
    init.add_argument("--flat", type=Path, help="the flat field: a photo of the screen, same camera and exposure")
    init.add_argument("--flat-kind", default="uniform", choices=("uniform", "substrate"),
                      help="what the flat field shows: the evenly lit screen (uniform, default) or the bare "
                           "substrate's caustic (substrate)")
    init.add_argument("--lens", type=Path, help="the lens calibration (sfc-lens calibrate)")
    init.add_argument("--light-mm", type=float, required=True, help="the light's height above the glass's top (mm)")
    init.add_argument("--substrate-mm", type=float, required=True, help="the substrate's thickness (mm)")
    init.add_argument("--screen-mm", type=float, required=True, help="the screen's distance below the substrate (mm)")
    init.add_argument("--wavelength-um", type=float, default=0.525, help="the filter's wavelength (um; default 0.525)")
    init.add_argument("--screen-sigma-mm", type=float, help="the screen's blur (mm; sfc-calibrate-screen)")
    init.add_argument("--channel", default="green", choices=("grey", "red", "green", "blue"),
                      help="the photo's channel (default green, a 525 nm filter)")
    init.add_argument("--mm-per-unit", type=float, default=25.0, help="mm per scene unit (default 25)")
    init.add_argument("--config-root", type=Path, default=CONFIG_ROOT, help="where rig/<name>.yaml goes")
    return p


def _checked_photo(path: Path, what: str, sheet: MarkerSheet, lens: LensModel | None) -> str:
    """The markers' fit in one photo of the bench, as the import will see it."""
    values, _ = read_photo(path)
    if lens is not None:
        values = lens.undistort(values, f"{what} {path.name}")
    return detect_receiver(values, sheet, f"{what} {path.name}").describe(sheet)


def rig_config(args: argparse.Namespace) -> dict:
    """The rig's config (plain data) from checked arguments."""
    for flag, value in (("--light-mm", args.light_mm), ("--substrate-mm", args.substrate_mm),
                        ("--screen-mm", args.screen_mm), ("--wavelength-um", args.wavelength_um),
                        ("--mm-per-unit", args.mm_per_unit)):
        if not value > 0:
            raise ValueError(f"{flag} {value:g} must be > 0")
    sheet = MarkerSheet.load(args.markers)
    half_width = float(reconstruct_config([])["receiver"]["half_width"])  # scene units (conf/scene/)
    receiver_mm = 2 * half_width * args.mm_per_unit
    sheet.check_frames(receiver_mm, f"--markers {args.markers}",
                       f"2 receiver.half_width at --mm-per-unit {args.mm_per_unit:g}",
                       f"give --mm-per-unit {sheet.receiver_mm / (2 * half_width):g} or print a sheet for "
                       f"{receiver_mm:g} mm")
    lens = LensModel.load(args.lens) if args.lens else None
    for path, what in ((args.marker_photo, "marker photo"), (args.flat, "flat field")):
        if path is not None:
            print(f"{what} {path.name}: {_checked_photo(path, what, sheet, lens)}")
    data = {"markers": str(args.markers.resolve()), "lens": str(args.lens.resolve()) if args.lens else None,
            "flat": str(args.flat.resolve()) if args.flat else None, "flat_kind": args.flat_kind,
            "channel": args.channel}
    config = {"defaults": [{"override /data": "photo"}], "data": data, "units": {"mm_per_unit": args.mm_per_unit},
              "light": {"position": [0, 0, f"{args.light_mm:g}mm"]},
              "substrate": {"thickness": f"{args.substrate_mm:g}mm"}, "receiver": {"z": f"-{args.screen_mm:g}mm"},
              "wavelengths": [args.wavelength_um]}
    if args.screen_sigma_mm is not None:
        config["screen"] = {"psf": "gaussian", "sigma": f"{args.screen_sigma_mm:g}mm"}
    return config


def run(args: argparse.Namespace) -> None:
    """Write the rig and say how to use it."""
    if not args.name.replace("_", "").replace("-", "").isalnum():
        raise ValueError(f"rig name {args.name!r} must be letters, digits, - and _, e.g. my_bench")
    config = rig_config(args)
    target = args.config_root / "rig" / f"{args.name}.yaml"
    target.parent.mkdir(parents=True, exist_ok=True)
    command = " ".join(shlex.quote(a) for a in ["sfc-rig", *sys.argv[1:]]) if sys.argv[1:] else "sfc-rig init"
    header = f"# @package _global_\n# The bench {args.name}, written by: {command}\n"
    target.write_text(header + yaml.safe_dump(config, sort_keys=False))
    print(f"{target}: sfc-reconstruct rig={args.name} data.photo=<print photo> height_field.path=<design> "
          "data.volume=<volume>  (run from this directory)")


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: an input error ends in one line and exit status 2."""
    run_command(run, parser().parse_args(argv), INPUT_ERROR_STATUS)


if __name__ == "__main__":
    main()
