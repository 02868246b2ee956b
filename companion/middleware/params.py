"""Live parameters of the optimiser: check every key, then apply all or nothing.

A ``set_params`` command (thesis sec. 3.3) changes the optimiser between two decisions:
``mcts_iterations``, ``time_budget_s``, ``alpha`` (eq. 7.1/7.2, rebuilds the mission spec's
utility functions), the optimiser's own numbers (:data:`LIVE_KEYS`) and ``constraint.NAME``
(a number of the goodput constraint). :func:`check_params` validates them all and returns
the complete new state, so applying cannot fail half-way.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.decider import ParamValue
from companion.middleware.errors import MiddlewareError, ParamError, UnknownParamError
from utility_specs.errors import SpecError
from utility_specs.functions import make_function
from utility_specs.spec import MissionSpec

if TYPE_CHECKING:
    from companion.middleware.middleware import MiddlewareConfig

__all__ = ["LIVE_KEYS", "CheckedParams", "check_params", "with_alpha"]

LIVE_KEYS = (
    "c", "horizon_s", "tail_s", "default_latency_s", "max_items", "chunk_iterations",
    "search_inflight",
)
"""``MiddlewareConfig`` fields a live ``set_params`` (and the ``[middleware]`` table) may set."""

_WHOLE = ("mcts_iterations", "max_items", "chunk_iterations")


@dataclass(frozen=True, slots=True, kw_only=True)
class CheckedParams:
    """The state after a ``set_params`` that passed every check."""

    config: MiddlewareConfig
    constraint: Mapping[str, float]
    """Constraint numbers to set (:meth:`GoodputConstraint.apply_params`)."""
    applied: Mapping[str, ParamValue]


def _number(key: str, value: ParamValue, *, low: int = 0) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ParamError(f"{key} must be a number, got {value!r}")
    if key in _WHOLE and (not isinstance(value, int) or value < low):
        raise ParamError(f"{key} must be a whole number >= {low}, got {value!r}")
    return value


def with_alpha(spec: MissionSpec, alpha: ParamValue) -> MissionSpec:
    """``spec`` with α set in every utility function that has one (eq. 7.1/7.2)."""
    if isinstance(alpha, bool) or not isinstance(alpha, int | float) or alpha < 0:
        raise ParamError(f"alpha must be a number >= 0, got {alpha!r}")
    types = dict(spec.types)
    changed = False
    for name, info in spec.types.items():
        utility = info.utility
        if "alpha" in utility.params():
            try:
                fn = make_function(utility.name, {**utility.params(), "alpha": float(alpha)})
            except SpecError as exc:
                raise ParamError(str(exc)) from None
            types[name] = dataclasses.replace(info, utility=fn)
            changed = True
    if not changed:
        raise ParamError("alpha: no information type of the mission uses alpha")
    return dataclasses.replace(spec, types=types)


def known_keys(constraint: GoodputConstraint) -> list[str]:
    return ["mcts_iterations", "time_budget_s", "alpha", *LIVE_KEYS,
            *(f"constraint.{name}" for name in sorted(constraint.tunable()))]


def check_params(config: MiddlewareConfig, constraint: GoodputConstraint,
                 params: Mapping[str, ParamValue]) -> CheckedParams:
    """Validate ``params`` against the current state; raises :class:`ParamError` naming the
    first rejected key and why. Nothing is changed."""
    changes: dict[str, float | int | None] = {}
    constraint_changes: dict[str, ParamValue] = {}
    applied: dict[str, ParamValue] = {}
    spec = config.spec
    for key, value in params.items():
        if key == "time_budget_s":
            if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
                raise ParamError(f"time_budget_s must be a number > 0, got {value!r}")
            changes["time_budget_s"] = applied[key] = float(value)
        elif key == "alpha":
            spec = with_alpha(spec, value)
            applied[key] = float(value)  # type: ignore[arg-type]  # checked by with_alpha
        elif key == "mcts_iterations":
            # 0 would leave every decision to the greedy fallback; the config refuses it too
            changes["max_iterations"] = applied[key] = _number(key, value, low=1)
        elif key in LIVE_KEYS:
            changes[key] = applied[key] = _number(key, value)
        elif key.startswith("constraint."):
            constraint_changes[key.removeprefix("constraint.")] = value
        else:
            raise UnknownParamError(key, known_keys(constraint), owner="the mcts policy")
    try:
        new_config = dataclasses.replace(config, spec=spec, **changes)  # type: ignore[arg-type]
    except (MiddlewareError, TypeError) as exc:
        raise ParamError(str(exc)) from None
    checked = constraint.check_params(constraint_changes) if constraint_changes else {}
    applied.update({f"constraint.{k}": v for k, v in checked.items()})
    return CheckedParams(config=new_config, constraint=checked, applied=applied)
