"""What the registry reads of a plugin class, whatever its kind, declared once.

Every kind's base (the operator's :class:`operators.image_operator.ImageOperator`, the
regularisers', the solvers', the data sources', the starts' ...) derives from :class:`Plugin`, so a
plugin declares only what differs from these defaults and the framework reads the attributes
directly (framework/core/plugin_config.py, framework/core/contracts/checks.py). It lives here, a
module that imports nothing, because operators/ and regularizers/ may not import framework/.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

__all__ = ["Plugin"]


class Plugin:
    """The declarations of a plugin class.

    Attributes:
        from_config: The callable a config's keys are given to, when it is not the class itself
            (a classmethod of the plugin); None: the class. Its signature decides which keys a
            config may give (an unknown key is refused, naming those it takes).
        length_keys: The config keys that are lengths and may be given with a unit ('0.4 mm'),
            converted to scene units before the plugin is built.
    """

    from_config: ClassVar[Callable[..., Any] | None] = None
    length_keys: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def factory(cls) -> Callable[..., Any]:
        """The callable that builds the plugin from its config: :attr:`from_config`, else the class."""
        return cls.from_config if cls.from_config is not None else cls

    @classmethod
    def example_settings(cls) -> dict[str, Any]:
        """Settings the contract checks build the plugin with: none unless it requires some."""
        return {}
