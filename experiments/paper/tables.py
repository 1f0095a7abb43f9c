"""What the reproduction scripts write beside their Markdown tables: the rows as CSV."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["write_csv"]


def write_csv(path: Path, rows: Sequence[dict[str, Any]], empty_header: Sequence[str] = ()) -> None:
    """``rows`` as CSV at ``path``, their first row's keys as the header (``empty_header`` where
    there are no rows)."""
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]) if rows else list(empty_header))
        writer.writeheader()
        writer.writerows(rows)
