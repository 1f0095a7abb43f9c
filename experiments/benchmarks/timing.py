"""Wall-clock timing and peak memory shared by the benchmark sections (experiments/benchmarks/bench.py,
bench_fidelity.py, bench_scale.py)."""

from __future__ import annotations

import resource
import time
from collections.abc import Callable
from typing import Any


def best_seconds(run: Callable[[], Any], repeats: int = 3) -> float:
    """Shortest wall time of ``repeats`` calls of ``run`` (the least disturbed by other load)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return min(times)


def peak_rss_mb() -> float:
    """High-water mark of this process's resident memory (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
