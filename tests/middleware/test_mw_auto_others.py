"""The other agents follow a fixed policy in this agent's tree (issue 18 round 8, ``auto``).

Their levels are no decisions of the tree: each takes the option its policy takes in the
path's state, and only the agent's own levels branch. Checked against a brute force over the
own options alone, with the others' options replayed by an independent reading of the rule.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import (
    ConstantConstraint,
    Middleware,
    MiddlewareConfig,
    MiddlewareError,
    _kernel,
)
from companion.middleware.incremental import Problem, build_problem
from companion.middleware.knowledge import PlanItem
from companion.middleware.mcts import MCTS
from tests.middleware.conftest import T0, msg, small_spec

SPEC = small_spec()


def _problem(seed: int, n: int, budget: int, *, images: bool = False) -> Problem:
    """Agent ``a`` decides its first message; ``b`` and ``c`` are the others."""
    rng = np.random.default_rng(seed)
    kinds = ("battery", "linear", "status", "image") if images else ("battery", "linear", "status")
    messages = [msg("a", 0, "battery", T0, size=int(rng.integers(50, 150)))]
    for k in range(1, n):
        kind = kinds[int(rng.integers(len(kinds)))]
        messages.append(msg(str(rng.choice(["a", "b", "c"])), k, kind,
                            T0 + 0.3 * k + float(rng.uniform(0, 0.2)),
                            size=int(rng.integers(50, 150))))
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                      kind="decide" if k == 0 else "forecast") for k, m in enumerate(messages)]
    return build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 6, budget_bytes=budget,
                         window_s=1.0, agent="a")


def _others_option(p: Problem, i: int, slot: int, used: int, mode: str, lam: float,
                   plan: np.ndarray) -> int:
    """The others' rule, read from the docs: knapsack's option if it fits; else the
    highest-gain option that fits (``fit``) and earns ``lam`` per byte (``density``)."""
    fits = [o for o in range(1, int(p.nopt[i])) if used + int(p.size[i, o]) <= p.budget_bytes]
    if mode == "knapsack":
        return int(plan[i]) if int(plan[i]) in fits else 0
    if mode == "density":
        fits = [o for o in fits if p.gain[i, o, slot] >= lam * int(p.size[i, o])]
    best, best_g = 0, 0.0
    for o in fits:
        if p.gain[i, o, slot] > best_g:
            best, best_g = o, float(p.gain[i, o, slot])
    return best


def _plan_value(p: Problem, own: dict[int, int], mode: str, lam: float,
                plan: np.ndarray) -> float | None:
    """Utility of the fleet plan in which the own levels take ``own`` and the others their
    rule; None when an own send breaks the window."""
    last = [0] * p.n_streams
    sends: list[tuple[float, int]] = []
    total = 0.0
    for i in range(p.n):
        used = sum(b for t, b in sends if t >= p.send_t[i] - p.window_s - 1e-9)
        s = int(p.stream[i])
        slot = last[s] if s >= 0 else 0
        if p.own[i]:
            o = own[i]
            if o and used + int(p.size[i, o]) > p.budget_bytes + 1e-9:
                return None
        else:
            o = _others_option(p, i, slot, used, mode, lam, plan)
        if o:
            total += float(p.gain[i, o, slot])
            sends.append((float(p.send_t[i]), int(p.size[i, o])))
            if s >= 0:
                last[s] = p.next_slot(i, o, slot)
    return total


def _brute_force(p: Problem, mode: str, lam: float, plan: np.ndarray
                 ) -> tuple[float, set[int]]:
    """Best plan value over the own options, and the decided level's options that reach it."""
    own_levels = [i for i in range(p.n) if p.own[i]]
    values: dict[tuple[int, ...], float] = {}
    for combo in itertools.product(*(range(int(p.nopt[i])) for i in own_levels)):
        v = _plan_value(p, dict(zip(own_levels, combo, strict=True)), mode, lam, plan)
        if v is not None:
            values[combo] = v
    best = max(values.values())
    at = own_levels.index(p.decided_level)
    return best, {c[at] for c, v in values.items() if v >= best - 1e-9}


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 10), budget=st.integers(0, 400),
       mode=st.sampled_from(["density", "fit", "knapsack"]), images=st.booleans())
def test_the_best_plan_is_the_best_response_to_the_others_fixed_policy(
        seed: int, n: int, budget: int, mode: str, images: bool) -> None:
    """Covered (few own levels), the tree's best plan is exactly the best own choice when the
    others follow their policy in each plan's state, and the answer is one that reaches it."""
    problem = _problem(seed, n, budget, images=images)
    search = MCTS(problem, max_nodes=3000, best_plan=True, auto=mode)
    search.run(3000)
    best, answers = _brute_force(problem, mode, search.lam, search.oplan)
    assert float(search.best[0]) == pytest.approx(best, abs=1e-9)
    assert search.result().option in answers


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 12), budget=st.integers(0, 400))
def test_only_own_levels_branch(seed: int, n: int, budget: int) -> None:
    """Every inner node sits at one of the agent's own levels: the others' levels have no
    nodes, so the tree's size does not grow with how the others could choose."""
    problem = _problem(seed, n, budget)
    search = MCTS(problem, max_nodes=600, auto="density")
    search.run(600)
    t = search.tree
    depths = t.depth[: t.n_nodes]
    inner = depths[depths < problem.n]
    assert all(problem.own[d] for d in inner)
    own_options = int(np.prod([problem.nopt[i] for i in range(problem.n) if problem.own[i]]))
    assert t.n_nodes <= 1 + own_options * int(problem.own.sum())


def test_the_decision_does_not_bend_the_others_to_this_agents_plan() -> None:
    """Agent a's low-value battery report now, b's report 0.3 s later, a's next report
    0.6 s later; the window holds one report. Searched, the tree may drop b's report to keep
    room for a's next one (b follows a's plan); with ``auto`` b sends its report whenever it
    fits, so dropping now only hands the window to b, and the best response differs."""
    messages = [msg("a", 0, "battery", T0, size=100, level=0.9),
                msg("b", 0, "battery", T0 + 0.3, size=100, level=0.2),
                msg("a", 1, "battery", T0 + 0.6, size=100, level=0.9)]
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                      kind="decide" if k == 0 else "forecast") for k, m in enumerate(messages)]
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 6, budget_bytes=150,
                            window_s=1.0, agent="a")
    assert problem.own.tolist() == [True, False, True]
    auto = MCTS(problem, max_nodes=200, best_plan=True, auto="fit")
    auto.run(200)
    searched = MCTS(problem, max_nodes=200, best_plan=True)
    searched.run(200)
    best, answers = _brute_force(problem, "fit", auto.lam, auto.oplan)
    assert float(auto.best[0]) == pytest.approx(best)
    assert auto.result().option in answers
    # the searched tree plans b's option too: its best plan is worth at least as much
    assert float(searched.best[0]) >= float(auto.best[0]) - 1e-9


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 12), budget=st.integers(0, 400))
def test_the_others_near_the_decided_message_stay_searched(seed: int, n: int, budget: int
                                                            ) -> None:
    """``auto_after_s``: the others' levels up to that long after the decided message branch;
    covering the whole horizon it is the searched tree itself, node for node."""
    problem = _problem(seed, n, budget)
    near = MCTS(problem, max_nodes=400, auto="density", auto_after_s=0.7)
    t0 = float(problem.send_t[problem.decided_level])
    assert near.branch.tolist() == [bool(o) or t <= t0 + 0.7
                                    for o, t in zip(problem.own, problem.send_t, strict=True)]
    everything = MCTS(problem, max_nodes=400, auto="density", auto_after_s=1e9)
    searched = MCTS(problem, max_nodes=400)
    everything.run(400)
    searched.run(400)
    assert everything.result() == searched.result()
    assert np.array_equal(everything.tree.visits, searched.tree.visits)


def test_compiled_and_plain_python_kernels_agree_with_auto(
        monkeypatch: pytest.MonkeyPatch) -> None:
    problem = _problem(7, 10, 250)
    compiled = MCTS(problem, max_nodes=300, auto="density")
    compiled.run(300)
    if not _kernel.JIT:
        pytest.skip("numba not installed: only the Python kernel exists")
    for name in ("_mix", "_score", "_auto_option", "_advance", "_rollout", "_backprop", "_kill",
                 "_abs_utility", "_hash_find", "search"):
        monkeypatch.setattr(_kernel, name, getattr(_kernel, name).py_func)
    plain = MCTS(problem, max_nodes=300, auto="density")
    plain.run(300)
    assert plain.result() == compiled.result()
    assert np.array_equal(plain.tree.visits, compiled.tree.visits)


def test_the_middleware_marks_its_own_levels_and_decides_with_auto() -> None:
    mw = Middleware(MiddlewareConfig(spec=SPEC, agent="a", max_iterations=300,
                                     auto_others="density"),
                    constraint=ConstantConstraint(limit_bytes_per_s=300, window_s=1.0))
    for k in range(4):
        mw.on_delivered([msg("b", k, "battery", T0 + k * 0.5, size=100).delivered(
            receiver="ground", t_rcv=T0 + k * 0.5 + 0.05)], T0 + k * 0.5 + 0.05)
    decision = mw.decide(msg("a", 0, "battery", T0 + 2.1, size=100), T0 + 2.1)
    problem = mw.last_problem
    assert problem is not None and decision.reason.startswith("mcts")
    assert problem.own.tolist() == [it.message.sender == "a" for it in problem.items]
    assert not problem.own.all() and problem.own[problem.decided_level]


def test_an_unknown_auto_policy_is_a_one_line_error() -> None:
    with pytest.raises(MiddlewareError, match="auto_others must be one of"):
        MiddlewareConfig(spec=SPEC, agent="a", auto_others="everyone")
    with pytest.raises(MiddlewareError, match="auto_after_s must be >= 0"):
        MiddlewareConfig(spec=SPEC, agent="a", auto_others="density", auto_after_s=-1.0)
    with pytest.raises(ValueError, match="auto must be one of"):
        MCTS(_problem(1, 3, 100), auto="everyone")
