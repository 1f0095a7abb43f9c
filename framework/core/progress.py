"""Progress of long runs where stderr is not a terminal (a log file, CI, a SLURM or Ray job): one
plain line every few seconds, instead of a tqdm bar that such a file would hold as one long line.

:class:`Heartbeat` writes the lines; the solver loop's progress bar
(:class:`framework.core.callbacks.ProgressBar`) and the run's phases (:func:`phase`) say what the
line reports. On a terminal the tqdm bars show progress and the heartbeat writes nothing.
"""

from __future__ import annotations

import sys
import threading
import time
from types import TracebackType
from typing import TextIO

__all__ = ["HEARTBEAT_SECONDS", "Heartbeat", "on_terminal", "phase", "report"]

HEARTBEAT_SECONDS = 5.0  # seconds between two progress lines


class _Status:
    """What the progress line says now (one per process; set from any thread)."""

    def __init__(self) -> None:
        self.text = ""
        self.lock = threading.Lock()


_STATUS = _Status()


def on_terminal(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (default: stderr) is a terminal, where tqdm's bars show progress."""
    stream = sys.stderr if stream is None else stream
    return stream.isatty()


def report(text: str) -> None:
    """Say what the run does now (e.g. ``"design (sfc): iteration 40/500, 12 s left"``); the next
    progress line carries it."""
    with _STATUS.lock:
        _STATUS.text = text


def phase(text: str) -> None:
    """A new phase of the run: one line now (terminal or not), and the progress lines' text."""
    report(text)
    print(text, file=sys.stderr, flush=True)


class Heartbeat:
    """While entered, a daemon thread writes ``[<elapsed> s] <status>`` to ``stream`` every
    ``interval`` seconds, unless ``stream`` is a terminal (``force`` writes anyway).

    Args:
        label: Status until the run reports one (e.g. the command's name).
        interval: Seconds between two lines, > 0.
        stream: Where the lines go (default: stderr).
        force: Write even on a terminal.
    """

    def __init__(self, label: str, interval: float = HEARTBEAT_SECONDS, stream: TextIO | None = None,
                 force: bool = False) -> None:
        if not interval > 0:
            raise ValueError(f"interval must be > 0 seconds, got {interval!r}")
        self.label, self.interval = label, float(interval)
        self.stream = sys.stderr if stream is None else stream
        self.active = force or not on_terminal(self.stream)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._began = 0.0

    def _beat(self) -> None:
        while not self._stop.wait(self.interval):
            with _STATUS.lock:
                text = _STATUS.text or self.label
            print(f"[{time.perf_counter() - self._began:.0f} s] {text}", file=self.stream, flush=True)

    def __enter__(self) -> Heartbeat:
        self._began = time.perf_counter()
        report(self.label)
        if self.active:
            self._thread = threading.Thread(target=self._beat, name="sfc-heartbeat", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        report("")
