"""The middleware's error types: one base, so a shell catches the layer's errors and no others.

``MiddlewareError`` subclasses ``ValueError`` because every one of them means "this value is
not acceptable" (a configuration, a parameter, an argument): code that caught ``ValueError``
before the layer had its own types keeps working.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "ConstraintError",
    "LinkStatsError",
    "MiddlewareError",
    "ParamError",
    "UnknownParamError",
    "UnknownPolicyError",
]


class MiddlewareError(ValueError):
    """The caller misused the middleware (bad configuration or argument)."""


class ConstraintError(MiddlewareError):
    """A goodput constraint was given a bad name or bad parameters."""


class LinkStatsError(MiddlewareError):
    """Link statistics were given a bad setting or an impossible round trip."""


class ParamError(MiddlewareError):
    """A (live or configured) parameter has a value the policy cannot take."""


class UnknownParamError(ParamError):
    """A parameter name the policy does not know; ``known`` lists the ones it does."""

    def __init__(self, key: str, known: Sequence[str], *, owner: str) -> None:
        self.key = key
        self.known = tuple(known)
        super().__init__(f"unknown parameter {key!r} for {owner} "
                         f"(known: {', '.join(self.known) or 'none'})")


class UnknownPolicyError(MiddlewareError):
    """A decision policy name that is not in the registry."""

    def __init__(self, name: object, known: Sequence[str]) -> None:
        self.name = name
        self.known = tuple(known)
        super().__init__(f"unknown policy {name!r}; expected one of {', '.join(self.known)}")
