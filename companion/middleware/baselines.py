"""Baseline policies with the middleware's interface, and the exact offline optimum.

``send_all``, ``random_drop(p)`` (seeded), ``greedy`` (send while the fleet's window budget
allows), ``knapsack_greedy`` (utility per byte within the window budget) and
:func:`offline_optimum`: dynamic programming over the tree's levels with full knowledge,
where the Markovian reduction (eq. 5.8/5.9) makes the exact search feasible for small
instances. It is the ceiling every policy is measured against.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from typing import Self

import numpy as np

from companion.middleware import _beam
from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.decider import (
    COMPANION_ALWAYS_SEND,
    Decider,
    DeciderSetup,
    Decision,
    ParamsResult,
    ParamValue,
)
from companion.middleware.errors import MiddlewareError, ParamError
from companion.middleware.incremental import Problem, build_problem, option_message
from companion.middleware.knowledge import FleetKnowledge
from companion.middleware.reports import ReceiverReport, ReportLearned, deliveries, feed_link
from utility_specs.message import Message
from utility_specs.spec import MissionSpec

__all__ = [
    "Baseline",
    "Greedy",
    "KnapsackGreedy",
    "OptimumResult",
    "Policy",
    "RandomDrop",
    "SendAll",
    "knapsack_option",
    "offline_optimum",
]

Policy = Decider
"""The old name of :class:`~companion.middleware.decider.Decider` (kept for importers)."""



def _send(message: Message, reason: str, version: int = 0) -> Decision:
    return Decision(send=True, version=version if message.versions else None, reason=reason)


class Baseline:
    """What every baseline shares: types it always sends, reports, no live parameters
    but the constraint's, no timers. Subclasses implement :meth:`_decide`."""

    constraint: GoodputConstraint | None = None
    agent: str = ""

    def __init__(self, *, always_send: Collection[str] = ()) -> None:
        self.always_send = frozenset(always_send)

    def decide(self, message: Message, now: float) -> Decision:
        if message.type in self.always_send:
            return Decision(send=True, version=None, reason="baseline-status")
        return self._decide(message, now)

    def _decide(self, message: Message, now: float) -> Decision:
        raise NotImplementedError

    def on_delivered(self, messages: Iterable[Message], now: float) -> None:
        return None

    def on_report(self, report: ReceiverReport, now: float) -> ReportLearned:
        """Deliveries to :meth:`on_delivered`, own link samples to the constraint if any."""
        messages, bad = deliveries(report)
        self.on_delivered(messages, now)
        if self.constraint is None:
            return ReportLearned(bad_entries=bad)
        return ReportLearned(bad_entries=bad,
                             link=feed_link(self.constraint, report, agent=self.agent, now=now))

    def set_params(self, params: Mapping[str, ParamValue], now: float) -> ParamsResult:
        """Only ``constraint.NAME`` keys, when the policy has a constraint."""
        del now
        name = type(self).__name__
        if self.constraint is None or any(not k.startswith("constraint.") for k in params):
            return ParamsResult.rejected(f"the {name} baseline has no live parameters"
                                         + (" but constraint.NAME" if self.constraint else ""))
        try:
            checked = self.constraint.check_params(
                {k.removeprefix("constraint."): v for k, v in params.items()})
        except ParamError as exc:
            return ParamsResult.rejected(str(exc))
        self.constraint.apply_params(checked)
        return ParamsResult(applied={f"constraint.{k}": v for k, v in checked.items()})

    def get_timer(self) -> float | None:
        return None

    def handle_timer(self, now: float) -> None:
        return None


class SendAll(Baseline):
    """Send every message in its best version."""

    @classmethod
    def from_setup(cls, setup: DeciderSetup, *,
                   always_send: Collection[str] = COMPANION_ALWAYS_SEND) -> Self:
        return cls(always_send=always_send)

    def _decide(self, message: Message, now: float) -> Decision:
        return _send(message, "send-all")


class RandomDrop(Baseline):
    """Drop each message with probability ``p`` (the thesis' random baseline); send the best
    version, or with ``any_version`` one of its versions picked uniformly (the same versions
    to choose from as the optimiser, which also keeps the delivered volume less lumpy)."""

    def __init__(self, p: float, *, rng: np.random.Generator, any_version: bool = False,
                 always_send: Collection[str] = ()) -> None:
        super().__init__(always_send=always_send)
        if isinstance(p, bool) or not isinstance(p, int | float) or not 0.0 <= p <= 1.0:
            raise ParamError(f"drop probability must be in [0, 1], got {p!r}")
        self.p = p
        self.rng = rng
        self.any_version = bool(any_version)

    @classmethod
    def from_setup(cls, setup: DeciderSetup, *, drop_probability: float = 0.5,
                   any_version: bool = False,
                   always_send: Collection[str] = COMPANION_ALWAYS_SEND) -> Self:
        return cls(drop_probability, rng=setup.rng, any_version=any_version,
                   always_send=always_send)

    def _decide(self, message: Message, now: float) -> Decision:
        if self.rng.random() < self.p:
            return Decision(send=False, reason="random-drop")
        if self.any_version and message.versions:
            version = int(self.rng.integers(len(message.versions)))
            return Decision(send=True, version=version, reason="random-send")
        return _send(message, "random-send")


class _Knowing(Baseline):
    """A policy that tracks the fleet's sends like the middleware does."""

    constraint: GoodputConstraint

    def __init__(
        self, spec: MissionSpec, *, agent: str, constraint: GoodputConstraint,
        default_latency_s: float = 0.05, always_send: Collection[str] = (),
    ) -> None:
        super().__init__(always_send=always_send)
        self.spec = spec
        self.agent = agent
        self.constraint = constraint
        self.knowledge = FleetKnowledge(spec, agent=agent, default_latency_s=default_latency_s,
                                        spread_forecasts=False)
        self.knowledge.forecaster.heartbeats = self.always_send

    def _commit(self, message: Message, decision: Decision, now: float) -> Decision:
        if decision.send:
            sent = option_message(message, (decision.version or 0) + 1)
            self.knowledge.on_sent(sent, now=now)
            self.constraint.on_sent(sent.size, now=now)
        self.knowledge.forget(now=now, keep_s=2.0 * self.constraint.window_s + 5.0)
        return decision

    def on_delivered(self, messages: Iterable[Message], now: float) -> None:
        self.knowledge.on_delivered(messages, now=now)


class Greedy(_Knowing):
    """Send the best version that fits the fleet's window budget, else drop."""

    @classmethod
    def from_setup(cls, setup: DeciderSetup, *, default_latency_s: float = 0.05,
                   always_send: Collection[str] = COMPANION_ALWAYS_SEND) -> Self:
        return cls(setup.spec, agent=setup.agent, constraint=setup.constraint,
                   default_latency_s=default_latency_s, always_send=always_send)

    def _decide(self, message: Message, now: float) -> Decision:
        self.knowledge.on_generated(message)
        used = self.knowledge.sent_in_window(now=now, window_s=self.constraint.window_s)
        budget = self.constraint.budget_bytes(now=now)
        sizes = [v.size for v in message.versions] if message.versions else [message.size]
        for v, size in enumerate(sizes):
            if used + size <= budget + 1e-9:
                return self._commit(message, _send(message, "greedy", v), now)
        return self._commit(message, Decision(send=False, reason="greedy-full"), now)


class KnapsackGreedy(_Knowing):
    """Fill the next window's budget by utility per byte (fractional-knapsack order).

    The candidates are this message and the messages forecast for the next window T; each is
    valued by what it adds over the horizon given what was already delivered. The message
    is sent (in its densest version) when it makes the cut.
    """

    def __init__(
        self, spec: MissionSpec, *, agent: str, constraint: GoodputConstraint,
        horizon_s: float = 3.0, default_latency_s: float = 0.05,
        always_send: Collection[str] = (),
    ) -> None:
        super().__init__(spec, agent=agent, constraint=constraint,
                         default_latency_s=default_latency_s, always_send=always_send)
        self.horizon_s = horizon_s

    @classmethod
    def from_setup(cls, setup: DeciderSetup, *, horizon_s: float = 3.0,
                   default_latency_s: float = 0.05,
                   always_send: Collection[str] = COMPANION_ALWAYS_SEND) -> Self:
        return cls(setup.spec, agent=setup.agent, constraint=setup.constraint,
                   horizon_s=horizon_s, default_latency_s=default_latency_s,
                   always_send=always_send)

    def _decide(self, message: Message, now: float) -> Decision:
        self.knowledge.on_generated(message)
        window_s = self.constraint.window_s
        view = self.knowledge.view(message, now=now, horizon_s=self.horizon_s, max_items=64,
                                   window_s=window_s)
        problem = build_problem(
            self.spec, items=view.items, fixed=view.fixed, horizon_end=view.horizon_end,
            budget_bytes=self.constraint.budget_bytes(now=now), window_s=window_s,
            root_window=view.root_window,
        )
        used = self.knowledge.sent_in_window(now=now, window_s=window_s)
        o = knapsack_option(problem, problem.decided_level, room=problem.budget_bytes - used,
                            now=now)
        if o:
            return self._commit(message, _send(message, "knapsack", o - 1), now)
        return self._commit(message, Decision(send=False, reason="knapsack-out"), now)


def knapsack_option(problem: Problem, level: int, *, room: float, now: float) -> int:
    """Knapsack-greedy's option for ``level`` (0: drop): its densest version when it makes
    the utility-per-byte cut, in ``room`` bytes, among the items of the next window T."""
    window_s = problem.window_s
    candidates: list[tuple[float, int, int]] = []
    for i in range(problem.n):
        if problem.send_t[i] > now + window_s or (i != level and problem.send_t[i] < now):
            continue
        density, best = max(
            (float(problem.gain[i, o, 0]) / max(1, int(problem.size[i, o])), o)
            for o in range(1, int(problem.nopt[i]))
        )
        if density > 0:
            candidates.append((density, i, best))
    candidates.sort(key=lambda c: (-c[0], c[1] != level))
    for _, i, o in candidates:
        size = int(problem.size[i, o])
        if size > room + 1e-9:
            continue
        if i == level:
            return o
        room -= size
    return 0


@dataclass(frozen=True, slots=True, kw_only=True)
class OptimumResult:
    """The best feasible plan: one option per level and the utility it adds."""

    choices: tuple[int, ...]
    gain: float
    states: int
    """Largest number of distinct states kept on one level."""


_State = tuple[tuple[int, ...], tuple[tuple[float, int], ...]]
"""(each stream's last sent slot, the sends (time, bytes) still inside the window)."""


def offline_optimum(problem: Problem, *, max_states: int = 500_000) -> OptimumResult:
    """Exact optimum of the problem's model under the window constraint (eq. 5.5/5.7).

    Dynamic programming over levels: a state is each stream's last sent message plus the
    sends still inside a window reaching the next level (tantamount nodes, eq. 5.8 and
    footnote 5), keeping the best utility per state. Raises ``MiddlewareError`` if a level holds
    more than ``max_states`` states (the instance is not small).
    """
    n = problem.n
    budget = problem.budget_bytes
    window_s = problem.window_s
    root = tuple(
        (float(t), int(b)) for t, b in zip(problem.root_win_t, problem.root_win_bytes, strict=True)
    )
    canon = _beam.canonical_slots(problem).tolist()
    start = (tuple([0] * problem.n_streams), root)
    layer: dict[_State, float] = {start: 0.0}
    back: list[dict[_State, tuple[_State, int]]] = []
    widest = 1
    for i in range(n):
        t_i = float(problem.send_t[i])
        t_next = float(problem.send_t[i + 1]) if i + 1 < n else float("inf")
        lo_i = t_i - window_s - 1e-9
        lo_next = t_next - window_s - 1e-9
        s = int(problem.stream[i])
        gain_i = problem.gain[i]
        nxt: dict[_State, float] = {}
        came: dict[_State, tuple[_State, int]] = {}
        for state, u in layer.items():
            last, win = state
            inside = tuple(w for w in win if w[0] >= lo_i)
            used = sum(b for _, b in inside)
            slot = last[s] if s >= 0 else 0
            for o in range(int(problem.nopt[i])):
                if o == 0:
                    new_last, new_win, g = last, inside, 0.0
                else:
                    size = int(problem.size[i, o])
                    if used + size > budget + 1e-9:
                        continue
                    g = float(gain_i[o, slot])
                    new_win = (*inside, (t_i, size))
                    new_last = last
                    if s >= 0:
                        new_last = (*last[:s], int(problem.nslot[i, o, slot]), *last[s + 1 :])
                if s >= 0 and canon[i][new_last[s]] != new_last[s]:
                    new_last = (*new_last[:s], int(canon[i][new_last[s]]), *new_last[s + 1 :])
                key = (new_last, tuple(w for w in new_win if w[0] >= lo_next))
                value = u + g
                old = nxt.get(key)
                if old is None or value > old + 1e-12:
                    nxt[key] = value
                    came[key] = (state, o)
        if len(nxt) > max_states:
            raise MiddlewareError(
                f"offline_optimum: {len(nxt)} states at level {i} exceed max_states={max_states}"
            )
        widest = max(widest, len(nxt))
        back.append(came)
        layer = nxt
    best_state = max(layer, key=lambda k: layer[k])
    best_u = layer[best_state]
    path: list[int] = []
    state = best_state
    for came in reversed(back):
        state, o = came[state]
        path.append(o)
    best_path = tuple(reversed(path))
    return OptimumResult(choices=best_path, gain=best_u, states=widest)
