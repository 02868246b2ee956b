"""Baseline policies with the middleware's interface, and the exact offline optimum.

``send_all``, ``random_drop(p)`` (seeded), ``greedy`` (send while the fleet's window budget
allows), ``knapsack_greedy`` (utility per byte within the window budget) and
:func:`offline_optimum`: dynamic programming over the tree's levels with full knowledge,
where the Markovian reduction (eq. 5.8/5.9) makes the exact search feasible for small
instances. It is the ceiling every policy is measured against.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from companion.middleware.constraint import GoodputConstraint
from companion.middleware.incremental import Problem, build_problem, option_message
from companion.middleware.knowledge import FleetKnowledge
from companion.middleware.middleware import Decision
from utility_specs.message import Message
from utility_specs.spec import MissionSpec

__all__ = [
    "Greedy",
    "KnapsackGreedy",
    "OptimumResult",
    "Policy",
    "RandomDrop",
    "SendAll",
    "knapsack_option",
    "offline_optimum",
]


class Policy(Protocol):
    """What the simulator and the companion app need from a policy."""

    def decide(self, message: Message, now: float) -> Decision: ...

    def on_delivered(self, messages: Iterable[Message], now: float) -> None: ...


def _send(message: Message, reason: str, version: int = 0) -> Decision:
    return Decision(send=True, version=version if message.versions else None, reason=reason)


class SendAll:
    """Send every message in its best version."""

    def decide(self, message: Message, now: float) -> Decision:
        return _send(message, "send-all")

    def on_delivered(self, messages: Iterable[Message], now: float) -> None:
        return None


class RandomDrop:
    """Drop each message with probability ``p`` (the thesis' random baseline)."""

    def __init__(self, p: float, *, rng: np.random.Generator) -> None:
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"drop probability must be in [0, 1], got {p}")
        self.p = p
        self.rng = rng

    def decide(self, message: Message, now: float) -> Decision:
        if self.rng.random() < self.p:
            return Decision(send=False, reason="random-drop")
        return _send(message, "random-send")

    def on_delivered(self, messages: Iterable[Message], now: float) -> None:
        return None


class _Knowing:
    """A policy that tracks the fleet's sends like the middleware does."""

    def __init__(
        self, spec: MissionSpec, *, agent: str, constraint: GoodputConstraint,
        default_latency_s: float = 0.05,
    ) -> None:
        self.spec = spec
        self.agent = agent
        self.constraint = constraint
        self.knowledge = FleetKnowledge(spec, agent=agent, default_latency_s=default_latency_s)

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

    def decide(self, message: Message, now: float) -> Decision:
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
    ) -> None:
        super().__init__(spec, agent=agent, constraint=constraint,
                         default_latency_s=default_latency_s)
        self.horizon_s = horizon_s

    def decide(self, message: Message, now: float) -> Decision:
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


def _canonical_slots(problem: Problem) -> list[list[int]]:
    """Per level i: each slot of item i's stream mapped to the smallest slot with the same
    future (identical gains and transitions for every later item of the stream). Messages
    whose utility has run out before the remaining items arrive all become one state."""
    n_slots = problem.gain.shape[2]
    identity = list(range(n_slots))
    out: list[list[int]] = [identity] * problem.n
    members: dict[int, list[int]] = {}
    for i in range(problem.n):
        s = int(problem.stream[i])
        if s >= 0:
            members.setdefault(s, []).append(i)
    for idxs in members.values():
        for k, i in enumerate(idxs):
            future = idxs[k + 1 :]
            if not future:
                out[i] = [0] * n_slots
                continue
            rows = np.concatenate(
                [problem.gain[future].reshape(len(future), -1, n_slots),
                 (problem.nslot[future] == np.arange(n_slots)).astype(np.float64)],
                axis=1,
            ).reshape(-1, n_slots).T
            seen: dict[bytes, int] = {}
            out[i] = [seen.setdefault(rows[x].tobytes(), x) for x in range(n_slots)]
    return out


def offline_optimum(problem: Problem, *, max_states: int = 500_000) -> OptimumResult:
    """Exact optimum of the problem's model under the window constraint (eq. 5.5/5.7).

    Dynamic programming over levels: a state is each stream's last sent message plus the
    sends still inside a window reaching the next level (tantamount nodes, eq. 5.8 and
    footnote 5), keeping the best utility per state. Raises ``ValueError`` if a level holds
    more than ``max_states`` states (the instance is not small).
    """
    n = problem.n
    budget = problem.budget_bytes
    window_s = problem.window_s
    root = tuple(
        (float(t), int(b)) for t, b in zip(problem.root_win_t, problem.root_win_bytes, strict=True)
    )
    canon = _canonical_slots(problem)
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
            raise ValueError(
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
