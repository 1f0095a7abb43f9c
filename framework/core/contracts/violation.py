"""What a failed contract check raises: :class:`ContractViolation`, naming the plugin and the check."""

from __future__ import annotations

__all__ = ["ContractViolation", "require"]


class ContractViolation(AssertionError):
    """A plugin breaks its kind's contract."""


def require(condition: bool, who: str, what: str) -> None:
    """Raise :class:`ContractViolation` ``who: what`` unless ``condition``."""
    if not condition:
        raise ContractViolation(f"{who}: {what}")
