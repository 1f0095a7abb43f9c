"""Save, load and resume solver state (one ``torch.save`` file, written atomically).

A checkpoint holds the solver's ``state_dict()`` (d, iteration, elapsed time, history, and what
the solver adds: wavelet coefficients, step-size state, the cached data-term evaluation at d) plus
the torch (CPU and CUDA) and NumPy global RNG states. Restoring all of it makes a resumed run continue exactly as
the uninterrupted one would: bit-for-bit for a deterministic operator, and also for a stochastic
one that draws from the global torch/NumPy generators (an operator's private generator is not
covered). Files are read with ``torch.load(weights_only=True)``: only tensors and plain data.
"""

from __future__ import annotations

import os
import pickle
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any
from collections.abc import Sequence

import numpy as np
import torch

if TYPE_CHECKING:
    from framework.core.solver_loop import Callback, IterativeSolver, RunResult

__all__ = ["save_checkpoint", "load_checkpoint", "restore", "resume", "CHECKPOINT_FORMAT"]

CHECKPOINT_FORMAT = 1


def _rng_state() -> dict[str, Any]:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "name": str(name), "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)),
            "pos": int(pos), "has_gauss": int(has_gauss), "cached_gaussian": float(cached),
        },
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state(
        (n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"])
    )
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_checkpoint(solver: IterativeSolver, path: str | os.PathLike[str],
                    run: Mapping[str, str] | None = None) -> Path:
    """Write the solver's state to ``path`` atomically (temporary file + ``os.replace``), with
    ``run``, the fingerprint of the run it belongs to (framework/reconstruction/run_identity.py), if given.

    A crash while writing leaves the previous checkpoint intact. Returns the path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": CHECKPOINT_FORMAT, "solver_state": solver.state_dict(), "rng": _rng_state(),
               "run": dict(run or {})}
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            torch.save(payload, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (tensors on the CPU)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}; check the path or start without resume")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, EOFError, OSError, pickle.UnpicklingError, zipfile.BadZipFile) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"{path} is not a readable checkpoint, truncated or not written by this software "
                         f"({reason[:120]})") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path} is not a checkpoint of format {CHECKPOINT_FORMAT} (found {found!r})")
    return payload


def restore(solver: IterativeSolver, path: str | os.PathLike[str], restore_rng: bool = True) -> IterativeSolver:
    """Load the checkpoint at ``path`` into ``solver`` (built with the same configuration)."""
    payload = load_checkpoint(path)
    solver.load_state_dict(payload["solver_state"])
    if restore_rng:
        _set_rng_state(payload["rng"])
    return solver


def resume(
    solver: IterativeSolver,
    path: str | os.PathLike[str],
    max_iter: int,
    callbacks: Sequence[Callback] = (),
) -> RunResult:
    """Restore ``solver`` from ``path`` and continue to the absolute cap ``max_iter``.

    With the same configuration and cap, the result equals that of an uninterrupted run.
    """
    restore(solver, path)
    return solver.run(max_iter, callbacks)
