"""sfc-markers: the marker sheet for the screen's frame, to print at its size, and its layout
(framework/lab/screen_markers.py, docs/photo_import.md, "Markers").

Examples::

    sfc-markers --receiver-mm 50                          # screen_markers.png and screen_markers.json
    sfc-markers --receiver-mm 50 --marker-mm 8 --per-side 5 --dpi 1200 --out bench/sheet

Print the PNG at 100% (its size is in the file: --dpi dots per inch) on the screen's paper, the
receiver square left white, and give the .json to the reconstruction as data.markers: every photo
is then located by the markers it shows, with no corners typed. The receiver's side is the scene's
(2 receiver.half_width in scene units times units.mm_per_unit; 50 mm for the defaults). A bad value
ends in one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from experiments.apps.input_errors import run_command
from framework.lab.screen_markers import MarkerSheet

INPUT_ERROR_STATUS = 2


def parser() -> argparse.ArgumentParser:
    """The command line of sfc-markers."""
    p = argparse.ArgumentParser(prog="sfc-markers", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--receiver-mm", type=float, required=True, help="the receiver's side on the screen (mm)")
    p.add_argument("--marker-mm", type=float, default=6.0, help="each marker's side, border included (mm; default 6)")
    p.add_argument("--gap-mm", type=float, default=2.0, help="from the receiver's edge to the markers (mm; default 2)")
    p.add_argument("--per-side", type=int, default=4, help="markers along each side, corners shared (default 4)")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="OpenCV ArUco dictionary (default DICT_4X4_50)")
    p.add_argument("--dpi", type=float, default=600.0, help="dots per inch of the PNG (default 600)")
    p.add_argument("--out", type=Path, default=Path("screen_markers"), help="path of the sheet, without suffix")
    return p


def write_sheet(args: argparse.Namespace) -> None:
    """Write the sheet's PNG and layout and say where, and how large it prints."""
    if not args.dpi > 0:
        raise ValueError(f"--dpi {args.dpi:g} must be > 0, e.g. 600")
    sheet = MarkerSheet(receiver_mm=args.receiver_mm, marker_mm=args.marker_mm, gap_mm=args.gap_mm,
                        per_side=args.per_side, dictionary=args.dictionary)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    png, layout = sheet.save(args.out, dpi=args.dpi)
    print(f"{png}: {len(sheet.centres())} markers around a {sheet.receiver_mm:g} mm receiver; print at 100% "
          f"({sheet.page_mm():.1f} mm square at {args.dpi:g} dpi)")
    print(f"{layout}: give it as data.markers={layout}")


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: a bad value ends in one line and exit status 2."""
    run_command(write_sheet, parser().parse_args(argv), INPUT_ERROR_STATUS)


if __name__ == "__main__":
    main()
