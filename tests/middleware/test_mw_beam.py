"""The beam dynamic programme over a decision's tantamount states, and the search it seeds
(``dp_seed``, issue 18 round 13)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import _beam
from companion.middleware.baselines import offline_optimum
from companion.middleware.errors import MiddlewareError
from companion.middleware.incremental import Problem
from companion.middleware.mcts import DP_TIGHT, MCTS
from companion.middleware.middleware import MiddlewareConfig
from tests.middleware.conftest import T0, msg, problem_of, random_problem, small_spec

SPEC = small_spec()


def _problem(n: int, budget: int, seed: int) -> Problem:
    return random_problem(SPEC, n, budget, seed)


def _reference_canonical_slots(problem: Problem) -> list[list[int]]:
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


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 9), budget=st.integers(0, 5), seed=st.integers(0, 10_000))
def test_a_wide_beam_is_the_exact_optimum(n: int, budget: int, seed: int) -> None:
    problem = _problem(n, budget, seed)
    opt = offline_optimum(problem)
    plan, value = _beam.plan_of(problem, 64)
    assert problem.feasible(list(plan))
    assert value == pytest.approx(opt.gain, rel=1e-9, abs=1e-9)
    assert problem.path_gain(list(plan)) == pytest.approx(value, rel=1e-9, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 9), budget=st.integers(0, 5), seed=st.integers(0, 10_000),
       width=st.integers(1, 4))
def test_a_narrow_beam_is_feasible_never_better_and_forcing_splits_it(
        n: int, budget: int, seed: int, width: int) -> None:
    problem = _problem(n, budget, seed)
    opt = offline_optimum(problem)
    plan, value = _beam.plan_of(problem, width)
    assert problem.feasible(list(plan))
    assert value <= opt.gain + 1e-9
    level = n // 2
    sent, u_send = _beam.plan_of(problem, 64, force_level=level, force_send=True)
    dropped, u_drop = _beam.plan_of(problem, 64, force_level=level, force_send=False)
    assert dropped[level] == 0 and problem.feasible(list(dropped))
    if u_send > -np.inf:
        assert sent[level] != 0 and problem.feasible(list(sent))
    assert max(u_send, u_drop) == pytest.approx(opt.gain, rel=1e-9, abs=1e-9)


def test_a_tight_budget_answers_with_a_plan_never_worse_than_the_seed() -> None:
    """Two streams, room for one message a second: the seeded search's answer is its best
    plan, worth at least the dynamic programme's."""
    messages = [msg(s, k, "linear", T0 + 0.25 * k + (0.1 if s == "b" else 0.0), size=100)
                for k in range(8) for s in ("a", "b")]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 4, budget_bytes=100, window_s=1.0)
    plan, value = _beam.plan_of(problem, 128)
    assert np.mean(plan == 0) >= DP_TIGHT
    search = MCTS(problem, max_nodes=301, dp_seed=128)
    assert search.best_plan
    search.run(300)
    result = search.result()
    assert result.option is not None
    assert float(search.best[0]) >= value - 1e-9


def test_a_loose_budget_keeps_the_most_visited_path() -> None:
    messages = [msg("a", k, "linear", T0 + 0.5 * k) for k in range(6)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 8)
    search = MCTS(problem, max_nodes=301, dp_seed=128)
    assert not search.best_plan  # nothing to drop: alg. 2's rule answers
    search.run(300)
    assert search.result().option == 1


@pytest.mark.parametrize("width", [0, -3])
def test_a_beam_width_below_one_is_refused(width: int) -> None:
    with pytest.raises(MiddlewareError, match="dp_seed"):
        MiddlewareConfig(spec=SPEC, agent="a", dp_seed=width)
    problem = problem_of(SPEC, [msg("a", 0, "linear", T0)], horizon_end=T0 + 5)
    with pytest.raises(ValueError, match="beam width"):
        MCTS(problem, dp_seed=width)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 12), budget=st.integers(0, 5), seed=st.integers(0, 10_000))
def test_the_compiled_canonical_slots_are_the_reference_ones(n: int, budget: int,
                                                             seed: int) -> None:
    problem = _problem(n, budget, seed)
    assert np.array_equal(_beam.canonical_slots(problem),
                          np.array(_reference_canonical_slots(problem)))


def test_the_knapsack_seed_is_not_overwritten_by_the_default_dp_seed() -> None:
    problem = _problem(8, 2, 3)
    alone = MCTS(problem, knapsack_seed=True)
    both = MCTS(problem, knapsack_seed=True, dp_seed=128)
    assert np.array_equal(both.plan, alone.plan)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 9), budget=st.integers(0, 5), seed=st.integers(0, 10_000),
       price=st.floats(0.0, 1.0), mix=st.sampled_from([0.25, 0.75, 1.0]))
def test_a_priced_beam_is_exact_when_wide_and_feasible_when_narrow(
        n: int, budget: int, seed: int, price: float, mix: float) -> None:
    """The price only orders which states a full beam drops: a wide beam keeps them all."""
    problem = _problem(n, budget, seed)
    opt = offline_optimum(problem)
    plan, value = _beam.plan_of(problem, 64, price=price, mix=mix)
    assert problem.feasible(list(plan))
    assert value == pytest.approx(opt.gain, rel=1e-9, abs=1e-9)
    narrow, low = _beam.plan_of(problem, 2, price=price, mix=mix)
    assert problem.feasible(list(narrow)) and low <= opt.gain + 1e-9
    assert problem.path_gain(list(narrow)) == pytest.approx(low, rel=1e-9, abs=1e-9)


def test_a_priced_beam_leaves_the_room_two_later_messages_need() -> None:
    """One 200-byte message, then two of 100 bytes within the window, each worth the same:
    kept by utility alone a one-state beam sends the first and has no room for the others;
    priced for the window its bytes still hold, it keeps the drop and sends both."""
    messages = [msg("a", 0, "linear", T0, size=200), msg("b", 0, "linear", T0 + 0.3, size=100),
                msg("c", 0, "linear", T0 + 0.6, size=100)]
    problem = problem_of(SPEC, messages, horizon_end=T0 + 6, budget_bytes=200, window_s=1.0)
    opt = offline_optimum(problem)
    greedy, u_greedy = _beam.plan_of(problem, 1)
    assert list(greedy) == [1, 0, 0] and u_greedy == pytest.approx(opt.gain / 2)
    density = opt.gain / 2 / 100  # utility per byte of the small messages
    priced, u_priced = _beam.plan_of(problem, 1, price=density)
    assert list(priced) == [0, 1, 1] and u_priced == pytest.approx(opt.gain)
