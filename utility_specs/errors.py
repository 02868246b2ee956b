"""One base error for the evaluation model, with a subclass per kind of bad input."""

from __future__ import annotations

__all__ = ["LogError", "MessageError", "SpecError", "UtilitySpecsError"]


class UtilitySpecsError(Exception):
    """Base of every error this package raises on bad input."""


class MessageError(UtilitySpecsError, ValueError):
    """A message that cannot exist (negative size, reception before generation...)."""


class SpecError(UtilitySpecsError, ValueError):
    """A mission spec that is malformed; the text names the file, the key and what was expected."""


class LogError(UtilitySpecsError, ValueError):
    """A mission log line that cannot be read; the text names the file and the line."""
