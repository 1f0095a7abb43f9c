"""Running a test script in a fresh Python process (for settings numba reads once, at import)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_json_script(script: str, **environment: str) -> dict:
    """Run ``script`` with ``python -c`` at the repository root, with ``environment`` added to this
    process's; fail the test with its stderr if it fails, else return the JSON of its last line."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), **environment)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])
