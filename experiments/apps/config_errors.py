"""Mistyped command-line overrides end in one ``error:`` line that names the key or option and the
likely fix ("did you mean"), before Hydra starts a run: an unknown option of a config group
(``scene=print_line``), an unknown key (``receiver.resolutoin=256``) and a value given to a section of
keys (``target=my.png``, meaning ``target.image=my.png``).

:func:`checked_app` wraps a command's Hydra entry point; the config is composed once with the
command line's overrides (each value of a sweep in turn) and only a failure is explained.
"""

from __future__ import annotations

import difflib
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException
from omegaconf import DictConfig, OmegaConf

import conf

__all__ = ["checked_app", "override_error"]

# Hydra's own flags that take the next argument, and those after which no run starts.
FLAGS_WITH_VALUE = ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd", "--experimental-rerun")
CUSTOM_CONFIG = ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd")
# Hydra's flags that print (the config, help, the search path) instead of running: Hydra reads those lines.
NO_RUN = ("--cfg", "-c", "--info", "-i", "--help", "-h", "--hydra-help", "--shell-completion", "-sc", "--package", "-p")
OWN_SEARCH_PATH = "hydra.searchpath"  # configs of the user's own (Hydra checks those; the compose API sees only conf/)
VALUE_KEYS = ("image", "path", "file", "name", "tau")  # the key a bare value most likely meant, in this order
MAX_OPTIONS = 12


def _overrides(argv: Sequence[str]) -> list[str] | None:
    """The overrides of a command line, or None where it chooses its own config or asks Hydra to print
    instead of run (then Hydra checks, as it does where the overrides add a config search path)."""
    out, skip = [], False
    for token in argv:
        if skip:
            skip = False
        elif token in CUSTOM_CONFIG or token in NO_RUN:
            return None
        elif token in FLAGS_WITH_VALUE:
            skip = True
        elif not token.startswith("-"):
            out.append(token)
    return out


def _combinations(overrides: list[str]) -> Iterator[list[str]]:
    """``overrides`` with each sweep (``a=1,2``, ``range(..)``, ``glob(..)``) given its values in turn,
    the others at their first value: every value is composed once."""
    parsed = OverridesParser.create().parse_overrides(overrides)
    values = [list(o.sweep_string_iterator()) if o.is_sweep_override() else [] for o in parsed]
    first = [f"{o.get_key_element()}={v[0]}" if v else o.input_line for o, v in zip(parsed, values)]
    yield first
    for index, (override, sweep) in enumerate(zip(parsed, values)):
        for value in sweep[1:]:
            yield [*first[:index], f"{override.get_key_element()}={value}", *first[index + 1 :]]


def _compose(config_name: str, overrides: list[str]) -> DictConfig:
    with initialize_config_dir(config_dir=conf.DIRECTORY, version_base=None):
        return compose(config_name, overrides=overrides, return_hydra_config=True)


def _listed(names: Sequence[str]) -> str:
    names = sorted(str(n) for n in names)
    return ", ".join(names[:MAX_OPTIONS]) + (", ..." if len(names) > MAX_OPTIONS else "")


def _did_you_mean(word: str, choices: Sequence[str], prefix: str = "") -> str:
    close = difflib.get_close_matches(word, [str(c) for c in choices], n=1, cutoff=0.6)
    return f"did you mean {prefix}{close[0]}? " if close else ""


def _unknown_option(error: MissingConfigException) -> str:
    group, _, option = str(error.missing_cfg_file or "").rpartition("/")
    options = list(error.options or [])
    return f"{group}={option} is not an option of {group}; {_did_you_mean(option, options)}options: {_listed(options)}"


def _without_unknown(config_name: str, overrides: list[str], key: str) -> tuple[DictConfig, list[str]]:
    """The config composed without the override of ``key`` nor of any other key it does not have,
    and those other keys."""
    others, also = [o for o in overrides if _key(o) != key], []
    while True:
        try:
            return _compose(config_name, others), also
        except ConfigCompositionException as error:
            found = re.search(r"Could not override '([^']+)'", str(error))
            if not found or found.group(1) in also:
                raise
            also.append(found.group(1))
            others = [o for o in others if _key(o) != found.group(1)]


def _unknown_key(config_name: str, overrides: list[str], key: str) -> str:
    """Explain an override of ``key``, which the config does not have (and name any other unknown key)."""
    base, also = _without_unknown(config_name, overrides, key)
    return _explained(base, key) + (f"; unknown too: {', '.join(also)}" if also else "")


def _explained(base: DictConfig, key: str) -> str:
    """Why ``key`` is not a key of ``base``, with the keys its section takes."""
    parts = key.split(".")
    node: Any = base
    for depth, part in enumerate(parts[:-1]):
        if not isinstance(node, DictConfig) or part not in node:
            section = ".".join(parts[:depth])
            keys = list(node.keys()) if isinstance(node, DictConfig) else []
            where = f"{section} takes" if section else "the config has"
            prefix = f"{section}." if section else ""
            return (
                f"unknown key {key}: {'.'.join(parts[: depth + 1])} does not exist; {_did_you_mean(part, keys, prefix)}"
                f"{where}: {_listed(keys)}"
            )
        node = node[part]
    keys = list(node.keys()) if isinstance(node, DictConfig) else []
    section = ".".join(parts[:-1]) or "the config"
    prefix = ".".join(parts[:-1]) + "." if len(parts) > 1 else ""
    return (
        f"unknown key {key}; {_did_you_mean(parts[-1], keys, prefix)}{section} takes: {_listed(keys)} "
        f"(+{key}=... adds a key of your own)"
    )


def _same_kind(current: Any, value: str) -> bool:
    """Whether a command-line ``value`` could replace ``current``: numbers for numbers, text for text."""
    try:
        float(value)
        number = True
    except ValueError:
        number = False
    if isinstance(current, DictConfig):
        return False
    return isinstance(current, (int, float)) if number else isinstance(current, str) or current is None


def _value_for_section(base: DictConfig, overrides: list[str]) -> str | None:
    """A plain value given to a key that is a section of keys (``target=my.png``), explained."""
    for override in overrides:
        key, sep, value = override.partition("=")
        if not sep or key.startswith(("+", "~")) or key.startswith("hydra"):
            continue
        node = OmegaConf.select(base, key, default=None, throw_on_missing=False)
        if isinstance(node, DictConfig) and not value.lstrip().startswith("{") and value.strip() != "null":
            keys = [str(k) for k in node.keys()]
            alike = [
                k for k in keys if _same_kind(OmegaConf.select(node, k, default=None, throw_on_missing=False), value)
            ]
            meant = next((k for k in VALUE_KEYS if k in alike), (alike or keys or ["<key>"])[0])
            example = f"{key}.{meant}={value}"
            return f"{key} is a section of keys ({_listed(keys)}), not a value; set one of them, e.g. {example}"
    return None


def override_error(config_name: str, overrides: list[str]) -> str | None:
    """The one-line explanation of what is wrong with ``overrides`` of conf/<config_name>.yaml
    (without ``error:``), or None where they compose."""
    bare = next((o for o in overrides if "=" not in o and not o.startswith("~")), None)
    if bare is not None:
        return f"{bare} has no value; give it as {bare}=<value> (or ~{bare} to remove the key)"
    try:
        combinations = list(_combinations(overrides))
    except OverrideParseException as error:
        return f"cannot read the override: {' '.join(str(error).split())}"
    for combination in combinations:
        try:
            composed = _compose(config_name, combination)
        except MissingConfigException as error:
            return _unknown_option(error)
        except ConfigCompositionException as error:
            found = re.search(r"Could not override '([^']+)'", str(error))
            if found:
                return _unknown_key(config_name, combination, found.group(1))
            return " ".join(str(error).split())
        groups = _group_keys(composed)
        values = [o for o in combination if _key(o) not in groups]
        if not values:  # only options of config groups chosen: no value that could meet a section
            continue
        chosen = [o for o in combination if _key(o) in groups]
        problem = _value_for_section(_compose(config_name, chosen), values)
        if problem is not None:
            return problem
    return None


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def _group_keys(composed: DictConfig) -> set[str]:
    """The config groups the composed config chose options of (``scene``, ``solver``, ...)."""
    choices = OmegaConf.select(composed, "hydra.runtime.choices", default=None)
    return {str(k) for k in choices.keys()} if isinstance(choices, DictConfig) else set()


def checked_app(config_name: str, app: Callable[[], Any]) -> Callable[[], Any]:
    """``app`` (a ``hydra.main`` entry point of conf/<config_name>.yaml) that first checks the
    command line's overrides and exits with status 1 and one ``error:`` line where they are wrong."""

    def main() -> Any:
        overrides = _overrides(sys.argv[1:])
        if overrides and not any(_key(o).startswith(OWN_SEARCH_PATH) for o in overrides):
            problem = override_error(config_name, overrides)
            if problem is not None:
                raise SystemExit(f"error: {problem}")
        return app()

    main.__doc__ = app.__doc__
    return main
