"""Plans agreed over the link (issue 18, round 10): each agent announces, with the messages
it sends, what it plans to do with its own forecast messages of the horizon; a receiver
fixes the other agents' levels of its tree to the option they announced (or, as a prior,
only in the default policy), so its search covers its own decisions and the un-announced
rest of the fleet.

Sans-I/O: the shell carries an :class:`AnnouncedPlan` with a sent message (``wire_bytes``
on the wire, in the message's header) and hands received ones to ``Middleware.on_plan``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from companion.middleware.incremental import Problem

__all__ = ["AGREED_MODES", "AgreedPlans", "AnnouncedPlan", "PlanEntry", "complete_plan",
           "own_plan"]

AGREED_MODES = ("fix", "prior")
"""``MiddlewareConfig.agreed_plans``: fix the announced levels in the tree, or only in the
default policy's rollouts."""

_SLACK = 1e-9


@dataclass(frozen=True, slots=True)
class PlanEntry:
    """One forecast message of the announcing agent and the option it plans for it."""

    type: str
    t_gen: float
    option: int
    """0: drop; o > 0: send option o (version o - 1)."""


@dataclass(frozen=True, slots=True)
class AnnouncedPlan:
    sender: str
    made_t: float
    """When the plan was made (the decision it came from)."""
    until_t: float
    """The horizon's end: the plan says nothing about later messages."""
    entries: tuple[PlanEntry, ...]

    def wire_bytes(self) -> int:
        """Bytes the plan takes in a message header: per stream a type index (1 byte), the
        first forecast time as an offset in ms (2 bytes) and 1 bit per message (2 bits with
        versions); a receiver forecasts the stream's period itself."""
        by_type: dict[str, list[int]] = {}
        for e in self.entries:
            by_type.setdefault(e.type, []).append(e.option)
        total = 0
        for options in by_type.values():
            bits = 1 if max(options) <= 1 else 2
            total += 3 + math.ceil(len(options) * bits / 8)
        return total


def complete_plan(problem: Problem, path: Sequence[int], lam: float) -> list[int]:
    """The plan behind a search's answer: the path's options, then the default policy of the
    kernel (``_kernel._rollout``: the highest gain that earns ``lam`` per byte and fits the
    window; announced levels take their option when it fits)."""
    n = problem.n
    options = [0] * n
    last = [0] * problem.n_streams
    window: list[tuple[float, int]] = [
        (float(t), int(b)) for t, b in zip(problem.root_win_t, problem.root_win_bytes,
                                           strict=True)]
    budget = problem.budget_bytes
    for i in range(n):
        t = float(problem.send_t[i])
        lo = t - problem.window_s - _SLACK
        used = sum(b for wt, b in window if wt >= lo)
        s = int(problem.stream[i])
        slot = last[s] if s >= 0 else 0
        best_o = 0
        forced = int(problem.force[i])
        if i < len(path):
            best_o = int(path[i])
        elif forced >= 0:
            if forced > 0 and used + int(problem.size[i, forced]) <= budget + _SLACK:
                best_o = forced
        else:
            best_g = 0.0
            for o in range(1, int(problem.nopt[i])):
                sz = int(problem.size[i, o])
                g = float(problem.gain[i, o, slot])
                if g <= best_g or g < lam * sz or used + sz > budget + _SLACK:
                    continue
                best_o, best_g = o, g
        options[i] = best_o
        if best_o:
            window.append((t, int(problem.size[i, best_o])))
            if s >= 0:
                last[s] = problem.next_slot(i, best_o, slot)
    return options


def own_plan(problem: Problem, path: Sequence[int], lam: float, *, agent: str, now: float
             ) -> AnnouncedPlan:
    """What ``agent`` plans for its own forecast messages after this decision."""
    options = complete_plan(problem, path, lam)
    entries = tuple(
        PlanEntry(it.message.type, float(it.message.t_gen), options[i])
        for i, it in enumerate(problem.items)
        if it.kind == "forecast" and it.message.sender == agent
    )
    return AnnouncedPlan(sender=agent, made_t=now, until_t=float(problem.horizon_end),
                         entries=entries)


class AgreedPlans:
    """The newest plan heard from each other agent, matched to the tree's levels."""

    __slots__ = ("agent", "kinds", "plans")

    def __init__(self, agent: str, *, kinds: tuple[str, ...] = ("forecast",)) -> None:
        self.agent = agent
        self.kinds = kinds
        """Kinds of tree items an announced plan fixes (in-flight ones were re-decided when
        they were generated, so by default only forecasts)."""
        self.plans: dict[str, AnnouncedPlan] = {}

    def hear(self, plan: AnnouncedPlan) -> None:
        old = self.plans.get(plan.sender)
        if plan.sender != self.agent and (old is None or plan.made_t >= old.made_t):
            self.plans[plan.sender] = plan

    def force(self, problem: Problem, *, own: AnnouncedPlan | None = None,
              commit_s: float = 0.0) -> npt.NDArray[np.int64]:
        """Per level the announced option (-1: no fresh plan names it). With ``own`` (this
        agent's last published plan) and ``commit_s``, this agent keeps its own word too:
        its messages generated up to ``commit_s`` after that plan was made take the option
        the plan gave them (the decided one included)."""
        force = np.full(problem.n, -1, dtype=np.int64)
        for i, it in enumerate(problem.items):
            m = it.message
            if m.sender == self.agent:
                if own is None or it.kind == "inflight" or m.t_gen > own.made_t + commit_s:
                    continue
                plan: AnnouncedPlan | None = own
            else:
                plan = self.plans.get(m.sender)
                if it.kind not in self.kinds:
                    continue
            if plan is not None and it.send_t <= plan.until_t:
                force[i] = _match(plan, m.type, float(m.t_gen), int(problem.nopt[i]))
        return force


def _match(plan: AnnouncedPlan, type_: str, t_gen: float, nopt: int) -> int:
    """The plan's option for the message of ``type_`` generated at ``t_gen``: its entry of
    that type nearest in time, within half the entries' spacing (a receiver's forecast of
    a stream's phase is not exact); -1: none."""
    times = [e for e in plan.entries if e.type == type_]
    if not times:
        return -1
    gaps = [b.t_gen - a.t_gen for a, b in itertools.pairwise(times)]
    tol = 0.5 * min(gaps) if gaps else 0.5
    best = min(times, key=lambda e: abs(e.t_gen - t_gen))
    if abs(best.t_gen - t_gen) <= tol and best.option < nopt:
        return best.option
    return -1
