"""The information distribution layer (thesis fig. 5.1, alg. 3): ``decide(message, now)``.

Sans-I/O, aioquic-shaped: the shell hands in each generated message with ``now`` (fleet
clock) and gets a :class:`Decision`; deliveries learned from receptions or receiver reports
come in through :meth:`Middleware.on_delivered` / :meth:`Middleware.on_report` (which also
feeds the constraint's link statistics), live parameters through
:meth:`Middleware.set_params`. It is the ``mcts`` :class:`~companion.middleware.decider.Decider`.
Nothing here reads a clock, except the optional injected ``budget_clock`` when a decision is
bounded by wall time (``time_budget_s`` or ``deadline``); by default the budget is an
iteration count, which keeps decisions deterministic.

The goodput budget ξ·T of :class:`GoodputConstraint` is the *fleet's* (one shared medium,
each agent plans for the whole fleet, ch. 5.3): windows count every send the agent knows of.
When it decides to send, the middleware itself records the send (``constraint.on_sent``):
the shell must not record it a second time.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Self

import numpy as np

from companion.middleware.constraints.base import ConstantConstraint, GoodputConstraint
from companion.middleware.decider import (
    COMPANION_ALWAYS_SEND,
    DeciderSetup,
    Decision,
    ParamsResult,
    ParamValue,
)
from companion.middleware.errors import MiddlewareError, ParamError, UnknownParamError
from companion.middleware.fleetshare import start_share
from companion.middleware.gate import creates_violation, price_per_byte, priced_option
from companion.middleware.incremental import Problem, build_problem, option_message
from companion.middleware.knowledge import FleetKnowledge, PlanningView, settle_inflight, usable
from companion.middleware.margin import OvershootMargin
from companion.middleware.mcts import MCTS, greedy_option
from companion.middleware.params import LIVE_KEYS, check_params, with_alpha
from companion.middleware.reports import ReceiverReport, ReportLearned, deliveries, feed_link
from companion.middleware.unheard import Roster, UnheardStreams, check_roster
from utility_specs.errors import UtilitySpecsError
from utility_specs.message import Message, Version
from utility_specs.spec import MissionSpec

__all__ = ["MISSION_KEYS", "Decision", "Middleware", "MiddlewareConfig", "MiddlewareError"]

ROSTER_UNHEARD_S = 5.0
"""With a roster and no ``plan_unheard_s``: how long unheard roster streams are planned for."""

RISEN_WORTH = 1.25
"""With ``price_rate_s``: another agent whose recent messages of a type are worth this many
times their history's median (``StreamForecaster.risen``) is counted in the price at its
generation rate, not its heard one. Not 2: the demo's red drone, heard sending half
frames, rose 1.3-1.4x in its first 4 s over red and 2-3x later, the plain drones stayed at
1.0 (debug log, 2026-11-25; per unit of quality: a half frame after quarters was 2.0x)."""

MISSION_KEYS = ("dp_seed", "fleet_size", "price_rate_s")
"""``MiddlewareConfig`` fields the ``[middleware]`` table sets besides :data:`LIVE_KEYS`;
fixed for a mission, so not live: ``fleet_size`` acts only in the first seconds of it,
``price_rate_s`` is the relay fleet's (docs/adaptive.md), and ``dp_seed`` sets how every
decision is made (0 there: alg. 2's unseeded search)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class MiddlewareConfig:
    """Parameters of the optimiser (ch. 5.3). Times in seconds."""

    spec: MissionSpec
    agent: str
    """This agent's sender name (its own messages are decided, others' only planned for)."""
    max_iterations: int = 1500
    time_budget_s: float | None = None
    """Wall time per decision on the middleware's ``budget_clock``; None: iterations only."""
    c: float = 0.35
    """Discovery factor of UCT (eq. 5.3)."""
    horizon_s: float = 3.0
    """How far ahead messages are forecast; should exceed the window T of the constraint."""
    tail_s: float = 0.0
    """Utility is integrated until ``horizon_s + tail_s``: the last forecast messages keep
    some value beyond the forecast horizon instead of being cut at it."""
    default_latency_s: float = 0.05
    """Latency assumed before the first delivery is known."""
    max_items: int = 64
    """At most this many levels (nearest first): bounds the work per decision."""
    chunk_iterations: int = 100
    """With a wall-time deadline, the budget clock is read every this many iterations."""
    search_inflight: int = 4
    """At most this many of other agents' possibly in-flight messages (the newest) are levels
    of the tree; older ones are settled at their senders' last known rate
    (:func:`~companion.middleware.knowledge.settle_inflight`): under a backlog they used to
    push the decided message out of the search's reach (issue 18)."""
    knapsack_seed: bool = False
    """Start the search from the knapsack-greedy plan (first expanded child at every node and
    a second default policy) and answer with the best complete plan found: the decision is
    never worse, *in the model*, than knapsack-greedy's plan, and more iterations never
    lower the model utility of the answer (issue 18). Off by default: measured, it shares
    frames between a red and a plain stream about 2 : 1 instead of the thesis' 4 : 1
    (tests/middleware/test_mw_fig73.py) and gains only 2.5 points in image streaming
    (docs/middleware.md)."""
    best_plan: bool = False
    """Opt-in: answer with the decided level's option of the best complete plan any
    iteration evaluated instead of the most visited path's: the model is deterministic, so
    the answer's model utility never falls with more iterations (issue 18, rounds 5-6).
    With ``search_depth=10`` it passes bench_mcts's anytime and optimum rows (95.2 %) but
    fails its like-for-like row (98.3 97.2 96.2 91.8 77.3 55.7 % against the most visited
    path's 99.0 98.2 96.7 94.8 81.8 49.3 %, and 9 window violations per run instead of 2),
    so it is not the default (docs/middleware.md, round 6). False: alg. 2's rule."""
    search_depth: int | None = None
    """Levels after the decided one that the tree searches; below them the default policy
    alone plans (None: every level). 10 with ``best_plan``: the fig. 5.7 anytime cases do
    not fall from 300 to 3000 iterations; 8 and 9 fall in mostly-low 2.5 msgs/T."""
    dp_seed: int | None = 128
    """Seed the search with the plan of a beam dynamic programme over the decision's
    tantamount states, this many kept per level (:mod:`~companion.middleware._beam`); where
    that plan drops at least half of the horizon (``mcts.DP_TIGHT``) the answer is the best
    complete plan evaluated, never worse in the model than the programme's, else the most
    visited path (issue 18, round 13). The beam keeps three quarters of its states by
    utility minus the budget their sends still hold, priced at the rollout threshold (round
    14). Width 128 passes bench_mcts's like-for-like, anytime and optimum rows (95.7 %) and
    wins 5 of its 9 equal-bytes cells (alg. 2's unseeded most visited path: 2, and it misses
    anytime and optimum). None: alg. 2's rule alone; ignored with ``knapsack_seed``, whose
    plan seeds the search instead."""
    veto: float | None = None
    """Opt-in (issue 18 round 7; with ``best_plan`` and ``search_depth``): an unbounded
    most visited tree vetoes the best plan's send when its drop child has more than this
    many times the send's visits (:class:`~companion.middleware.mcts.MCTS`). None: off."""
    learn_margin: bool = False
    """Plan against the budget less a margin learned from the fleet's observed overshoot
    (:class:`~companion.middleware.margin.OvershootMargin`): the others' sends are known
    only when they arrive, so without it the fleet fills the same window (issue 18)."""
    announce_after_s: float | None = 60.0
    """Other agents learn of a stream only from its deliveries: a stream of this agent that
    has sent nothing for this long is invisible to their plans, so they fill the shared
    window and it is dropped for ever (a starvation loop; at mission start, the agents that
    speak first take the window). Then a message the tree would send if the others had not
    planned for the window goes out, once, and makes the stream known ("mcts-announce").
    None: off."""
    price_bytes: bool = True
    """A message with versions is sent only in a version that earns the horizon's utility per
    byte (:mod:`~companion.middleware.gate`); False: the tree's option as it is."""
    announce_over_budget: bool = True
    """Announce even over the sends known to fill the window: at most one planned window
    violation per stream per ``announce_after_s`` (counter ``over_budget``). False: zero
    planned violations, a stream waits for room among the known sends; measured, that costs
    up to 15 points at tight budgets, 6 with ``plan_unheard_s`` and the declared fleet
    (``fleet_size``, ``start_share_s=None``), and 1.6 points of the offline optimum
    (docs/middleware.md, rounds 5 and 8). Ignored (False) with a ``roster``."""
    plan_unheard_s: float | None = None
    """For this long after the agent's first decision, plan for the spec's types nobody has
    been heard sending (:mod:`~companion.middleware.unheard`): forecast at the fleet's
    median period with the data of a known message of the same utility function, so the
    fleet leaves room for a heavy stream it has not heard of yet. After it a type still
    unheard is taken as absent. With ``fleet_size`` only while the unheard agents can fly
    every unheard type (:meth:`~companion.middleware.unheard.UnheardStreams.plausible`).
    None: off."""

    small_share: float | None = None
    """Opt-in (issue 18 round 6): a message of at most this share of the budget (a position,
    a battery report) that the tree drops is still sent when it earns the price per byte and
    breaks no window that was within the budget
    (:func:`~companion.middleware.gate.creates_violation`). It rescues telemetry at tight
    budgets but adds sends to windows already over the budget (fleet window violations
    32-53 instead of 4-18 per run at 25 kB/s), so it is off by default. None: off."""

    fleet_size: int | None = None  # issue 18 round 7
    """Agents the mission declares. At the mission start (for ``start_share_s``) an agent
    leaves each peer it has not heard of its equal share of the budget and ramps its own
    plan up over the first window (:mod:`~companion.middleware.fleetshare`). None: off."""
    start_share_s: float | None = 5.0
    """How long the mission-start share lasts; None: off (the fleet is declared only for
    ``plan_unheard_s``, which the start share costs in the fig. 5.7 fleets, round 8)."""

    price_rate_s: float | None = None
    """Opt-in (the relay fleet's, docs/adaptive.md "The decider's lag"): the price per byte
    (``price_bytes``) counts another agent's messages with versions only up to the bytes
    it is expected to send over the horizon, at the rate it was heard to send over this
    many seconds (:func:`~companion.middleware.gate.price_per_byte`, ``expected``), unless
    its recent worth rose :data:`RISEN_WORTH` times over its history (the red drone); and
    every stream is forecast from its observations of the last this many seconds
    (``StreamForecaster.pool_span_s``). None: every forecast frame counts."""

    roster: Roster | None = None  # issue 18 round 9
    """Which agent generates which types (the mission's declared fleet; None: the spec's
    ``roster``, if any). With one, nothing is guessed: the streams of the roster nobody has
    heard yet are planned for (:meth:`~companion.middleware.unheard.UnheardStreams.roster_items`,
    for ``plan_unheard_s``, else 5 s) and an announcement never goes over the known window
    (``announce_over_budget`` is ignored): zero planned violations (docs/middleware.md,
    round 9)."""

    @property
    def declared_roster(self) -> Roster | None:
        """The roster in force: this config's, else the mission spec's."""
        return self.roster if self.roster is not None else self.spec.roster

    def __post_init__(self) -> None:
        if not self.agent:
            raise MiddlewareError("agent must not be empty")
        roster = self.declared_roster
        if roster is not None:  # the spec's too: a roster without this agent plans it no room
            why = check_roster(roster, self.spec, agent=self.agent)
            if why is not None:
                raise MiddlewareError(why if self.roster is not None
                                      else f"mission spec {self.spec.name!r}: {why}")
        if self.max_iterations < 0 or self.chunk_iterations <= 0 or self.max_items <= 0 \
                or self.search_inflight < 0:
            raise MiddlewareError("max_iterations >= 0, chunk_iterations > 0, max_items > 0, "
                                  "search_inflight >= 0")
        if not (self.horizon_s > 0 and self.c >= 0 and self.default_latency_s >= 0
                and self.tail_s >= 0):
            raise MiddlewareError("need horizon_s > 0, c >= 0, default_latency_s >= 0, tail_s >= 0")
        if self.search_depth is not None and self.search_depth < 0:
            raise MiddlewareError("search_depth must be >= 0 or None")
        if (self.fleet_size is not None and self.fleet_size < 1) \
                or (self.start_share_s is not None and not self.start_share_s > 0):
            raise MiddlewareError("fleet_size must be >= 1 or None, start_share_s > 0 or None")
        if self.veto is not None and not self.veto > 0:
            raise MiddlewareError("veto must be > 0 or None")
        if self.dp_seed is not None and self.dp_seed < 1:
            raise MiddlewareError("dp_seed must be >= 1 or None")
        if self.plan_unheard_s is not None and not self.plan_unheard_s > 0:
            raise MiddlewareError("plan_unheard_s must be > 0 or None")
        if self.announce_after_s is not None and not self.announce_after_s > 0:
            raise MiddlewareError("announce_after_s must be > 0 or None")
        if self.time_budget_s is not None and not self.time_budget_s > 0:
            raise MiddlewareError("time_budget_s must be > 0 or None")
        if self.small_share is not None and not 0 < self.small_share <= 1:
            raise MiddlewareError("small_share must be in (0, 1] or None")
        if self.price_rate_s is not None and not self.price_rate_s > 0:
            raise MiddlewareError("price_rate_s must be > 0 or None")


def _dense_enough(problem: Problem, level: int, lam: float) -> bool:
    """The message is worth a place in the fleet's plan: some version brings at least the
    utility per byte at which the horizon's messages fill the budget (the density the
    default policy asks for, :func:`~companion.middleware.mcts.rollout_threshold`)."""
    if not 0 <= level < problem.n or lam <= 0:
        return False
    return any(
        float(problem.gain[level, o, 0]) >= lam * max(1, int(problem.size[level, o]))
        for o in range(1, int(problem.nopt[level]))
    )


class Middleware:
    """Per-agent optimiser: forecast + in-flight + MCTS with pruning and merging (ch. 5)."""

    def __init__(
        self,
        config: MiddlewareConfig,
        *,
        rng: np.random.Generator | None = None,
        constraint: GoodputConstraint,
        budget_clock: Callable[[], float] | None = None,
    ) -> None:
        self.config = config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        """Kept for the policy interface; the search itself is deterministic (ties are broken
        by a fixed option order), so decisions do not depend on it."""
        self.constraint = constraint
        self.budget_clock = budget_clock
        self.knowledge = FleetKnowledge(
            config.spec, agent=config.agent, default_latency_s=config.default_latency_s
        )
        self.knowledge.forecaster.pool_span_s = config.price_rate_s
        self.counters: Counter[str] = Counter()
        self.margin = OvershootMargin()
        self.last_problem: Problem | None = None
        self._last_sent: dict[str, float] = {}
        """Per own message type: when it last sent one (what the fleet has heard of)."""
        self.unheard = UnheardStreams()
        self._started: float | None = None
        """Time of the first decision (``plan_unheard_s`` counts from it)."""
        self._mission_start: float | None = None
        """When the ground station last started the mission (:meth:`mission_started`)."""
        self._always_send: frozenset[str] = frozenset()

    @classmethod
    def from_setup(cls, setup: DeciderSetup, *, alpha: ParamValue = None,
                   **params: ParamValue) -> Self:
        """The ``mcts`` policy of the registry: ``params`` are :data:`LIVE_KEYS` and
        :data:`MISSION_KEYS`, ``alpha`` sets α of the mission's utility functions (eq. 7.1/7.2)."""
        for key in params:
            if key not in LIVE_KEYS and key not in MISSION_KEYS:
                raise UnknownParamError(key, ("alpha", *LIVE_KEYS, *MISSION_KEYS),
                                        owner="the mcts policy")
        spec = setup.spec if alpha is None else with_alpha(setup.spec, alpha)
        if type(params.get("dp_seed")) is int and params["dp_seed"] == 0:  # TOML has no None
            params["dp_seed"] = None
        try:
            config = MiddlewareConfig(spec=spec, agent=setup.agent,
                                      max_iterations=setup.max_iterations,
                                      time_budget_s=setup.time_budget_s,
                                      **params)  # type: ignore[arg-type]
        except TypeError as exc:  # a value of the wrong type
            raise ParamError(str(exc)) from None
        middleware = cls(config, rng=setup.rng, constraint=setup.constraint,
                         budget_clock=setup.budget_clock)
        middleware.always_send = frozenset(COMPANION_ALWAYS_SEND)
        return middleware

    @property
    def always_send(self) -> frozenset[str]:
        """Own types sent whatever the search says (the companion's status heartbeat); every
        agent's stream of them is forecast as a heartbeat."""
        return self._always_send

    @always_send.setter
    def always_send(self, types: frozenset[str]) -> None:
        self._always_send = frozenset(types)
        self.knowledge.forecaster.heartbeats = self._always_send

    @property
    def spec(self) -> MissionSpec:
        return self.config.spec

    def decide(self, message: Message, now: float, *, deadline: float | None = None) -> Decision:
        """Send or drop ``message`` generated by this agent (alg. 3, lines 5-14).

        ``deadline`` (on ``budget_clock``'s clock) bounds the search by wall time, by
        default ``time_budget_s`` from now; the iteration budget ``max_iterations`` always
        applies.
        """
        if deadline is None and self.config.time_budget_s is not None \
                and self.budget_clock is not None:
            deadline = self.budget_clock() + self.config.time_budget_s
        if message.sender != self.config.agent:
            raise MiddlewareError(
                f"decide() is for this agent's ({self.config.agent}) messages, got "
                f"{message.sender}/{message.seq}"
            )
        self.counters["decisions"] += 1
        if message.type not in self.spec.types:
            self.counters["unknown_type"] += 1
            return Decision(send=False, reason="unknown-type")
        if not usable(self.spec, message):
            self.counters["bad_message"] += 1
            return Decision(send=False, reason="bad-message: its utility cannot be read")
        self.knowledge.on_generated(message)
        self.unheard.observe(self.spec, message)
        if self._started is None:
            self._started = now
        window_s = self.constraint.window_s
        view = self.knowledge.view(
            message, now=now, horizon_s=self.config.horizon_s,
            max_items=self.config.max_items, window_s=window_s,
        )
        lag = max(self.knowledge.latency.high_s, self.knowledge.latency.mean_s)
        view = settle_inflight(view, now=now, lag_s=lag, keep=self.config.search_inflight,
                               rates=self.knowledge.sender_rates(now=now, lag_s=lag,
                                                                 window_s=window_s),
                               settle_versions=True)  # issue 18 round 5
        roster = self.config.declared_roster
        unheard_s = self.config.plan_unheard_s
        if roster is not None and unheard_s is None:
            unheard_s = ROSTER_UNHEARD_S
        planning_unheard = unheard_s is not None and now - self._started <= unheard_s
        if planning_unheard:
            view = self._with_unheard(view, now=now, window_s=window_s)  # unheard.py
        budget = self.constraint.budget_bytes(now=now)
        if self.config.fleet_size is not None and self.config.start_share_s is not None:
            # from a started mission: its peers' heartbeats were heard, their data, which
            # they all start sending now, is not (see mission_started)
            since, heard = (self._started, len(self.knowledge.peers_of(self.config.agent))) \
                if self._mission_start is None else (self._mission_start, 0)
            if now - since <= self.config.start_share_s:
                budget = start_share(budget, fleet=self.config.fleet_size,  # fleetshare.py
                                     heard=heard, elapsed_s=now - since, window_s=window_s,
                                     for_s=self.config.start_share_s,
                                     floor_bytes=min((v.size for v in message.versions),
                                                     default=message.size))
        if self.config.learn_margin:
            self.margin.observe(self.knowledge.known_sends(), now=now, settle_s=lag,
                                window_s=window_s, budget_bytes=budget)
            budget = self.margin.plan_budget(budget)
        try:
            problem = build_problem(
                self.spec, items=view.items, fixed=view.fixed,
                horizon_end=view.horizon_end + self.config.tail_s,
                budget_bytes=budget, window_s=window_s,
                root_window=view.root_window, receivers=view.receivers,
            )
        except UtilitySpecsError as exc:  # bad message data: counted, not a crash
            self.counters["bad_message"] += 1
            return Decision(send=False, reason=f"bad-message: {exc}")
        self.last_problem = problem
        search = MCTS(problem, c=self.config.c, max_nodes=self.config.max_iterations + 1,
                      knapsack_seed=self.config.knapsack_seed, best_plan=self.config.best_plan,
                      depth=self.config.search_depth, veto=self.config.veto,
                      dp_seed=self.config.dp_seed)
        self._run(search, deadline)
        result = search.result()
        level = problem.decided_level
        if result.option is None:
            option, reason = greedy_option(problem, level), "fallback-greedy"
            self.counters["fallback"] += 1
        else:
            option, reason = result.option, "mcts-exact" if result.exhausted else "mcts"
            if self.config.price_bytes and message.versions:  # issue 18 rounds 5-6, gate.py
                price = price_per_byte(problem, level=level,
                                       expected=self._expected_bytes(message, now, lag))
                tree_option, option = option, priced_option(problem, level, option, price)
                if tree_option and not option and self.config.price_rate_s is not None:
                    option = self._fitting_option(problem, level, price, now=now,
                                                  budget=budget, window_s=window_s)
            small = self.config.small_share
            if small is not None and option == 0 and message.size <= small * budget:
                option = self._small_option(problem, level, search.lam, now=now,
                                            budget=budget, window_s=window_s)
                if option:
                    reason = "mcts-rescue"
                    self.counters["rescue"] += 1
        if option == 0 and view.root_window and self._invisible(message.type, now) \
                and not (roster is not None and planning_unheard) \
                and _dense_enough(problem, level, search.lam):
            # (Not while a roster's unheard streams are planned for: the fleet leaves this
            # stream room then, and an announcement ignoring the room left for the others'
            # heavier unheard streams took it from them: round 9, mostly-low 9.25 / 5.5 /
            # 2.5 msgs/T 96.8 / 91.1 / 68.5 -> 98.1 / 92.5 / 72.1 %.)
            # What the tree would do if the fleet, knowing of this stream, had left room:
            # without the others' planned messages, within the sends known to the window
            # (or, with announce_over_budget, over them: a planned violation).
            over = self.config.announce_over_budget and roster is None
            own = [it for it in view.items if it.message.sender == self.config.agent]
            free = build_problem(
                self.spec, items=view.items if over else own, fixed=view.fixed,
                horizon_end=view.horizon_end + self.config.tail_s,
                budget_bytes=budget, window_s=window_s,
                root_window=() if over else view.root_window, receivers=view.receivers,
            )
            relaxed = MCTS(free, c=self.config.c, max_nodes=self.config.max_iterations + 1,
                           knapsack_seed=self.config.knapsack_seed,
                           best_plan=self.config.best_plan, depth=self.config.search_depth,
                           veto=self.config.veto, dp_seed=self.config.dp_seed)
            self._run(relaxed, deadline)
            announce = relaxed.result()
            if announce.option:
                option, reason, result = announce.option, "mcts-announce", announce
                self.counters["announce"] += 1
        decision = Decision(
            send=option != 0,
            version=(option - 1) if option != 0 and message.versions else None,
            score=result.score,
            reason=reason,
            iterations=result.iterations,
            nodes=result.nodes,
            pruned=result.pruned,
            merged=result.merged,
            levels=problem.n,
            level=level,
        )
        if not decision.send and message.type in self.always_send:
            # the heartbeat (a status): it always goes, so the station's silence means loss;
            # its bytes count in the window like any send (``_after``)
            decision = dataclasses.replace(decision, send=True, version=None,
                                           reason="status-heartbeat")
        self._after(message, decision, now)
        return decision

    def _expected_bytes(self, message: Message, now: float, lag: float
                        ) -> dict[str, float] | None:
        """Per other agent, the bytes it is expected to send over the horizon: its rate
        over the ``price_rate_s`` before the last ``lag`` (what has had time to be
        reported) times the horizon; None without ``price_rate_s``. An agent whose recent
        ``message.type`` messages are worth :data:`RISEN_WORTH` times its history's median
        or more (the red drone, seen from a plain one) is expected to send them all: counted
        at its past rate, just when its worth rose, its frames left the plain drones' price
        and they took its windows (docs/adaptive.md, "The red drone's precedence")."""
        span = self.config.price_rate_s
        if span is None:
            return None
        rates = self.knowledge.sender_rates(now=now, lag_s=lag, window_s=span)
        out = {sender: rate * self.config.horizon_s for sender, (rate, _) in rates.items()}
        forecaster = self.knowledge.forecaster
        for sender, kind in forecaster.streams():
            if kind != message.type or sender == self.config.agent:
                continue
            rise = forecaster.risen((sender, kind))
            if rise is not None and rise >= RISEN_WORTH:
                out[sender] = math.inf
        return out

    def _fitting_option(self, problem: Problem, level: int, price: float, *, now: float,
                        budget: float, window_s: float) -> int:
        """With ``price_rate_s``: the tree chose to send but no option as small as its
        earns the price; the most valuable option that earns it and fits the window (no
        violated window among the sends known), else 0. Over red the red drone's tree
        chose its quarter frame, worth 0 over its base, with the window empty, and the
        price dropped it: about one red frame a second went out with the others silent."""
        gain, size = problem.gain[level, :, 0], problem.size[level]
        earning = [o for o in range(1, int(problem.nopt[level]))
                   if float(gain[o]) > 0 and float(gain[o]) >= price * max(1, int(size[o]))]
        sends = self.knowledge.known_sends()
        for o in sorted(earning, key=lambda o: -float(gain[o])):  # most valuable that fits
            if not creates_violation(sends, now=now, size=int(size[o]), window_s=window_s,
                                     budget_bytes=budget):
                return o
        return 0

    def _small_option(self, problem: Problem, level: int, lam: float, *, now: float,
                      budget: float, window_s: float) -> int:
        """The best option of a small message the tree dropped, if it earns ``lam`` per byte
        and adds no violated window to the sends this agent knows of (eq. 5.5 counts
        violated instants: a window the others already broke stays one), else 0."""
        best = max(range(1, int(problem.nopt[level])),
                   key=lambda o: float(problem.gain[level, o, 0]), default=0)
        if not best:
            return 0
        size = int(problem.size[level, best])
        if float(problem.gain[level, best, 0]) < lam * max(1, size):
            return 0
        if creates_violation(self.knowledge.known_sends(), now=now, size=size,
                             window_s=window_s, budget_bytes=budget):
            return 0
        return best

    def _with_unheard(self, view: PlanningView, *, now: float, window_s: float) -> PlanningView:
        """``view`` with the spec's unheard types forecast (``plan_unheard_s``), if they may
        be flown (:meth:`UnheardStreams.plausible`). Before any stream's period is known
        (the mission's first messages) each is assumed to send once per window T: without
        it the first speakers found no unheard stream in their plans and filled the window
        (round 8, room mode: mostly-low 9.25 / 5.5 / 2.5 msgs/T 94.2 / 89.4 / 70.3 ->
        96.8 / 91.1 / 68.5 %). A roster's unheard stream repeats at the period of the known
        streams of its type, else at its type's declared ``period_s``, else as above: once
        per T was 2.5 times too slow in the fig. 5.7 fleets, and the first speakers still
        filled the window (round 15, periods declared: uniform 9.25 msgs/T at equal bytes
        +0.1 -> -1.0)."""
        period = self.knowledge.forecaster.prior_period
        roster = self.config.declared_roster
        if roster is not None:  # round 9: exactly the roster's unheard streams
            forecaster = self.knowledge.forecaster

            def period_of(type_name: str) -> float:
                typed = forecaster.type_period(type_name)
                if typed is not None:
                    return typed
                return window_s if period is None else period

            extra = self.unheard.roster_items(
                self.spec, roster, agent=self.config.agent, now=now,
                horizon_end=view.horizon_end, period_of=period_of,
                latency_s=self.knowledge.latency.mean_s)
            return self.unheard.add_to(view, self.spec, now=now, period_s=None,
                                       latency_s=self.knowledge.latency.mean_s,
                                       max_items=self.config.max_items, extra=extra)
        fleet = self.config.fleet_size
        peers = self.knowledge.peers_of(self.config.agent)
        missing = None if fleet is None else fleet - 1 - len(peers)
        if not self.unheard.plausible(self.spec, unheard_agents=missing):
            return view
        return self.unheard.add_to(view, self.spec, now=now,
                                   period_s=window_s if period is None else period,
                                   latency_s=self.knowledge.latency.mean_s,
                                   max_items=self.config.max_items)

    def _invisible(self, type_name: str, now: float) -> bool:
        """Has the fleet not heard of this agent's ``type_name`` stream for a long time?"""
        after = self.config.announce_after_s
        if after is None:
            return False
        last = self._last_sent.get(type_name)
        return last is None or now - last > after

    def _run(self, search: MCTS, deadline: float | None) -> None:
        budget = self.config.max_iterations
        if deadline is None or self.budget_clock is None:
            search.run(budget)
            return
        while budget > 0 and self.budget_clock() < deadline:
            ran = search.run(min(budget, self.config.chunk_iterations))
            if ran == 0:
                return
            budget -= ran
        # Past the deadline but the tree has no answer yet (a loaded CPU, a slow table
        # build): one more chunk, not the greedy fallback. A chunk costs well under 1 ms.
        if budget > 0 and search.result().option is None:
            search.run(min(budget, self.config.chunk_iterations))

    def _after(self, message: Message, decision: Decision, now: float) -> None:
        self.counters["sent" if decision.send else "dropped"] += 1
        if decision.send:
            self._last_sent[message.type] = now
            sent = option_message(message, (decision.version or 0) + 1)
            known = self.knowledge.sent_in_window(now=now, window_s=self.constraint.window_s)
            if known + sent.size > self.constraint.budget_bytes(now=now) + 1e-9:
                # a planned violation: the window as this agent knows it is over budget
                # (also when the others had already put it over: the send adds to it)
                self.counters["over_budget"] += 1
            self.knowledge.on_sent(sent, now=now)
            self.constraint.on_sent(sent.size, now=now)
        horizon = max(self.constraint.window_s, self.config.horizon_s,
                      self.config.price_rate_s or 0.0)  # the rates' window (_expected_bytes)
        self.knowledge.forget(now=now, keep_s=horizon + 4.0 * self.knowledge.latency.high_s)

    def on_delivered(self, messages: Iterable[Message], now: float) -> None:
        """Messages (any agent's) known to have arrived, with ``t_rcv`` (and ``t_sent``)."""
        if self.config.plan_unheard_s is not None or self.config.declared_roster is not None:
            messages = list(messages)
            for m in messages:
                if m.t_rcv is not None and usable(self.spec, m):
                    self.unheard.observe(self.spec, m)
        self.counters["delivered"] += self.knowledge.on_delivered(messages, now=now)

    def on_report(self, report: ReceiverReport, now: float) -> ReportLearned:
        """A receiver report: every entry for the delivered-set knowledge, this agent's own
        entries and clock echo for the constraint's link statistics (ch. 6.1)."""
        messages, bad = deliveries(report)
        self.counters["bad_report_entry"] += bad
        before = self.counters["delivered"]
        self.on_delivered(messages, now)
        link = feed_link(self.constraint, report, agent=self.config.agent, now=now)
        self.counters["link_samples"] += link.link_samples
        self.counters["round_trips"] += link.round_trips
        self.counters["bad_round_trips"] += link.bad_round_trips
        return ReportLearned(delivered=self.counters["delivered"] - before, bad_entries=bad,
                             link=link)

    def on_stall(self, t_from: float, t_to: float, now: float) -> None:
        """The agent's process did not run in [t_from, t_to] (swap, a paused VM, a blocked
        loop): the constraint does not learn the link from what that delayed."""
        self.counters["stalls"] += 1
        self.constraint.on_stall(t_from, t_to, now=now)

    def mission_started(self, now: float) -> None:
        """The ground station started the mission at ``now``: for ``start_share_s`` the agent
        plans its declared share of the budget (``fleet_size``) as if no peer had been heard.
        Before the start the drones heard each other's status heartbeats, so the share by
        heard peers (fleetshare.py) gave each the whole budget, and the four drones of the
        demo fleet sent four full frames within 0.14 s (112 kB into the relay's 20 kB queue:
        all lost, ξ learnt nothing from them, and the next frames went the same way)."""
        self._mission_start = now

    def set_params(self, params: Mapping[str, ParamValue], now: float) -> ParamsResult:
        """Live parameters (:mod:`companion.middleware.params`), effective from the next
        decision. All or nothing: a rejected key changes nothing and the result says why."""
        del now
        try:
            checked = check_params(self.config, self.constraint, params)
        except ParamError as exc:
            return ParamsResult.rejected(str(exc))
        if checked.config.spec is not self.config.spec:
            self.knowledge.use_spec(checked.config.spec)
        self.config = checked.config
        self.constraint.apply_params(checked.constraint)
        return ParamsResult(applied=checked.applied)

    def warm_up(self) -> None:
        """One decision on a throwaway optimiser, so JIT compilation (numba) happens before
        the first real message instead of costing it a decision timeout."""
        scratch = type(self)(self.config, constraint=ConstantConstraint(limit_bytes_per_s=1e5))
        spec_types = self.config.spec.types
        type_name = "image" if "image" in spec_types else next(iter(spec_types))
        versions = (Version(name="full", size=20_000, quality=1.0),
                    Version(name="half", size=5_000, quality=0.5))
        for seq in range(3):
            scratch.decide(Message(sender=self.config.agent, seq=seq, type=type_name,
                                   t_gen=seq * 0.2, size=20_000,
                                   data={"red": 0.1, "object": False, "level": 0.9},
                                   versions=versions, version=0), seq * 0.2)

    def get_timer(self) -> float | None:
        """No timers: everything happens in ``decide`` and ``on_delivered``."""
        return None

    def handle_timer(self, now: float) -> None:
        return None
