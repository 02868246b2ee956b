"""Pick a goodput constraint by name, as the mission configuration names it.

>>> make_constraint("constant", limit_bytes_per_s=1000.0).limit_bytes_per_s(now=0.0)
1000.0
>>> sorted(CONSTRAINTS)
['adaptive', 'aimd', 'constant']
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

from companion.middleware.adaptive import AdaptiveConstraint
from companion.middleware.aimd import AimdConstraint
from companion.middleware.constraint import ConstantConstraint, GoodputConstraint

__all__ = ["CONSTRAINTS", "make_constraint"]

CONSTRAINTS: Mapping[str, Callable[..., GoodputConstraint]] = {
    "constant": ConstantConstraint,
    "adaptive": AdaptiveConstraint,
    "aimd": AimdConstraint,
}


def make_constraint(name: str, **params: Any) -> GoodputConstraint:
    """Build the constraint called ``name`` with keyword ``params``.

    Raises ValueError naming the known constraints, or the parameter that was not
    understood, so a typo in a mission file fails at start with a clear message.
    """
    try:
        factory = CONSTRAINTS[name]
    except KeyError:
        raise ValueError(
            f"unknown goodput constraint {name!r}; expected one of {sorted(CONSTRAINTS)}"
        ) from None
    try:
        inspect.signature(factory).bind(**params)
    except TypeError as exc:  # unexpected or missing keyword
        raise ValueError(f"bad parameters for goodput constraint {name!r}: {exc}") from None
    return factory(**params)
