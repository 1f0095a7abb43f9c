"""Where a reconstruction's configuration goes: every call of the project's code whose arguments
hold the config (a mapping with the groups operator, solver, data and height_field), grouped by
module into stays (consecutive such calls in one module).

    python -m tests.architecture.config_path     # prints the stays of a small reconstruction
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

PACKAGES = ("framework", "operators", "regularizers", "experiments")
GROUPS = {"operator", "solver", "data", "height_field"}


def _is_config(value: Any) -> bool:
    try:
        return isinstance(value, Mapping) and GROUPS <= set(value.keys()) and isinstance(value["operator"], Mapping)
    except Exception:  # a mapping that cannot list its keys is not a config
        return False


def config_calls(run: Callable[[], Any]) -> list[tuple[str, str]]:
    """(module, function) of every call that receives the config while ``run()`` runs, in order."""
    calls: list[tuple[str, str]] = []

    def profile(frame: Any, event: str, arg: Any) -> None:
        if event != "call":
            return
        module = frame.f_globals.get("__name__") or ""
        if not module.startswith(PACKAGES):
            return
        code = frame.f_code
        names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]
        if any(_is_config(frame.f_locals.get(name)) for name in names):
            calls.append((module, code.co_name))

    previous = sys.getprofile()
    sys.setprofile(profile)
    try:
        run()
    finally:
        sys.setprofile(previous)
    return calls


def stays(calls: list[tuple[str, str]]) -> Counter[str]:
    """Module -> how many separate times the config came to it."""
    count: Counter[str] = Counter()
    last = None
    for module, _ in calls:
        if module != last:
            count[module] += 1
        last = module
    return count


SMALL_RUN = ["photons=20000", "receiver.resolution=64", "height_field.resolution=32", "solver.max_iter=2",
             "data.reference_photons=20000", "data.reference_resolution=64", "initial=zero"]


def small_run_calls(directory: Path) -> list[tuple[str, str]]:
    """:func:`config_calls` of a small synthetic reconstruction (two iterations) run in ``directory``."""
    from hydra import compose, initialize_config_dir

    from experiments.apps.configs import to_plain
    from framework.reconstruction.reconstruction import run_reconstruction

    conf = Path(__file__).resolve().parents[2] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base=None):
        cfg = to_plain(compose("reconstruct", overrides=[*SMALL_RUN, f"tracking.store_dir={directory}/mlruns"]))
    # A first run, not traced, creates the tracking store (its schema migrations are most of the
    # Python calls a first run makes) and warms the caches; the traced run is the second.
    run_reconstruction(cfg, directory / "first", directory)
    return config_calls(lambda: run_reconstruction(cfg, directory / "run", directory))


def main() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        calls = small_run_calls(Path(tmp))
    for module, count in stays(calls).most_common():
        print(f"{module}: {count} stays ({', '.join(sorted({f for m, f in calls if m == module}))})")


if __name__ == "__main__":
    main()
