"""sfc-calibrate-screen: the screen's blur (screen.sigma) from a photo of the caustic, by its profile.

Reconstructs the photo under several widths of the Gaussian screen blur, each with the same start
and budget and no stop at the noise level, and takes the width whose fit explains the photo best
(framework/lab/width_search.py; docs/method.md, "The screen's blur from the photo"). The blur
belongs to the setup (screen, camera, focus), not to the print: calibrate it once per setup, then
reconstruct every print with ``screen.psf=gaussian screen.sigma=<found>``.

    sfc-calibrate-screen data=photo data.photo=caustic.png data.flat=flat.png data.corners=[...] data.delta=0.013
    sfc-calibrate-screen --widths 0.35 0.7 1.4 2.8 --iterations 60 scene=bump data.delta=0.01

Every other argument is a Hydra override of conf/reconstruct.yaml, as for sfc-reconstruct. Writes
screen_calibration.json and screen_profile.png into --work (default outputs/screen_calibration),
one reconstruction per width beneath it (reused when the command runs again with the same
overrides and iterations; other settings need another --work), each an MLflow run of
the experiment ``screen_calibration``. Needs a photo whose noise is below the blur's imprint: at 5%
noise the heights absorb a blur of 1.5 px and the profile says the width is not told.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from experiments.apps.configs import chooses_start, reconstruct_config  # noqa: E402
from experiments.apps.input_errors import one_line_input_errors  # noqa: E402
from framework.lab.width_search import MIN_RISE, WidthProfile, search_width  # noqa: E402
from framework.reconstruction.reconstruction import run_reconstruction  # noqa: E402
from framework.scene.scene_config import build_scene  # noqa: E402
from operators.values import checked_whole  # noqa: E402

GRID_PX = (0.35, 0.7, 1.4, 2.8)
# The best fit must come within this factor of the noise level for its width to count: fits far
# from it differ by how far each got, not by the blur.
NEAR_NOISE = 2.0


class ProfileRuns:
    """One reconstruction per width (pixels) under ``work``, reused when its metrics.json exists."""

    def __init__(self, overrides: list[str], work: Path, iterations: int) -> None:
        self.overrides, self.work, self.iterations = list(overrides), work, iterations
        settings = {"overrides": self.overrides, "iterations": iterations}
        saved = work / "profile_settings.json"
        if saved.is_file() and json.loads(saved.read_text()) != settings:
            raise ValueError(f"--work {work} holds fits of other settings ({saved}): give another --work, or delete it "
                             "to start afresh")
        work.mkdir(parents=True, exist_ok=True)
        saved.write_text(json.dumps(settings, indent=2))
        scene = build_scene(reconstruct_config(self.overrides))
        self.pixel, self.mm_per_unit = scene.receiver.pixel_size, float(scene.mm_per_unit)  # scene units, mm
        # A start of its own (initial=auto would retry from flat glass: every profile run ends short
        # of the noise level by design).
        self.start = [] if chooses_start(overrides) else ["initial=transport"]
        self.delta = float("nan")  # the data's noise level, from the first fit

    def misfit(self, width_px: float) -> float:
        """The relative discrepancy of the fit under a blur of ``width_px`` receiver pixels."""
        run_dir = self.work / f"sigma_{width_px:.4f}px"
        if (run_dir / "metrics.json").is_file():
            metrics: dict[str, Any] = json.loads((run_dir / "metrics.json").read_text())
        else:
            cfg = reconstruct_config([*self.overrides, *self.start, "screen.psf=gaussian",
                                      f"screen.sigma={width_px * self.pixel!r}", "~stopping.morozov",
                                      f"solver.max_iter={self.iterations}", "tracking.experiment=screen_calibration",
                                      "defects.enabled=off"])
            metrics = run_reconstruction(cfg, run_dir, self.work)
        misfit, self.delta = float(metrics["rel_discrepancy"]), float(metrics["delta"])
        print(f"screen blur {width_px:.3f} px: relative discrepancy {misfit:.5f} after {metrics['iterations']} "
              "iterations", flush=True)
        return misfit

    def summary(self, profile: WidthProfile) -> dict[str, Any]:
        """The result for screen_calibration.json (widths in pixels, scene units and mm)."""
        near = profile.best()[1] / self.delta
        return {"sigma_px": profile.width, "sigma": profile.width * self.pixel,
                "sigma_mm": profile.width * self.pixel * self.mm_per_unit,
                "identified": profile.identified and near <= NEAR_NOISE, "rise_at_factor_2": profile.rise,
                "at_bound": profile.at_bound, "best_misfit_over_delta": near, "iterations": self.iterations,
                "profile": [{"sigma_px": w, "rel_discrepancy": r} for w, r in profile.sorted_points()]}


def verdict(result: dict[str, Any]) -> str:
    """One line: the width to configure, or why the photo does not tell it."""
    if result["at_bound"]:
        side = "below" if result["at_bound"] == "lower" else "above"
        return (f"Screen blur not told: the best fit lies at the search's {result['at_bound']} bound "
                f"({result['sigma_px']:.3f} px); the blur is {side} what the search covers (--widths) or the "
                "heights absorb it (lower noise, or a photo of a known print).")
    line = (f"screen blur sigma = {result['sigma_px']:.3f} px = {result['sigma']:.6g} scene units = "
            f"{result['sigma_mm']:.4f} mm (the misfit rises {100 * result['rise_at_factor_2']:.0f}% a factor 2 away)")
    if result["best_misfit_over_delta"] > NEAR_NOISE:
        return (f"Screen blur not told: the best fit ends at {result['best_misfit_over_delta']:.2f} x the noise level "
                f"(> {NEAR_NOISE:g}), so the fits differ by how far each got ({line}): raise --iterations")
    if not result["identified"]:
        return (f"Screen blur not told: {line}, less than {100 * MIN_RISE:.0f}%: the heights absorb the blur at this "
                "noise level; keep the measured blur, or photograph with less noise")
    return f"{line}: reconstruct with screen.psf=gaussian screen.sigma={result['sigma']:.6g}"


def profile_figure(result: dict[str, Any], path: Path) -> None:
    """The misfit against the width, the found width marked."""
    widths = [p["sigma_px"] for p in result["profile"]]
    misfits = [p["rel_discrepancy"] for p in result["profile"]]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.semilogx(widths, misfits, "o-")
    ax.axvline(result["sigma_px"], color="k", ls="--", lw=1, label=f"found {result['sigma_px']:.3f} px")
    ax.set_xlabel("screen blur sigma (receiver pixels)")
    ax.set_ylabel("relative discrepancy of the fit")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def calibrate(overrides: list[str], work: Path, widths: tuple[float, ...] = GRID_PX, iterations: int = 60,
              tolerance: float = 0.05) -> dict[str, Any]:
    """Search the width, write screen_calibration.json and screen_profile.png into ``work``; returns the result."""
    iterations = checked_whole(iterations, "--iterations", 1, example="60")
    runs = ProfileRuns(overrides, work, iterations)
    result = runs.summary(search_width(runs.misfit, widths, tolerance=tolerance))
    result["verdict"] = verdict(result)
    (work / "screen_calibration.json").write_text(json.dumps(result, indent=2))
    profile_figure(result, work / "screen_profile.png")
    return result


@one_line_input_errors
def _run(args: argparse.Namespace) -> None:
    result = calibrate(args.overrides, args.work.resolve(), tuple(args.widths), args.iterations, args.tolerance)
    print(result["verdict"])
    print(f"wrote screen_calibration.json and screen_profile.png to {args.work}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of conf/reconstruct.yaml (the photo, the setup)")
    parser.add_argument("--widths", nargs="+", type=float, default=list(GRID_PX),
                        help="the first widths to fit, receiver pixels (>= 3; extended at the edges)")
    parser.add_argument("--iterations", type=int, default=60, help="iterations of every fit")
    parser.add_argument(
        "--tolerance", type=float, default=0.05, help="stop when the width moves by less than this share"
    )
    parser.add_argument("--work", type=Path, default=Path("outputs/screen_calibration"))
    _run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
