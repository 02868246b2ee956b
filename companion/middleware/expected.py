"""Other agents' future sends valued by expectation, not searched (issue 18, round 8).

In the tree of one decision the other agents' forecast messages used to be levels: the
search chose, for them, whether they go. So it optimised a model in which the others
follow this agent's plan, and a better model plan was not a better fleet outcome (round 7).
Here they leave the tree, as their in-flight messages already do
(:func:`~companion.middleware.knowledge.settle_inflight`), and in their place each other
sender's *expected* sends over the horizon join the goodput windows: whole messages at the
rate it was last seen to send (:meth:`FleetKnowledge.sender_rates`: bytes/s and mean
message bytes). The search then checks this agent's plan against what the others will
most likely use. Their utility is not this agent's to gain, so it does not enter the gains.

Two placements (``mode``):

* ``"spread"``: ``round(rate · H / size)`` messages evenly over the horizon ``(now, end]``;
* ``"forecast"``: as many messages, placed at that sender's forecast send times (evenly
  chosen among them, at most one per forecast message): the sent share of its stream.
* ``"demand"`` (not by rate): every forecast message of the senders in ``rates`` is
  expected, in the mean size the sender is seen to send (else its best version). The
  middleware passes the senders whose streams are denser than its own
  (``expect_ranked``): a sender that waits for room is then not locked out by the rate of
  those that took the window first.

Streams that couple senders keep the others' forecast levels in the tree: a ``max`` or
``last`` type with ``per_sender = false`` aggregates every sender's messages in one stream
(:func:`~companion.middleware.incremental.stream_of` returns sender None), so whether
another agent sends there changes what this agent's message adds. No built-in mission
has one (their fleet-level types are ``sum``: independent items), so this only keeps a
user spec's shared stream exact. The forecast levels of the senders in ``keep`` stay in
the tree as well (the middleware's ``expect_keep_unrated``: senders never yet heard sending,
at the mission start, whose rate says nothing).
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import replace

from companion.middleware.incremental import PlanItem
from companion.middleware.knowledge import PlanningView
from utility_specs.spec import MissionSpec

__all__ = ["MODES", "expect_others"]

MODES = ("spread", "forecast", "demand")


def _couples_senders(spec: MissionSpec, item: PlanItem) -> bool:
    info = spec.types[item.message.type]
    return info.aggregation != "sum" and not info.per_sender


def expect_others(view: PlanningView, spec: MissionSpec, *, agent: str, now: float,
                  rates: dict[str, tuple[float, float]], mode: str = "spread",
                  keep: Collection[str] = ()) -> tuple[PlanningView, list[tuple[float, int]]]:
    """The view without the other agents' forecast levels, and (send time, bytes) of the
    sends expected of them in ``(now, view.horizon_end]`` in their place."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    out: dict[str, list[PlanItem]] = {}
    kept: list[PlanItem] = []
    for it in view.items:
        sender = it.message.sender
        if it.kind != "forecast" or sender == agent or _couples_senders(spec, it) \
                or sender in keep:
            kept.append(it)
        else:
            out.setdefault(sender, []).append(it)
    span = view.horizon_end - now
    expected: list[tuple[float, int]] = []
    for sender, (rate, size) in sorted(rates.items()):
        if mode == "demand" and sender != agent:
            # in the size it is seen to send (a version), else the forecast's best version
            expected += [(it.send_t, int(size) if size > 0 else it.message.size)
                         for it in out.get(sender, []) if it.send_t > now]
            continue
        if sender == agent or size <= 0 or span <= 0:
            continue
        n = math.floor(rate * span / size + 0.5)  # whole messages (see settle_inflight)
        if mode == "spread":
            expected += [(now + (i + 0.5) * span / n, int(size)) for i in range(n)]
            continue
        times = sorted(it.send_t for it in out.get(sender, []) if it.send_t > now)
        n = min(n, len(times))
        expected += [(times[int((i + 0.5) * len(times) / n)], int(size)) for i in range(n)]
    return replace(view, items=kept), sorted(expected)
