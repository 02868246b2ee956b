"""Shared builders for the middleware tests: small specs and hand-made problems."""

from __future__ import annotations

from typing import Any

import numpy as np

from companion.middleware.incremental import FixedItem, PlanItem, Problem, build_problem
from utility_specs.message import Message, Version
from utility_specs.spec import MissionSpec, parse_spec

T0 = 1_700_000_000.0


def small_spec() -> MissionSpec:
    """battery (max, Markovian), linear (sum), status (last), image (max, versions)."""
    raw: dict[str, Any] = {
        "mission": {"name": "test"},
        "types": {
            "battery": {"utility": "battery", "aggregation": "max", "weight": 2.0,
                        "per_sender": True, "markovian": True,
                        "params": {"depletion_rate": 0.2}},
            "linear": {"utility": "linear", "aggregation": "sum", "weight": 1.0,
                       "params": {"initial": 1.0, "slope": 0.25}},
            "status": {"utility": "status", "aggregation": "last", "weight": 0.5,
                       "per_sender": True, "markovian": True},
            "image": {"utility": "video_versions", "aggregation": "max", "weight": 1.0,
                      "per_sender": True, "markovian": True,
                      "params": {"S": 0.1, "f_max": 5.0, "f_1": 2.5}},
        },
    }
    return parse_spec(raw)


VERSIONS = (
    Version(name="full", size=4000, quality=1.0),
    Version(name="half", size=1000, quality=0.5),
    Version(name="quarter", size=250, quality=0.25),
)


def msg(sender: str, seq: int, type_: str, t_gen: float, size: int = 100, **data: Any) -> Message:
    if type_ == "battery":
        data.setdefault("level", 1.0)
    if type_ == "image":
        return Message(sender=sender, seq=seq, type=type_, t_gen=t_gen, size=VERSIONS[0].size,
                       data=data, versions=VERSIONS, version=0)
    return Message(sender=sender, seq=seq, type=type_, t_gen=t_gen, size=size, data=data)


def problem_of(
    spec: MissionSpec,
    messages: list[Message],
    *,
    latency: float = 0.1,
    horizon_end: float,
    budget_bytes: float = float("inf"),
    window_s: float = 1.0,
    decided: int = 0,
    fixed: list[FixedItem] | None = None,
) -> Problem:
    items = [
        PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + latency,
                 kind="decide" if k == decided else "forecast")
        for k, m in enumerate(messages)
    ]
    return build_problem(spec, items=items, fixed=fixed or [], horizon_end=horizon_end,
                         budget_bytes=budget_bytes, window_s=window_s)


def random_problem(spec: MissionSpec, n: int, budget: int, seed: int) -> Problem:
    """``n`` 100-byte messages of two senders and three kinds, 0.4 s apart with jitter, a
    window of 1 s holding ``budget`` of them."""
    rng = np.random.default_rng(seed)
    kinds = ["battery", "linear", "status"]
    messages = [
        msg(str(rng.choice(["a", "b"])), k, kinds[int(rng.integers(3))],
            T0 + float(k) * 0.4 + float(rng.uniform(0, 0.2)), size=100)
        for k in range(n)
    ]
    return problem_of(spec, messages, horizon_end=T0 + 6, budget_bytes=100 * budget,
                      window_s=1.0)
