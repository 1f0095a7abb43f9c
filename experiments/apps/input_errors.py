"""Bad input to the command-line apps ends in its one-line message, not in a traceback."""

from __future__ import annotations

import functools
import os
import sys
from typing import TypeVar
from collections.abc import Callable

# What the config, file and shape checks raise on bad input (each with a message naming the
# value and the fix).
INPUT_ERRORS = (ValueError, KeyError, FileNotFoundError)
TRACEBACK_VARIABLE = "SFC_TRACEBACK"  # set to 1: input errors propagate with their traceback

Config = TypeVar("Config")


def one_line_input_errors(task: Callable[[Config], None]) -> Callable[[Config], None]:
    """Wrap a Hydra task function: an input error (INPUT_ERRORS) exits with status 1 and
    ``error: <message>`` as the one line on stderr, unless the environment sets
    SFC_TRACEBACK=1 (then it propagates, traceback and all, as any other exception does)."""

    @functools.wraps(task)
    def run(cfg: Config) -> None:
        try:
            task(cfg)
        except INPUT_ERRORS as error:
            if os.environ.get(TRACEBACK_VARIABLE) == "1":
                raise
            raise SystemExit(f"error: {one_line(error)} ({TRACEBACK_VARIABLE}=1 shows the traceback)") from None

    return run


def one_line(error: BaseException) -> str:
    """The message of an input error on one line (str() of a KeyError quotes it; args[0] does not)."""
    message = error.args[0] if isinstance(error, KeyError) and error.args else error
    return " ".join(str(message).split())


def run_command(task: Callable[[Config], None], args: Config, status: int) -> None:
    """Run a command-line app's ``task`` on its parsed ``args``: an input error prints its one line
    (:func:`one_line_input_errors`) on stderr and exits with ``status``."""
    try:
        one_line_input_errors(task)(args)
    except SystemExit as stop:
        if not isinstance(stop.code, str):
            raise
        print(stop.code, file=sys.stderr)
        raise SystemExit(status) from None
