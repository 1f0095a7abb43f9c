"""sfc-lens: the camera lens's distortion, calibrated once from photos of a ChArUco board and saved
for data.lens (framework/lab/lens.py, docs/photo_import.md, "Lens distortion").

Examples::

    sfc-lens board --out charuco                       # charuco.png (prints at its size) and charuco.json
    sfc-lens calibrate --board charuco.json shots/*.dng --out lens.json

Photograph the printed board with the camera, lens, focus and zoom of the bench, 5-15 times, the
whole board in each photo, tilted a different way each time and reaching into the corners of the
frame. The photos are read as the reconstruction reads them (camera RAW files linearly, PNG/TIFF
or .npy). An input error ends in one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from experiments.apps.input_errors import run_command
from framework.lab.lens import CharucoBoard, calibrate_lens
from framework.lab.photo_import import read_photo

INPUT_ERROR_STATUS = 2


def parser() -> argparse.ArgumentParser:
    """The command line of sfc-lens."""
    p = argparse.ArgumentParser(prog="sfc-lens", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = p.add_subparsers(dest="command", required=True)
    board = commands.add_parser("board", help="write a ChArUco board to print")
    board.add_argument("--squares", type=int, nargs=2, default=[9, 6], metavar=("X", "Y"),
                       help="squares across and down (default 9 6)")
    board.add_argument("--square-mm", type=float, default=10.0, help="a square's side (mm; default 10)")
    board.add_argument("--marker-mm", type=float, default=7.0, help="a marker's side in its square (mm; default 7)")
    board.add_argument("--dictionary", default="DICT_4X4_50", help="OpenCV ArUco dictionary (default DICT_4X4_50)")
    board.add_argument("--dpi", type=float, default=600.0, help="dots per inch of the PNG (default 600)")
    board.add_argument("--out", type=Path, default=Path("charuco"), help="path of the board, without suffix")
    calibrate = commands.add_parser("calibrate", help="calibrate the lens from photos of the board")
    calibrate.add_argument("photos", type=Path, nargs="+", help="photos of the printed board")
    calibrate.add_argument("--board", type=Path, required=True, help="the board's .json (sfc-lens board)")
    calibrate.add_argument("--out", type=Path, default=Path("lens.json"), help="where to save the calibration")
    return p


def run(args: argparse.Namespace) -> None:
    """Write the board, or calibrate and save the lens, saying what was done."""
    if args.command == "board":
        if not args.dpi > 0:
            raise ValueError(f"--dpi {args.dpi:g} must be > 0, e.g. 600")
        board = CharucoBoard(squares_x=args.squares[0], squares_y=args.squares[1], square_mm=args.square_mm,
                             marker_mm=args.marker_mm, dictionary=args.dictionary)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        png, layout = board.save(args.out, dpi=args.dpi)
        print(f"{png}: print at 100% and glue flat; {layout}: give it to sfc-lens calibrate --board")
        return
    board = CharucoBoard.load(args.board)
    lens = calibrate_lens([read_photo(p)[0] for p in args.photos], board, [p.name for p in args.photos])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    lens.save(args.out)
    print(f"{args.out}: {lens.views} of {len(args.photos)} photos used; {lens.describe()}; give it as "
          f"data.lens={args.out}")


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: an input error ends in one line and exit status 2."""
    run_command(run, parser().parse_args(argv), INPUT_ERROR_STATUS)


if __name__ == "__main__":
    main()
