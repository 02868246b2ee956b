"""Pick a decision policy by name, as the companion configuration names it.

``[middleware] policy = "mcts"`` (the default) and the policy's own keys in the same table:

>>> sorted(DECIDERS)
['greedy', 'knapsack_greedy', 'mcts', 'random_drop', 'send_all']

A new policy is one module with a class that has the :class:`Decider` methods and a
``from_setup(setup, **params)`` factory, plus one line in :data:`DECIDERS` (or one
:func:`register_decider` call). See docs/architecture.md, "Adding a policy".
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from companion.middleware.baselines import Greedy, KnapsackGreedy, RandomDrop, SendAll
from companion.middleware.decider import Decider, DeciderSetup, ParamValue
from companion.middleware.errors import (
    MiddlewareError,
    ParamError,
    UnknownParamError,
    UnknownPolicyError,
)
from companion.middleware.middleware import Middleware

__all__ = ["DECIDERS", "DeciderFactory", "make_decider", "policy_params", "register_decider"]

DeciderFactory = Callable[..., Decider]
"""``factory(setup: DeciderSetup, **params) -> Decider``; its keyword parameters are the
policy's configuration keys (checked against its signature before it is called)."""

DECIDERS: dict[str, DeciderFactory] = {
    "mcts": Middleware.from_setup,
    "send_all": SendAll.from_setup,
    "random_drop": RandomDrop.from_setup,
    "greedy": Greedy.from_setup,
    "knapsack_greedy": KnapsackGreedy.from_setup,
}


def register_decider(name: str, factory: DeciderFactory) -> None:
    """Add a policy under ``name`` (a plug-in's one registry line); names are unique."""
    if not name or name in DECIDERS:
        raise MiddlewareError(f"policy name {name!r} is empty or already registered")
    DECIDERS[name] = factory


def policy_params(name: str) -> list[str]:
    """The configuration keys policy ``name`` takes (its factory's keyword parameters)."""
    factory = _factory(name)
    return [p.name for p in list(inspect.signature(factory).parameters.values())[1:]
            if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]


def _factory(name: object) -> DeciderFactory:
    if not isinstance(name, str) or name not in DECIDERS:
        raise UnknownPolicyError(name, sorted(DECIDERS))
    return DECIDERS[name]


def make_decider(name: str, setup: DeciderSetup, **params: ParamValue) -> Decider:
    """Build policy ``name`` from ``setup`` and its own ``params``.

    Raises :class:`UnknownPolicyError` (lists the registered names), :class:`UnknownParamError`
    (lists the policy's keys) or another :class:`MiddlewareError` for a bad value.
    """
    factory = _factory(name)
    signature = inspect.signature(factory)
    takes_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
    if not takes_any:
        known = policy_params(name)
        for key in params:
            if key not in known:
                raise UnknownParamError(key, known, owner=f"the {name} policy")
    try:
        return factory(setup, **params)
    except TypeError as exc:  # a value of the wrong type deep in a constructor
        raise ParamError(f"policy {name}: {exc}") from None
