"""Plans agreed over the link (opt-in, issue 18 round 10): the other agents' levels fixed to
the options they announced, the announced plan itself, and the plans riding on the
simulated fleet's delivered messages."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import MiddlewareConfig
from companion.middleware.agreed import AgreedPlans, AnnouncedPlan, PlanEntry, own_plan
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.errors import MiddlewareError
from companion.middleware.incremental import PlanItem, Problem, build_problem
from companion.middleware.mcts import MCTS
from companion.middleware.middleware import Middleware
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from tests.middleware.conftest import T0, msg, small_spec
from utility_specs.files import builtin_spec

SPEC = small_spec()


def _problem(seed: int, n: int, budget: int) -> Problem:
    """Agent "a" decides its first message; "b" and "c" have forecast messages."""
    rng = np.random.default_rng(seed)
    kinds = ("battery", "linear", "status")
    messages = [
        msg("a" if k == 0 else str(rng.choice(["a", "b", "c"])), k,
            kinds[int(rng.integers(3))], T0 + 0.3 * k + float(rng.uniform(0, 0.2)),
            size=int(rng.integers(50, 150)))
        for k in range(n)
    ]
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                      kind="decide" if k == 0 else "forecast") for k, m in enumerate(messages)]
    return build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 6, budget_bytes=budget,
                         window_s=1.0)


def _fits(problem: Problem, choices: list[int], i: int, option: int) -> bool:
    lo = float(problem.send_t[i]) - problem.window_s - 1e-9
    used = sum(int(b) for t, b in zip(problem.root_win_t, problem.root_win_bytes, strict=True)
               if t >= lo)
    used += sum(int(problem.size[j, o]) for j, o in enumerate(choices)
                if o and problem.send_t[j] >= lo)
    return used + int(problem.size[i, option]) <= problem.budget_bytes + 1e-9


def _brute_force(problem: Problem) -> float:
    """Best utility over the free levels' options; a fixed level takes its option when it
    fits the window its earlier levels leave, else drop (an independent reading)."""
    free = [i for i in range(problem.n) if problem.force[i] < 0]
    best = -1.0
    for combo in itertools.product(*(range(int(problem.nopt[i])) for i in free)):
        pick = dict(zip(free, combo, strict=True))
        choices: list[int] = []
        ok = True
        for i in range(problem.n):
            f = int(problem.force[i])
            o = pick[i] if f < 0 else (f if f > 0 and _fits(problem, choices, i, f) else 0)
            if f < 0 and o and not _fits(problem, choices, i, o):
                ok = False
                break
            choices.append(o)
        if ok:
            best = max(best, problem.path_gain(choices))
    return best


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 8), budget=st.integers(0, 400),
       pattern=st.integers(0, 2**16))
def test_the_search_optimises_only_the_levels_no_plan_fixes(seed: int, n: int, budget: int,
                                                           pattern: int) -> None:
    """With every node expanded, the search's best plan is the brute force over the free
    levels, and its path takes each fixed level's option (drop where it does not fit)."""
    problem = _problem(seed, n, budget)
    for i, it in enumerate(problem.items):
        if it.message.sender != "a" and (pattern >> i) & 1:
            problem.force[i] = int((pattern >> (8 + i)) & 1)
    search = MCTS(problem, max_nodes=6000, best_plan=True)
    search.run(6000)  # more than the whole tree's nodes (at most 2^9): every leaf evaluated
    assert float(search.best[0]) == pytest.approx(_brute_force(problem), abs=1e-9)
    path = search.result().path
    for i, o in enumerate(path):
        f = int(problem.force[i])
        if f >= 0:
            assert o == (f if f and _fits(problem, list(path[:i]), i, f) else 0)


def _contested() -> Problem:
    """b's battery report, then a's 0.1 s later; the window holds one of them."""
    items = [
        PlanItem(message=msg("b", 0, "battery", T0, size=100), send_t=T0, rcv_t=T0 + 0.1),
        PlanItem(message=msg("a", 1, "battery", T0 + 0.1, size=100), send_t=T0 + 0.1,
                 rcv_t=T0 + 0.2, kind="decide"),
    ]
    return build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 3, budget_bytes=150,
                         window_s=1.0)


@pytest.mark.parametrize("announced, decided", [(1, 0), (0, 1)])
def test_the_decision_follows_the_other_agents_announced_option(announced: int,
                                                                decided: int) -> None:
    """b announced a send: a drops (the window is b's); b announced a drop: a sends. The
    unfixed tree chooses b's option itself, and then a's answer does not depend on it."""
    problem = _contested()
    free = MCTS(problem, max_nodes=301)
    free.run(300)
    problem.force[0] = announced
    search = MCTS(problem, max_nodes=301)
    search.run(300)
    assert search.result().option == decided
    assert search.result().path == (announced, decided)
    def level_0(search: MCTS) -> list[int]:
        return sorted(int(search.tree.option[n]) for n in range(1, search.tree.n_nodes)
                      if search.tree.depth[n] == 1)

    assert level_0(search) == [announced]  # b's level: the announced option only
    assert level_0(free) == [0, 1]


@pytest.mark.parametrize("announced", [1, 0])
def test_as_a_prior_the_announced_option_only_values_rollouts(announced: int) -> None:
    """force_tree=False: b's level stays a decision of the tree (both options searched)."""
    problem = _contested()
    problem.force[0] = announced
    search = MCTS(problem, max_nodes=301, force_tree=False)
    search.run(300)
    assert sorted(int(search.tree.option[n]) for n in range(1, search.tree.n_nodes)
                  if search.tree.depth[n] == 1) == [0, 1]


def test_plans_match_forecast_levels_by_type_and_nearest_time() -> None:
    """b's entries at T0+1.0 / 1.5 / 2.0; the receiver's forecast at T0+1.45 takes the
    1.5 entry (within half the 0.5 s spacing), one at T0+2.4 is past the spacing, own and
    in-flight levels and c's stream stay free; a stale plan (horizon passed) fixes nothing."""
    plan = AnnouncedPlan(sender="b", made_t=T0, until_t=T0 + 3.0, entries=(
        PlanEntry("battery", T0 + 1.0, 0), PlanEntry("battery", T0 + 1.5, 1),
        PlanEntry("battery", T0 + 2.0, 0)))
    items = [
        PlanItem(message=msg("a", 0, "battery", T0 + 0.9), send_t=T0 + 0.9, rcv_t=T0 + 1,
                 kind="decide"),
        PlanItem(message=msg("b", 1, "battery", T0 + 0.95), send_t=T0 + 0.95, rcv_t=T0 + 1,
                 kind="inflight"),
        PlanItem(message=msg("b", 2, "battery", T0 + 1.45), send_t=T0 + 1.45, rcv_t=T0 + 2),
        PlanItem(message=msg("c", 3, "battery", T0 + 1.5), send_t=T0 + 1.5, rcv_t=T0 + 2),
        PlanItem(message=msg("b", 4, "battery", T0 + 2.05), send_t=T0 + 2.05, rcv_t=T0 + 3),
        PlanItem(message=msg("b", 5, "battery", T0 + 2.4), send_t=T0 + 2.4, rcv_t=T0 + 3),
    ]
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 4,
                            budget_bytes=1e9, window_s=1.0)
    agreed = AgreedPlans("a")
    agreed.hear(plan)
    assert agreed.force(problem).tolist() == [-1, -1, 1, -1, 0, -1]
    agreed.hear(AnnouncedPlan(sender="b", made_t=T0 - 5, until_t=T0 - 2, entries=()))
    assert agreed.plans["b"] is plan  # an older plan never replaces a newer one
    agreed.hear(AnnouncedPlan(sender="b", made_t=T0 + 0.1, until_t=T0 + 1.0,
                              entries=plan.entries))
    assert agreed.force(problem).tolist() == [-1] * 6  # every level past the plan's horizon


def test_the_own_plan_is_the_path_then_the_default_policy_and_fits_a_header() -> None:
    """Own forecast levels only, with the path's options where it reaches; 1 bit each."""
    items = [
        PlanItem(message=msg("a", 0, "battery", T0), send_t=T0, rcv_t=T0 + 0.1, kind="decide"),
        PlanItem(message=msg("b", 1, "battery", T0 + 0.5), send_t=T0 + 0.5, rcv_t=T0 + 0.6),
        PlanItem(message=msg("a", 2, "battery", T0 + 1.0), send_t=T0 + 1.0, rcv_t=T0 + 1.1),
        PlanItem(message=msg("a", 3, "battery", T0 + 2.0), send_t=T0 + 2.0, rcv_t=T0 + 2.1),
    ]
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 3,
                            budget_bytes=1e9, window_s=1.0)
    plan = own_plan(problem, [1, 0, 0], 0.0, agent="a", now=T0)
    assert plan.entries == (PlanEntry("battery", T0 + 1.0, 0), PlanEntry("battery", T0 + 2.0, 1))
    assert (plan.sender, plan.made_t, plan.until_t) == ("a", T0, T0 + 3)
    assert plan.wire_bytes() == 4


def test_agreed_plans_is_off_by_default_and_checked() -> None:
    spec = builtin_spec("sim_mostly_low")
    assert MiddlewareConfig(spec=spec, agent="a").agreed_plans is None
    with pytest.raises(MiddlewareError, match="agreed_plans"):
        MiddlewareConfig(spec=spec, agent="a", agreed_plans="trust")


def test_the_fleet_hears_a_plan_only_with_a_delivered_message() -> None:
    """Three agents on a simulated channel: each agent's newest heard plan from a peer is the
    one that peer made when it sent its last delivered message (same delay and loss)."""
    spec = builtin_spec("sim_mostly_low")
    agents = []
    for i in range(3):
        config = MiddlewareConfig(spec=spec, agent=f"agent{i}", max_iterations=100,
                                  agreed_plans="fix")
        policy = Middleware(config, constraint=ConstantConstraint(limit_bytes_per_s=4096 / 2.5,
                                                                  window_s=2.5))
        stream = StreamConfig(type=f"battery_{i}", period_s=0.5 + 0.1 * i, size=2048,
                              data=lambda k, g: {"level": 1.0, "depletion_rate": 0.01})
        agents.append(SimAgent(name=f"agent{i}", policy=policy, streams=[stream]))
    made: dict[tuple[str, int], float] = {}
    for agent in agents:
        decide = agent.policy.decide

        def wrapped(m, now, _decide=decide, _name=agent.name, **kw):  # type: ignore[no-untyped-def]
            decision = _decide(m, now, **kw)
            if decision.send:
                made[(_name, m.seq)] = now
            return decision

        agent.policy.decide = wrapped  # type: ignore[method-assign]
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=50_000, loss=0.3),
                      t_end=10.0, rng=np.random.default_rng(5))
    assert result.lost > 0
    for agent in agents:
        heard = agent.policy.agreed.plans  # type: ignore[attr-defined]
        for peer in agents:
            if peer is agent:
                continue
            got = [m for m in result.delivered if m.sender == peer.name]
            assert got, "every peer had a message delivered"
            newest = max(got, key=lambda m: m.t_rcv or 0.0)
            assert heard[peer.name].made_t == made[(peer.name, newest.seq)]
            assert heard[peer.name].sender == peer.name
