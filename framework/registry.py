"""Plugin registry: configs name plugins by ``kind/name``; only registered classes can be built.

Our own plugins register with the :func:`register` decorator when their module is imported.
Third-party packages add plugins through the ``shape_from_caustics.plugins`` entry-point group;
each entry point names a module that registers its classes on import, e.g. in their
pyproject.toml::

    [project.entry-points."shape_from_caustics.plugins"]
    my_solver = "my_package.my_solver"
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any, Callable, TypeVar

T = TypeVar("T")

ENTRY_POINT_GROUP = "shape_from_caustics.plugins"
# Modules of this project that register plugins; imported lazily on first lookup.
BUILTIN_PLUGIN_MODULES: tuple[str, ...] = (
    "regularizers",
    "framework.solvers",
    "operators.caustic_operator",
)

_REGISTRY: dict[str, dict[str, Callable[..., Any]]] = {}
_loaded = False


def register(kind: str, name: str) -> Callable[[T], T]:
    """Class decorator: make ``cls`` buildable as ``kind/name``."""

    def decorator(cls: T) -> T:
        slot = _REGISTRY.setdefault(kind, {})
        if name in slot and slot[name] is not cls:
            raise ValueError(f"plugin {kind}/{name} is registered twice; pick another name")
        slot[name] = cls  # type: ignore[assignment]
        return cls

    return decorator


def _load_plugins() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for module in BUILTIN_PLUGIN_MODULES:
        importlib.import_module(module)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        importlib.import_module(ep.value)


def available(kind: str) -> list[str]:
    """Names registered under ``kind``, sorted."""
    _load_plugins()
    return sorted(_REGISTRY.get(kind, {}))


def lookup(kind: str, name: str) -> Callable[..., Any]:
    """The class registered as ``kind/name``; a clear error lists the known names otherwise."""
    _load_plugins()
    try:
        return _REGISTRY[kind][name]
    except KeyError:
        known = ", ".join(available(kind)) or "none"
        raise KeyError(f"unknown {kind} plugin {name!r}; registered {kind} plugins: {known}") from None


def build(kind: str, name: str, **params: Any) -> Any:
    """Instantiate the plugin ``kind/name`` with keyword ``params``."""
    return lookup(kind, name)(**params)
