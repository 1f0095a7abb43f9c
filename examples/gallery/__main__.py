"""Run every gallery script, each writing its figure into --out (default docs/gallery, where the
user guide's examples page shows them).

    python -m examples.gallery --out docs/gallery
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from examples.gallery import custom_operator, custom_regularizer, design_through_lenses, reconstruct_from_python

SCRIPTS = (reconstruct_from_python, custom_regularizer, custom_operator, design_through_lenses)


def main(argv: list[str] | None = None) -> None:
    """Command line: --out, the folder of the figures (the runs go to a temporary folder)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/gallery"), help="folder of the figures")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sfc-gallery-") as scratch:
        for script in SCRIPTS:
            began = time.perf_counter()
            figure = script.main(Path(scratch))
            shutil.copy(figure, args.out / figure.name)
            print(f"{script.__name__}: {args.out / figure.name} in {time.perf_counter() - began:.0f} s", flush=True)


if __name__ == "__main__":
    main()
