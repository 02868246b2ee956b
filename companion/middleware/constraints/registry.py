"""The constraints by name: :func:`make_constraint` builds the one a configuration names.

>>> make_constraint("constant", limit_bytes_per_s=1000.0).limit_bytes_per_s(now=0.0)
1000.0
>>> sorted(CONSTRAINTS)
['adaptive', 'adaptive-smooth', 'adaptive-thesis', 'aimd', 'constant']

``"adaptive"`` (the default) and ``"adaptive-thesis"`` are the thesis' SGD with equal steps;
the studies that reproduce the thesis' figures name the latter, so they stay thesis-exact
whatever the default becomes. ``"adaptive-smooth"`` adds use-weighted steps, the knee
memory and a 5 ms queueing budget (:class:`AdaptiveConstraint`, docs/adaptive.md): smoother
than AIMD in figure 6.5 and mostly on the real link, but it still misses targets when the
loaded host starves the sender, so it is not the default.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Mapping

from companion.middleware.constraints.adaptive import AdaptiveConstraint
from companion.middleware.constraints.aimd import AimdConstraint
from companion.middleware.constraints.base import ConstantConstraint, GoodputConstraint
from companion.middleware.errors import ConstraintError

__all__ = ["CONSTRAINTS", "make_constraint"]

CONSTRAINTS: Mapping[str, Callable[..., GoodputConstraint]] = {
    "constant": ConstantConstraint,
    "adaptive": AdaptiveConstraint,
    "adaptive-thesis": functools.partial(AdaptiveConstraint, use_weighted=False, knee_band=0.0),
    "adaptive-smooth": functools.partial(AdaptiveConstraint, use_weighted=True, knee_band=0.05,
                                         knee_step=0.01, queueing_budget_s=0.005),
    "aimd": AimdConstraint,
}


def make_constraint(name: str, **params: object) -> GoodputConstraint:
    """Build the constraint called ``name`` with keyword ``params``.

    Raises :class:`ConstraintError` naming the known constraints, or the parameter that was
    not understood, so a typo in a mission file fails at start with a clear message.
    """
    try:
        factory = CONSTRAINTS[name]
    except KeyError:
        raise ConstraintError(
            f"unknown goodput constraint {name!r}; expected one of {sorted(CONSTRAINTS)}"
        ) from None
    try:
        inspect.signature(factory).bind(**params)
    except TypeError as exc:  # unexpected or missing keyword
        raise ConstraintError(f"bad parameters for goodput constraint {name!r}: {exc}") from None
    try:
        return factory(**params)
    except TypeError as exc:  # a value of the wrong type (a string for a number...)
        raise ConstraintError(f"bad parameters for goodput constraint {name!r}: {exc}") from None
