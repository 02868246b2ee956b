"""Goodput constraints (thesis ch. 5.3 and 6), picked by name as the mission configuration names it.

Modules, bottom up, with no import circle: ``linkstats`` (samples, round trips, window
statistics; imports nothing of the middleware but its errors) <- ``base`` (the constraint
interface and the constant ξ) <- ``adaptive`` (the SGD model of ch. 6.2) <- ``aimd`` (alg. 4)
<- ``registry`` (:func:`make_constraint`). The last three are imported on first use, so
that importing the optimiser does not import scikit-learn.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from companion.middleware.constraints.base import ConstantConstraint, GoodputConstraint
from companion.middleware.constraints.linkstats import (
    ClockOffset,
    ClockOffsetEstimator,
    LinkSample,
    LinkStats,
    RoundTrip,
    WindowStats,
)

if TYPE_CHECKING:  # the lazy names, typed for checkers (imported on first use at run time)
    from companion.middleware.constraints.adaptive import (
        AdaptiveConstraint,
        LinkStatsConstraint,
    )
    from companion.middleware.constraints.aimd import AimdConstraint
    from companion.middleware.constraints.registry import CONSTRAINTS, make_constraint

_LAZY = {
    "AdaptiveConstraint": "companion.middleware.constraints.adaptive",
    "LinkStatsConstraint": "companion.middleware.constraints.adaptive",
    "AimdConstraint": "companion.middleware.constraints.aimd",
    "CONSTRAINTS": "companion.middleware.constraints.registry",
    "make_constraint": "companion.middleware.constraints.registry",
}

__all__ = [
    "CONSTRAINTS",
    "AdaptiveConstraint",
    "AimdConstraint",
    "ClockOffset",
    "ClockOffsetEstimator",
    "ConstantConstraint",
    "GoodputConstraint",
    "LinkSample",
    "LinkStats",
    "LinkStatsConstraint",
    "RoundTrip",
    "WindowStats",
    "make_constraint",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
