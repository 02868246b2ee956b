"""The information distribution layer (thesis ch. 5 and 6): sans-I/O optimiser and constraints.

One seam for the shells: a :class:`Decider` (``decide``, ``on_delivered``, ``on_report``,
``set_params``, timers) built by name with :func:`make_decider` (``mcts`` is
``Middleware(config, *, rng, constraint)``; ``send_all``, ``random_drop``, ``greedy`` and
``knapsack_greedy`` are the baselines). Goodput constraints live in :mod:`.constraints`
(:func:`make_constraint`); the layer's errors are :class:`MiddlewareError` subclasses. The
constraint strategies and the registry are imported lazily, so importing this package does
not import scikit-learn.
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
from companion.middleware.constraints.base import ConstantConstraint, GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample
from companion.middleware.decider import Decider, DeciderSetup, Decision, ParamsResult
from companion.middleware.errors import MiddlewareError
from companion.middleware.forecast import LatencyEstimator, StreamForecaster
from companion.middleware.incremental import FixedItem, PlanItem, Problem, build_problem
from companion.middleware.knowledge import FleetKnowledge
from companion.middleware.mcts import MCTS, SearchResult, greedy_option
from companion.middleware.middleware import Middleware, MiddlewareConfig
from companion.middleware.reports import ReceiverReport, ReportLearned

_LAZY = {
    "AdaptiveConstraint": "companion.middleware.constraints.adaptive",
    "LinkStatsConstraint": "companion.middleware.constraints.adaptive",
    "AimdConstraint": "companion.middleware.constraints.aimd",
    "CONSTRAINTS": "companion.middleware.constraints.registry",
    "make_constraint": "companion.middleware.constraints.registry",
    "LinkStats": "companion.middleware.constraints.linkstats",
    "DECIDERS": "companion.middleware.policies",
    "make_decider": "companion.middleware.policies",
    "register_decider": "companion.middleware.policies",
}

__all__ = [
    "CONSTRAINTS",
    "DECIDERS",
    "MCTS",
    "AdaptiveConstraint",
    "AimdConstraint",
    "ConstantConstraint",
    "Decider",
    "DeciderSetup",
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
    "ParamsResult",
    "PlanItem",
    "Policy",
    "Problem",
    "RandomDrop",
    "ReceiverReport",
    "ReportLearned",
    "SearchResult",
    "SendAll",
    "StreamForecaster",
    "build_problem",
    "greedy_option",
    "make_constraint",
    "make_decider",
    "offline_optimum",
    "register_decider",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
