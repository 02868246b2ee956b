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

import numpy as np

from companion.middleware.incremental import PlanItem, Problem, build_problem
from companion.middleware.knowledge import PlanningView
from companion.middleware.mcts import rollout_threshold
from utility_specs.errors import UtilitySpecsError
from utility_specs.spec import MissionSpec

__all__ = ["MODES", "denser", "expect_others", "plan_expected"]

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


def denser(problem: Problem, rates: dict[str, tuple[float, float]], *, agent: str,
           factor: float = 1.0) -> dict[str, tuple[float, float]]:
    """``rates`` of the senders whose streams are at least ``factor`` times as dense as this
    agent's (``expect_ranked``). A stream's density is what its messages add per byte when
    it is sent in full (each forecast message after the previous one of its stream, best
    version): the same measure for every sender, not a gain over what this agent happens to
    know each receiver holds (a peer's base is older in its knowledge than its own)."""
    later = np.nonzero((problem.stream >= 0) & (problem.pos > 0))[0]
    if not len(later):
        return rates
    prev = 1 + (problem.pos[later] - 1) * problem.max_versions
    density = problem.gain[later, 1, prev] / np.maximum(1, problem.size[later, 1])
    by_sender: dict[str, list[float]] = {}
    for i, d in zip(later.tolist(), density.tolist(), strict=True):
        by_sender.setdefault(problem.items[i].message.sender, []).append(d)
    mine = by_sender.get(agent)
    if not mine:
        return rates
    floor = factor * float(np.mean(mine))
    return {s: r for s, r in rates.items()
            if s not in by_sender or float(np.mean(by_sender[s])) >= floor}


def plan_expected(view: PlanningView, spec: MissionSpec, *, agent: str, now: float,
                  rates: dict[str, tuple[float, float]], mode: str, keep: Collection[str],
                  ranked: bool, margin: float, price: bool, budget: float, window_s: float,
                  tail_s: float) -> tuple[PlanningView, list[tuple[float, int]], float | None]:
    """The middleware's ``expect_*`` fields applied to one decision's view: the view without
    the others' forecast levels, the sends expected of them and, with ``price``, the fleet's
    price per byte (the default policy's threshold on the whole fleet's forecast; else None).

    ``ranked`` counts only denser senders (:func:`denser`); in ``"demand"`` mode with
    ``margin`` > 1, a sender within the margin counts at the rate it was seen to send
    (``"spread"``), a denser one at its demand. Ranking and price build the fleet's tables
    once more (the others' forecasts included).
    """
    sent_rates = rates
    if mode == "demand":  # every forecast sender is a candidate
        rates = {it.message.sender: rates.get(it.message.sender, (0.0, 0.0))
                 for it in view.items if it.kind == "forecast"}
    lam = None
    more: list[tuple[float, int]] = []
    if price or ranked:
        try:
            full: Problem | None = build_problem(
                spec, items=view.items, fixed=view.fixed, horizon_end=view.horizon_end + tail_s,
                budget_bytes=budget, window_s=window_s, root_window=view.root_window,
                receivers=view.receivers)
        except UtilitySpecsError:
            full = None
        if full is not None and ranked:
            rates = denser(full, rates, agent=agent, factor=margin)
            if margin > 1 and mode == "demand":  # near-equals at the rate they were seen to send
                similar = {s: r for s, r in denser(full, sent_rates, agent=agent,
                                                   factor=1 / margin).items() if s not in rates}
                _, more = expect_others(view, spec, agent=agent, now=now, rates=similar,
                                        mode="spread")
        if full is not None and price:
            lam = rollout_threshold(full)
    view, expected = expect_others(view, spec, agent=agent, now=now, rates=rates, mode=mode,
                                   keep=keep)
    return view, sorted(expected + more), lam
