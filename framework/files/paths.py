"""Checks of the directories a run writes into, before it starts."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["check_creatable_directory"]


def check_creatable_directory(path: Path, key: str) -> None:
    """Refuse a directory ``path`` (config key ``key``) that cannot be created or written: it, or
    the nearest existing folder above it, is a file or not writable."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{key}={path}: {existing} is a file, not a directory; give a directory (created if missing)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{key}={path}: {existing} cannot be written; give a directory you can write to")
