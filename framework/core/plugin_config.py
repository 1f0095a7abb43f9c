"""Building plugins from their config: one set of rules for every kind.

A plugin's config is a mapping of keyword arguments. The plugin class is called with them: its
``from_config`` classmethod if it declares one, else the class itself (operators/plugin.py). The
keys are checked against that callable's signature first, so an unknown key fails with the list
of the keys it takes, and the plugin's own checks (types, ranges) raise a ValueError that names
the value. Arguments the framework supplies (e.g. the scene for an operator) are not config keys.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any, TypeVar
from collections.abc import Callable

from framework.core.registry import lookup
from framework.core.units import scene_length
from operators.plugin import Plugin

__all__ = ["as_mapping", "plugin_class", "plugin_factory", "build_plugin", "build_plugin_map", "split_name",
           "with_scene_lengths"]

P = TypeVar("P", bound=Plugin)

# Where plugins sit in a reconstruction's config: (kind, path of one plugin's params, or of a
# {name: params} map when the path ends in "*"). Used to convert their lengths.
PLUGIN_PLACES = (("regularizer", ("solver", "regularizers", "*")), ("post_step", ("solver", "post_steps", "*")),
                 ("regularizer", ("solver", "wavelet_regularizer")), ("preconditioner", ("solver", "preconditioner")),
                 ("initial", ("initial",)), ("initial", ("initial", "candidates", "*")), ("data", ("data",)))


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


def plugin_class(kind: str, name: str, base: type[P]) -> type[P]:
    """The registered class of plugin ``kind/name``; anything but a subclass of ``base`` (the kind's
    base, or :class:`Plugin` for what every plugin declares) is refused in one line."""
    plugin = lookup(kind, name)
    if not (isinstance(plugin, type) and issubclass(plugin, Plugin)):
        raise ValueError(f"plugin {kind}/{name} is {plugin!r}, not a plugin class: derive it from its kind's base "
                         "(docs/plugins.md, Kinds)")
    if not issubclass(plugin, base):
        raise ValueError(f"plugin {kind}/{name} does not derive from {base.__module__}.{base.__qualname__}")
    return plugin


def plugin_factory(kind: str, name: str) -> Callable[..., Any]:
    """The callable that builds plugin ``kind/name``: its ``from_config`` or the class itself."""
    return plugin_class(kind, name, Plugin).factory()


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


def _length(value: Any, mm: float, where: str) -> Any:
    """A string with a unit ('0.4 mm') in scene units, a list element-wise; other values as given."""
    if isinstance(value, str):
        return scene_length(value, mm, where)
    if isinstance(value, list):
        return [_length(v, mm, f"{where}[{i}]") for i, v in enumerate(value)]
    return value


def _converted(kind: str, name: str, params: dict[str, Any], mm: float, where: str) -> dict[str, Any]:
    """``params`` with the plugin's ``length_keys`` (a class attribute) in scene units."""
    try:
        keys = plugin_class(kind, name, Plugin).length_keys
    except KeyError:
        return params  # an unknown name is refused, with the known names, when the plugin is built
    return {k: _length(v, mm, f"{where}.{k}") if k in keys else v for k, v in params.items()}


def with_scene_lengths(cfg: Mapping[str, Any], mm_per_unit: float) -> dict[str, Any]:
    """The plain config ``cfg`` with every plugin length (a key its plugin lists in ``length_keys``)
    given as a string with a unit, e.g. ``solver.regularizers.l1_bounds.p2='0.4 mm'``, converted to
    scene units with ``mm_per_unit`` (framework/core/units.py), so that lengths read alike everywhere."""
    out = dict(cfg)
    for kind, path in PLUGIN_PLACES:
        *parents, last = path
        node: Any = out
        for key in parents:
            if not isinstance(node.get(key), Mapping):
                break
            node[key] = node = dict(node[key])
        else:
            if last == "*":
                if isinstance(node, dict):
                    node.update({name: _converted(kind, name, dict(params), mm_per_unit, f"{'.'.join(parents)}.{name}")
                                 for name, params in node.items() if isinstance(params, Mapping)})
            elif isinstance(node.get(last), Mapping) and isinstance(node[last].get("name"), str):
                node[last] = _converted(kind, node[last]["name"], dict(node[last]), mm_per_unit, ".".join(path))
    return out
