"""MCTS steps on hand-made trees (alg. 1-2), pruning (eq. 5.5), merging (eq. 5.8/5.9)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import _kernel
from companion.middleware.baselines import offline_optimum
from companion.middleware.mcts import MCTS, greedy_option
from tests.middleware.conftest import T0, msg, problem_of, random_problem, small_spec

SPEC = small_spec()


def _two_children(c: float) -> MCTS:
    """Root with a fully expanded pair: send child (10 visits, mean 0.6), drop (1, 0.3)."""
    problem = problem_of(SPEC, [msg("a", 0, "linear", T0), msg("a", 1, "linear", T0 + 1)],
                         horizon_end=T0 + 5)
    search = MCTS(problem, c=c, max_nodes=20)
    t = search.tree
    t.counters[_kernel.C_NODES] = 3
    t.visits[0], t.tried[0], t.live[0] = 11, 2, 2
    for node, o, visits, mean in ((1, 1, 10, 0.6), (2, 0, 1, 0.3)):
        t.parent[node], t.depth[node], t.option[node] = 0, 1, o
        t.visits[node], t.value[node] = visits, visits * mean
        t.children[0, o] = node
    return search


@pytest.mark.parametrize(("c", "expected"), [(0.35, 2), (0.1, 1)])
def test_uct_choice(c: float, expected: int) -> None:
    """UCT (eq. 5.3): 0.6 + c·sqrt(ln 11 / 10) against 0.3 + c·sqrt(ln 11 / 1)."""
    uct_send = 0.6 + c * math.sqrt(math.log(11) / 10)
    uct_drop = 0.3 + c * math.sqrt(math.log(11) / 1)
    assert (uct_drop > uct_send) == (expected == 2)
    search = _two_children(c)
    search.run(1)
    assert search.tree.visits[expected] == (10 if expected == 1 else 1) + 1
    assert search.tree.parent[3] == expected  # the new node was expanded below the choice


def test_expansion_order_sends_first_and_decision_by_most_visits() -> None:
    problem = problem_of(SPEC, [msg("a", 0, "linear", T0)], horizon_end=T0 + 5)
    search = MCTS(problem, max_nodes=10)
    search.run(1)
    assert int(search.tree.option[1]) == 1  # the first child created is "send"
    search.run(1)
    assert int(search.tree.option[2]) == 0
    search.run(20)
    result = search.result()
    assert result.option == 1
    assert result.visits == max(int(search.tree.visits[c]) for c in search.tree.live_children(0))


def test_tie_in_visits_prefers_sending() -> None:
    problem = problem_of(SPEC, [msg("a", 0, "linear", T0 + 10.0)], horizon_end=T0 + 5)
    search = MCTS(problem, max_nodes=10)  # the message arrives after the horizon: no gain
    search.run(2)
    assert search.result().option == 1


def test_pruning_never_keeps_a_node_over_budget() -> None:
    messages = [msg("a", k, "linear", T0 + 0.3 * k, size=100) for k in range(6)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 5, budget_bytes=200, window_s=1.0)
    search = MCTS(problem, max_nodes=3000)
    search.run(3000)
    assert search.result().pruned > 0
    for node in range(1, search.tree.n_nodes):
        if not search.tree.dead[node]:
            assert problem.feasible(_path(search, node) + [0] * (problem.n - _depth(search, node)))


def _path(search: MCTS, node: int) -> list[int]:
    out = []
    while node > 0:
        out.append(int(search.tree.option[node]))
        node = int(search.tree.parent[node])
    return out[::-1]


def _depth(search: MCTS, node: int) -> int:
    return int(search.tree.depth[node])


def test_markovian_merging_keeps_tree_polynomial() -> None:
    """One Markovian stream of 14 messages: at most level+1 states per level (eq. 5.9)."""
    messages = [msg("a", k, "battery", T0 + 0.5 * k) for k in range(14)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 10)
    search = MCTS(problem, max_nodes=20_000)
    search.run(20_000)
    t = search.tree
    alive = [n for n in range(t.n_nodes) if not t.dead[n]]
    per_level = np.bincount(t.depth[alive], minlength=problem.n + 1)
    assert all(per_level[d] <= d + 1 for d in range(problem.n + 1))
    assert search.result().merged > 0
    assert t.n_nodes < 2**problem.n / 20  # polynomial, not 2^14 = 16384 nodes


def test_fallback_when_the_decided_level_is_not_reached() -> None:
    messages = [msg("b", k, "linear", T0 + 0.1 * k) for k in range(5)] + [
        msg("a", 9, "linear", T0 + 1.0, size=100)
    ]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 5, decided=5)
    search = MCTS(problem, max_nodes=5)
    search.run(3)
    assert search.result().option is None
    assert greedy_option(problem, 5) == 1


def test_deterministic() -> None:
    messages = [msg(s, k, "battery", T0 + 0.37 * k + (0.1 if s == "b" else 0))
                for k in range(8) for s in ("a", "b")]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 6, budget_bytes=300, window_s=1.0)
    runs = []
    for _ in range(2):
        search = MCTS(problem, max_nodes=800)
        search.run(800)
        runs.append((search.result(), search.tree.visits.copy()))
    assert runs[0][0] == runs[1][0]
    assert np.array_equal(runs[0][1], runs[1][1])


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 8), budget=st.integers(0, 5), seed=st.integers(0, 10_000))
def test_offline_optimum_is_exact_and_never_beaten(n: int, budget: int, seed: int) -> None:
    problem = random_problem(SPEC, n, budget, seed)
    best = max(
        problem.path_gain(c)
        for c in itertools.product(*[range(int(problem.nopt[i])) for i in range(problem.n)])
        if problem.feasible(c)
    )
    opt = offline_optimum(problem)
    assert opt.gain == pytest.approx(best, rel=1e-12, abs=1e-12)
    assert problem.feasible(opt.choices)
    search = MCTS(problem, max_nodes=300)
    search.run(300)
    chosen = list(search.result().path) + [0] * (problem.n - len(search.result().path))
    assert problem.feasible(chosen)
    assert problem.path_gain(chosen) <= opt.gain + 1e-9


def test_without_a_constraint_everything_is_sent() -> None:
    messages = [msg("a", k, "linear", T0 + 0.5 * k) for k in range(6)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 8)
    search = MCTS(problem, max_nodes=500)
    search.run(500)
    assert search.result().path == (1,) * 6


def _random_messages(seed: int, n: int, kinds: tuple[str, ...]) -> list:  # type: ignore[type-arg]
    rng = np.random.default_rng(seed)
    return [
        msg(str(rng.choice(["a", "b", "c"])), k, kinds[int(rng.integers(len(kinds)))],
            T0 + 0.3 * k + float(rng.uniform(0, 0.2)), size=int(rng.integers(50, 150)))
        for k in range(n)
    ]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 10))
def test_property_no_constraint_sends_everything(seed: int, n: int) -> None:
    messages = _random_messages(seed, n, ("battery", "linear"))
    problem = problem_of(SPEC, messages, horizon_end=T0 + 6)
    search = MCTS(problem, max_nodes=400)
    search.run(400)
    assert search.result().path == (1,) * n


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 10), budget=st.integers(0, 400))
def test_property_kept_nodes_never_violate_the_window(seed: int, n: int, budget: int) -> None:
    messages = _random_messages(seed, n, ("battery", "linear", "status"))
    problem = problem_of(SPEC, messages, horizon_end=T0 + 6, budget_bytes=budget, window_s=1.0)
    search = MCTS(problem, max_nodes=500)
    search.run(500)
    for node in range(1, search.tree.n_nodes):
        if not search.tree.dead[node]:
            assert problem.feasible(_path(search, node) + [0] * (problem.n - _depth(search, node)))


def test_compiled_and_plain_python_kernels_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without numba the same kernel runs as Python: same tree, same decision."""
    messages = [msg(s, k, "battery", T0 + 0.37 * k + (0.1 if s == "b" else 0))
                for k in range(6) for s in ("a", "b")]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 6, budget_bytes=300, window_s=1.0)
    compiled = MCTS(problem, max_nodes=300)
    compiled.run(300)
    if not _kernel.JIT:
        pytest.skip("numba not installed: only the Python kernel exists")
    for name in ("_mix", "_score", "_rollout", "_backprop", "_kill", "_abs_utility",
                 "_hash_find", "search"):
        monkeypatch.setattr(_kernel, name, getattr(_kernel, name).py_func)
    plain = MCTS(problem, max_nodes=300)
    plain.run(300)
    assert plain.result() == compiled.result()
    assert np.array_equal(plain.tree.visits, compiled.tree.visits)
