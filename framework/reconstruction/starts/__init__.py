"""Starts of the iteration (plugins of kind ``initial``): flat glass, the design, a file, the
masked transport of the caustic, or the one of several that fits the data best (docs/method.md,
"The start"); the contract they keep is framework/core/contracts/start.py."""

from .auto import AutoStart
from .simple import DesignStart, FileStart, ZeroStart
from .transport import TransportStart

__all__ = ["AutoStart", "DesignStart", "FileStart", "TransportStart", "ZeroStart"]
