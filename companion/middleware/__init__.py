"""The information distribution layer (thesis ch. 5 and 6): sans-I/O optimiser and constraints.

``Middleware(config, *, rng, constraint).decide(message, now) -> Decision`` decides send /
drop / version by MCTS over the utility model under a goodput window constraint. Baselines
share the interface. The constraint strategies (constant, adaptive SGD, AIMD) are imported
lazily so that this package imports even while one of their modules is missing.
"""

from __future__ import annotations

import importlib
from typing import Any

from companion.middleware.baselines import (
    Greedy,
    KnapsackGreedy,
    OptimumResult,
    Policy,
    RandomDrop,
    SendAll,
    offline_optimum,
)
from companion.middleware.constraint import ConstantConstraint, GoodputConstraint, LinkSample
from companion.middleware.forecast import LatencyEstimator, StreamForecaster
from companion.middleware.incremental import FixedItem, PlanItem, Problem, build_problem
from companion.middleware.knowledge import FleetKnowledge
from companion.middleware.mcts import MCTS, SearchResult, greedy_option
from companion.middleware.middleware import (
    Decision,
    Middleware,
    MiddlewareConfig,
    MiddlewareError,
)

_LAZY = {
    "AdaptiveConstraint": "companion.middleware.adaptive",
    "LinkStatsConstraint": "companion.middleware.adaptive",
    "AimdConstraint": "companion.middleware.aimd",
    "CONSTRAINTS": "companion.middleware.constraints",
    "make_constraint": "companion.middleware.constraints",
    "LinkStats": "companion.middleware.linkstats",
}

__all__ = [
    "CONSTRAINTS",
    "MCTS",
    "AdaptiveConstraint",
    "AimdConstraint",
    "ConstantConstraint",
    "Decision",
    "FixedItem",
    "FleetKnowledge",
    "GoodputConstraint",
    "Greedy",
    "KnapsackGreedy",
    "LatencyEstimator",
    "LinkSample",
    "LinkStats",
    "LinkStatsConstraint",
    "Middleware",
    "MiddlewareConfig",
    "MiddlewareError",
    "OptimumResult",
    "PlanItem",
    "Policy",
    "Problem",
    "RandomDrop",
    "SearchResult",
    "SendAll",
    "StreamForecaster",
    "build_problem",
    "greedy_option",
    "make_constraint",
    "offline_optimum",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
