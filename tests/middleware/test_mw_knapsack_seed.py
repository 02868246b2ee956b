"""MCTS seeded with the knapsack-greedy plan (issue 18): the plan is the baseline's, the search
starts from it, and more iterations never lower the model utility of the answer."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import _kernel
from companion.middleware.baselines import knapsack_option, offline_optimum
from companion.middleware.incremental import Problem, build_problem
from companion.middleware.knowledge import PlanItem
from companion.middleware.mcts import MCTS, rollout_threshold
from tests.middleware.conftest import T0, msg, problem_of, small_spec

SPEC = small_spec()


def _problem(seed: int, n: int, budget: int, *, root: bool = False) -> Problem:
    rng = np.random.default_rng(seed)
    kinds = ("battery", "linear", "status")
    messages = [
        msg(str(rng.choice(["a", "b", "c"])), k, kinds[int(rng.integers(3))],
            T0 + 0.3 * k + float(rng.uniform(0, 0.2)), size=int(rng.integers(50, 150)))
        for k in range(n)
    ]
    items = [PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + 0.1,
                      kind="decide" if k == 0 else "forecast") for k, m in enumerate(messages)]
    return build_problem(SPEC, items=items, fixed=[], horizon_end=T0 + 6, budget_bytes=budget,
                         window_s=1.0, root_window=((T0 - 0.5, 120),) if root else ())


def _used(problem: Problem, plan: list[int], i: int) -> int:
    lo = float(problem.send_t[i]) - problem.window_s - 1e-9
    used = sum(int(b) for t, b in zip(problem.root_win_t, problem.root_win_bytes, strict=True)
               if t >= lo)
    return used + sum(int(problem.size[j, o]) for j, o in enumerate(plan[:i])
                      if o and problem.send_t[j] >= lo)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 12), budget=st.integers(0, 400),
       root=st.booleans())
def test_plan_is_the_baselines_decision_level_by_level(seed: int, n: int, budget: int,
                                                       root: bool) -> None:
    """Each level's option is what KnapsackGreedy decides there, given the plan's earlier
    sends; the plan keeps the window constraint (unless the root window alone breaks it)."""
    problem = _problem(seed, n, budget, root=root)
    search = MCTS(problem, max_nodes=10, knapsack_seed=True)
    plan = [int(o) for o in search.plan[: problem.n]]
    for i in range(problem.n):
        room = problem.budget_bytes - _used(problem, plan, i)
        assert plan[i] == knapsack_option(problem, i, room=room, now=float(problem.send_t[i]))
    assert problem.feasible(plan) or not problem.feasible([0] * problem.n)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 7), budget=st.integers(0, 400))
def test_answer_starts_at_the_plan_and_only_improves(seed: int, n: int, budget: int) -> None:
    """After one iteration the best plan is worth at least the knapsack plan; every further
    chunk of iterations keeps or raises it, never above the exact optimum."""
    problem = _problem(seed, n, budget)
    search = MCTS(problem, max_nodes=400, knapsack_seed=True)
    plan = [int(o) for o in search.plan[: problem.n]]
    search.run(1)
    assert search.result().option is not None
    values = [float(search.best[0])]
    assert values[0] >= problem.path_gain(plan) - 1e-9
    for _ in range(8):
        search.run(50)
        values.append(float(search.best[0]))
    assert values == sorted(values)
    assert values[-1] <= offline_optimum(problem).gain + 1e-9


def test_seed_expands_the_plans_option_first() -> None:
    """Two levels, room for one 100-byte message in the window: the densest (the status
    message, worth most alone) is the plan, and the root's first child takes its option."""
    messages = [msg("a", 0, "linear", T0), msg("b", 1, "status", T0 + 0.2)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 5, budget_bytes=100, window_s=1.0)
    search = MCTS(problem, max_nodes=10, knapsack_seed=True)
    dens = [max(float(problem.gain[i, o, 0]) / float(problem.size[i, o])
                for o in range(1, int(problem.nopt[i]))) for i in range(2)]
    expected = [0, 1] if dens[1] > dens[0] else [1, 0]
    assert [int(o) for o in search.plan[:2]] == expected
    search.run(1)
    assert int(search.tree.option[1]) == expected[0]


def test_unseeded_search_is_unchanged() -> None:
    """knapsack_seed=False leaves the kernel's plan empty: the thesis' MCTS, most visited."""
    problem = _problem(7, 10, 250)
    search = MCTS(problem, max_nodes=300)
    assert not search.seeded and int(search.plan[0]) == -1
    search.run(300)
    result = search.result()
    assert result.option == int(search.tree.option[search.most_visited_path()[0]])
    assert _kernel.NO_CHILD == -1


def _threshold_loop(problem: Problem, chain: bool) -> float:
    """The rollout threshold as first written (plain loops): the vectorised one must match."""
    dens: list[tuple[float, int]] = []
    for i in range(problem.n):
        s, q = int(problem.stream[i]), int(problem.pos[i])
        slot = 1 + (q - 1) * problem.max_versions if chain and s >= 0 and q > 0 else 0
        best = 0.0
        for o in range(1, int(problem.nopt[i])):
            best = max(best, float(problem.gain[i, o, slot]) / max(1, int(problem.size[i, o])))
        dens.append((best, max(1, int(problem.size[i, 1]))))
    span = float(problem.send_t[-1] - problem.send_t[0])
    capacity = problem.budget_bytes * max(1.0, span / problem.window_s)
    used = 0.0
    for density, size in sorted(dens, reverse=True):
        used += size
        if used > capacity:
            return density
    return 0.0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 12), budget=st.integers(0, 400),
       chain=st.booleans())
def test_vectorised_rollout_threshold_is_exact(seed: int, n: int, budget: int,
                                               chain: bool) -> None:
    problem = _problem(seed, n, budget)
    assert rollout_threshold(problem, chain=chain) == _threshold_loop(problem, chain)


def test_study_policy_names_select_the_seed() -> None:
    """``mcts300ks`` in the mcts-vs-baselines study is the seeded search, ``mcts300`` not."""
    from companion.middleware.middleware import Middleware
    from sitl.study.baselines import _policy

    made = {name: _policy(name, 0.0, spec=SPEC, agent="a", index=0, seed=1,
                          budget_bytes=1000.0, window_s=1.0, horizon_s=3.0)
            for name in ("mcts300", "mcts300ks", "mcts1500ks")}
    assert all(isinstance(p, Middleware) for p in made.values())
    seeded = {n: (p.config.knapsack_seed, p.config.max_iterations)  # type: ignore[union-attr]
              for n, p in made.items()}
    assert seeded == {"mcts300": (False, 300), "mcts300ks": (True, 300),
                      "mcts1500ks": (True, 1500)}
