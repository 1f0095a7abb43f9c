"""Progress lines where stderr is not a terminal (framework/core/progress.py) and the figures the
progress bar reports (framework/core/callbacks.py)."""

from __future__ import annotations

import io
import re
import time
from types import SimpleNamespace

import pytest

from framework.core.callbacks import ProgressBar
from framework.core.progress import Heartbeat, on_terminal, phase, report


def test_the_heartbeat_writes_the_reported_status_every_interval():
    stream = io.StringIO()
    with Heartbeat("starting", interval=0.05, stream=stream, force=True):
        time.sleep(0.13)
        report("iteration 3/10")
        time.sleep(0.13)
    lines = stream.getvalue().splitlines()
    assert 3 <= len(lines) <= 6, lines
    assert all(re.fullmatch(r"\[\d+ s\] (starting|iteration 3/10)", line) for line in lines), lines
    assert lines[0].endswith("starting") and lines[-1].endswith("iteration 3/10")
    after = len(stream.getvalue())
    time.sleep(0.12)
    assert len(stream.getvalue()) == after  # nothing once the run has left the block


def test_the_heartbeat_is_silent_on_a_terminal_and_refuses_a_bad_interval(capsys):
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    assert on_terminal(terminal) and not on_terminal(io.StringIO())
    with Heartbeat("quiet", interval=0.02, stream=terminal):
        time.sleep(0.08)
    assert terminal.getvalue() == ""
    phase("design: the transport start")
    assert capsys.readouterr().err == "design: the transport start\n"
    with pytest.raises(ValueError, match="interval must be > 0 seconds, got 0"):
        Heartbeat("x", interval=0)


def test_the_time_left_is_the_remaining_iterations_at_the_pace_so_far_capped_by_the_budget():
    solver = SimpleNamespace(max_iter=100, iteration=10, name="s", state=SimpleNamespace(elapsed_s=4.0))
    bar = ProgressBar(disable=True)
    bar.on_start(solver)
    # 10 iterations in 5 s since the start: 0.5 s each, 80 left.
    assert bar.seconds_left(20, 9.0, 100) == pytest.approx(40.0)
    budget = ProgressBar(disable=True, seconds=12.0)
    budget.on_start(solver)
    assert budget.seconds_left(20, 9.0, 100) == pytest.approx(3.0)
    assert bar.seconds_left(10, 4.0, 100) == float("inf")  # no iteration yet: no pace
