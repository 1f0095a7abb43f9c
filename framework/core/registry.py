"""Plugin registry: configs name plugins by kind and name; only registered objects can be built.

A leaf module: it imports nothing of this project. Plugins come from two places:

- Python entry points, one group per kind, ``shape_from_caustics.<kind>``, each entry naming the
  plugin object (``name = "package.module:Object"``). This project declares its own built-ins
  this way in pyproject.toml, and a third-party package does the same in its own::

      [project.entry-points."shape_from_caustics.solver"]
      my_solver = "my_package.my_solver:MySolver"

  An entry point is imported only when its plugin is looked up.
- :func:`register`, for plugins defined in a running program (a notebook, a test).

Kinds (what a plugin of each kind is, docs/plugins.md):
``operator``, ``solver``, ``regularizer``, ``post_step``, ``step_size``, ``preconditioner``,
``stopping``, ``data``, ``initial`` (the start of the iteration) and ``design`` (the solver of a
caustic-design method, ``sfc-design``'s ``design_method.solver``), ``representation`` (the heights
as a function of the parameters a solver fits, framework/core/contracts/representation.py) and
``stage`` (a feature every reconstruction runs after its solve, framework/core/contracts/stage.py)
``tracker`` (where a run is logged, framework/core/contracts/run_log.py) and ``calibration`` (the
setup fitted with the heights, framework/core/contracts/calibration.py).
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points
from typing import Any, TypeVar
from collections.abc import Callable

T = TypeVar("T")

KINDS: tuple[str, ...] = ("operator", "solver", "regularizer", "post_step", "step_size", "preconditioner",
                          "stopping", "data", "initial", "design", "representation", "stage", "tracker",
                          "calibration")
ENTRY_POINT_PREFIX = "shape_from_caustics."

_registered: dict[str, dict[str, Any]] = {kind: {} for kind in KINDS}
_loaded: dict[str, dict[str, Any]] = {kind: {} for kind in KINDS}
_entry_point_cache: dict[str, dict[str, EntryPoint]] = {}


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown plugin kind {kind!r}; kinds: {', '.join(KINDS)}")


def _entry_points(kind: str) -> dict[str, EntryPoint]:
    """The installed entry points of ``kind`` by name (read once per process)."""
    if kind not in _entry_point_cache:
        found: dict[str, EntryPoint] = {}
        for ep in entry_points(group=ENTRY_POINT_PREFIX + kind):
            known = found.get(ep.name)
            if known is not None and known.value != ep.value:
                raise ValueError(f"plugin {kind}/{ep.name} is declared twice ({known.value} and {ep.value}); "
                                 "uninstall one of the packages")
            found[ep.name] = ep
        _entry_point_cache[kind] = found
    return _entry_point_cache[kind]


def register(kind: str, name: str) -> Callable[[T], T]:
    """Decorator: make ``obj`` the plugin ``kind/name`` in this process (shadows no entry point)."""
    _check_kind(kind)

    def decorator(obj: T) -> T:
        slot = _registered[kind]
        if (name in slot and slot[name] is not obj) or name in _entry_points(kind):
            raise ValueError(f"plugin {kind}/{name} is registered twice; pick another name")
        slot[name] = obj
        return obj

    return decorator


def available(kind: str) -> list[str]:
    """Names of the plugins of ``kind``, sorted."""
    _check_kind(kind)
    return sorted({*_registered[kind], *_entry_points(kind)})


def lookup(kind: str, name: str) -> Any:
    """The plugin ``kind/name``; a KeyError lists the known names otherwise."""
    _check_kind(kind)
    if name in _registered[kind]:
        return _registered[kind][name]
    if name not in _loaded[kind]:
        ep = _entry_points(kind).get(name)
        if ep is None:
            known = ", ".join(available(kind)) or "none (is the project installed? pip install -e .)"
            raise KeyError(f"unknown {kind} plugin {name!r}; {kind} plugins: {known}")
        _loaded[kind][name] = ep.load()
    return _loaded[kind][name]
