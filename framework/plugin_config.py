"""Building plugins from their config: one set of rules for every kind.

A plugin's config is a mapping of keyword arguments. The plugin object is called with them: its
``from_config`` classmethod if it has one, else the object itself (a class or a function). The
keys are checked against that callable's signature first, so an unknown key fails with the list
of the keys it takes, and the plugin's own checks (types, ranges) raise a ValueError that names
the value. Arguments the framework supplies (e.g. the scene for an operator) are not config keys.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any, Callable

from framework.registry import lookup

__all__ = ["as_mapping", "plugin_factory", "build_plugin", "build_plugin_map", "split_name"]


def as_mapping(value: Any, where: str) -> dict[str, Any]:
    """``value`` as a dict (None: empty); anything but a mapping is refused, naming ``where``."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{where}={value!r} must be a mapping of keyword: value")
    return dict(value)


def split_name(spec: Any, where: str) -> tuple[str, dict[str, Any]]:
    """``{name: x, **params}`` -> (x, params): a plugin chosen by the ``name`` key of its group."""
    params = as_mapping(spec, where)
    name = params.pop("name", None)
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where} needs a plugin name, e.g. {where}.name=...; got {spec!r}")
    return name, params


def plugin_factory(kind: str, name: str) -> Callable[..., Any]:
    """The callable that builds plugin ``kind/name``: its ``from_config`` or the object itself."""
    plugin = lookup(kind, name)
    factory = getattr(plugin, "from_config", plugin)
    if not callable(factory):
        raise ValueError(f"plugin {kind}/{name} is not callable and has no from_config")
    return factory


def _config_keys(factory: Callable[..., Any], supplied: Mapping[str, Any]) -> tuple[list[str], bool]:
    """The keyword names a config may give ``factory`` (minus those supplied), and whether it
    takes any keyword (a ``**kwargs``)."""
    parameters = inspect.signature(factory).parameters.values()
    names = [p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
             and p.name not in supplied]
    return names, any(p.kind == p.VAR_KEYWORD for p in parameters)


def build_plugin(kind: str, name: str, params: Mapping[str, Any] | None, where: str, **supplied: Any) -> Any:
    """Build plugin ``kind/name`` from config ``params`` (keys checked first) and ``supplied``
    arguments; ``where`` is the config path of ``params`` for error messages (e.g. ``solver``)."""
    factory = plugin_factory(kind, name)
    params = as_mapping(params, where)
    keys, open_ended = _config_keys(factory, supplied)
    if not open_ended:
        for key in params:
            if key not in keys:
                raise ValueError(f"unknown key {where}.{key}; {kind}/{name} takes: {', '.join(keys) or 'no keys'}")
    try:
        return factory(**params, **supplied)
    except TypeError as error:  # a required key is missing, or a value of the wrong kind
        raise ValueError(f"{where} ({kind}/{name}): {error}") from None


def build_plugin_map(kind: str, specs: Any, where: str) -> list[Any]:
    """Plugins from ``{name: {params}}`` (e.g. ``solver.regularizers``), in config order."""
    return [build_plugin(kind, name, params, f"{where}.{name}") for name, params in as_mapping(specs, where).items()]
