"""Shared builders and the slow reference integral the exact evaluator is checked against."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from utility_specs.evaluate import aggregate_at
from utility_specs.functions import UtilityFunction
from utility_specs.message import Message, StateHistory
from utility_specs.spec import InfoType, MissionSpec


def info(fn: UtilityFunction, aggregation: str = "max", **kw: object) -> InfoType:
    return InfoType(name="x", utility=fn, aggregation=aggregation, **kw)  # type: ignore[arg-type]


def spec_of(*types: InfoType) -> MissionSpec:
    return MissionSpec(name="test", types={t.name: t for t in types})


def msg(
    t_gen: float,
    t_rcv: float | None,
    *,
    seq: int = 0,
    sender: str = "a",
    receiver: str = "g",
    type: str = "x",
    **data: object,
) -> Message:
    return Message(
        sender=sender, receiver=receiver, seq=seq, type=type, t_gen=t_gen, t_rcv=t_rcv, data=data
    )


def reference_integral(
    info_type: InfoType,
    messages: Sequence[Message],
    t_end: float,
    *,
    history: StateHistory | None = None,
    step: float = 1e-3,
) -> float:
    """Midpoint rule over the literal A_p(M, t, s); error O(step) at each discontinuity."""
    history = history or StateHistory()
    n = math.ceil(t_end / step)
    h = t_end / n
    grid = (np.arange(n) + 0.5) * h
    return h * math.fsum(
        aggregate_at(info_type, messages, float(t), history.at(float(t))) for t in grid
    )
