"""Monte Carlo Tree Search over send/drop/version decisions (thesis ch. 5.2-5.3, alg. 1-3).

Levels of the tree are the messages of one decision's :class:`Problem` in generation-time
order (other agents' messages that may still be in flight, the message being decided,
forecast messages). A node's children are its level's options: send version 0, 1, ... or
drop. One iteration selects by UCT (eq. 5.3), expands one new child (alg. 1: options are
tried best version first, drop last, so that an unexplored tie never silently favours
dropping), scores it and backpropagates. Children that break the goodput window (eq. 5.5,
5.7) are pruned with their subtree; tantamount children (same Markovian state eq. 5.8, same
sets for other types, same sends in the window, footnote 5) are merged, keeping the better.

Node score (eq. 5.2). The thesis scores a node by U(M_v) / (ψ·U(𝓜)) with ψ = t / t_end, which
assumes the tree spans the mission: U(M_v) is then the utility of everything decided so far
and ψ·U(𝓜) what that share of the mission could bring. Here the tree spans a horizon of a few
seconds, and a literal ψ = t / t_end would make early decisions greedy (tiny ψ, scores near
1 for any send) and late ones random (scores pinned near the top). Instead every node is
scored as a *complete plan* over the horizon: the utility added by its decided prefix (levels
< d, the incremental tables) plus what the default policy adds from level d on (alg. 1's
simulation step: in generation order, send the option with the highest gain whose utility per
byte reaches the density at which the horizon's messages would fill the window budget, if it
fits the window), divided by U of sending every message of the horizon in its best version
(the horizon's U(𝓜), i.e. ψ = 1 for a plan that covers the whole horizon). So S(v) ∈ [0, 1]
at every depth, a shallow node is neither favoured nor penalised for having decided less,
budget spent early shows up as sends the default policy can no longer make, and the
discovery factor c = 0.35 keeps one meaning at every level. A horizon where nothing can be
gained (U(𝓜) = 0) scores 1.

With ``best_plan`` (opt-in since issue 18 round 6, measured with ``depth`` 10) the
decision is the decided level's option of the best complete plan any iteration evaluated:
the model is deterministic, so more iterations never lower the answer's model utility.
Otherwise it follows the most visited path (alg. 2); ties go to the higher mean score, then
to sending. If the budget ends before the decided message's level is reached on that path,
:func:`greedy_option` answers instead (stated in the decision's reason).

With ``veto`` (opt-in, issue 18 round 7) a second, unbounded tree runs the same iterations
and its most visited path may veto a send: the bounded best plan's send goes out unless, at
the decided level of the second tree's most visited path, the drop child has more than
``veto`` times the visits of that send's child. A send then needs both the best plan found
and the averaged statistics of a tree in which the others' choices vary.

With ``knapsack_seed`` the search starts from knapsack-greedy's plan (expanded first at
every node, and a second default policy that follows it) and answers with the decided
level's option of the best complete plan any iteration evaluated: never worse in the model
than the knapsack plan, and never worse with more iterations (issue 18).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.middleware import _beam, _kernel
from companion.middleware.incremental import Problem

__all__ = ["MCTS", "SearchResult", "Tree", "greedy_option"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SearchResult:
    """What one search found for the decided level."""

    option: int | None
    """0 drop, ``v + 1`` send version v; ``None`` when the path never reached the level."""
    score: float
    """Mean node score (eq. 5.2, normalised) of the chosen child; NaN without an answer."""
    visits: int
    path: tuple[int, ...]
    """Options along the most visited path from the root."""
    iterations: int
    nodes: int
    pruned: int
    merged: int
    replaced: int
    exhausted: bool
    """The whole (reduced) tree was explored: the answer is exact for the model."""


class Tree:
    """Node arrays; node 0 is the root. Every iteration creates at most one node."""

    __slots__ = (
        "children",
        "counters",
        "dead",
        "delta",
        "depth",
        "hkeys",
        "hvals",
        "live",
        "option",
        "parent",
        "tried",
        "value",
        "visits",
    )

    def __init__(self, *, max_nodes: int, max_opt: int) -> None:
        self.parent = np.full(max_nodes, -1, dtype=np.int64)
        self.depth = np.zeros(max_nodes, dtype=np.int64)
        self.option = np.zeros(max_nodes, dtype=np.int64)
        self.visits = np.zeros(max_nodes, dtype=np.int64)
        self.value = np.zeros(max_nodes, dtype=np.float64)
        self.delta = np.zeros(max_nodes, dtype=np.float64)
        self.children = np.full((max_nodes, max_opt), _kernel.NO_CHILD, dtype=np.int64)
        self.tried = np.zeros(max_nodes, dtype=np.int64)
        self.live = np.zeros(max_nodes, dtype=np.int64)
        self.dead = np.zeros(max_nodes, dtype=np.bool_)
        size = 1 << max(4, int(4 * max_nodes - 1).bit_length())
        self.hkeys = np.zeros(size, dtype=np.uint64)
        self.hvals = np.full(size, -1, dtype=np.int64)
        self.counters = np.zeros(8, dtype=np.int64)
        self.counters[_kernel.C_NODES] = 1  # the root

    @property
    def n_nodes(self) -> int:
        return int(self.counters[_kernel.C_NODES])

    def live_children(self, node: int) -> list[int]:
        return [int(c) for c in self.children[node] if c >= 0 and not self.dead[c]]

    def mean(self, node: int) -> float:
        v = int(self.visits[node])
        return float(self.value[node]) / v if v else float("nan")


DP_TIGHT = 0.5
"""With ``dp_seed``: the share of the decided level and the levels after it that the
dynamic programme's plan drops, from which the answer is the best plan evaluated (a tight
budget: which few messages go is a combinatorial choice, and the averaged statistics favour
sending); below it the most visited path (most messages go, the plan's drops are near-ties in
the model, and the averages hedge against its errors). Measured, issue 18 round 13."""


class MCTS:
    """One decision's search: build with a :class:`Problem`, :meth:`run`, read :meth:`result`."""

    __slots__ = ("best", "best_at", "best_plan", "c", "depth_limit", "lam", "plan", "problem",
                 "robust", "top", "tree", "veto")

    def __init__(self, problem: Problem, *, c: float = 0.35, max_nodes: int = 1501,
                 knapsack_seed: bool = False, best_plan: bool = False,
                 depth: int | None = None, veto: float | None = None,
                 dp_seed: int | None = None) -> None:
        if not c >= 0:
            raise ValueError(f"discovery factor c must be >= 0, got {c}")
        self.problem = problem
        self.c = float(c)
        self.top = float(problem.all_send_norm()[-1])
        self.lam = rollout_threshold(problem)
        self.tree = Tree(max_nodes=max(2, max_nodes + 1), max_opt=problem.max_opt)
        self.plan = np.full(max(1, problem.n), -1, dtype=np.int64)
        """The knapsack-greedy plan (one option per level) with ``knapsack_seed``, else -1."""
        if knapsack_seed and problem.n:
            _kernel.knapsack_plan(problem.nopt, problem.size, problem.send_t, problem.gain,
                                  problem.root_win_t, problem.root_win_bytes,
                                  float(problem.budget_bytes), float(problem.window_s),
                                  self.plan)
        tight = False
        if dp_seed is not None and problem.n and not knapsack_seed:  # one seed: knapsack's wins
            if dp_seed < 1:
                raise ValueError(f"dp_seed (beam width) must be >= 1, got {dp_seed}")
            self.plan[: problem.n] = _beam.plan_of(problem, dp_seed, price=self.lam,
                                                   mix=_beam.PRICED_SHARE)[0]
            ahead = self.plan[max(0, problem.decided_level) : problem.n]
            tight = len(ahead) > 0 and float(np.mean(ahead == 0)) >= DP_TIGHT
        self.best_plan = best_plan or knapsack_seed or tight
        """Answer with the best complete plan evaluated (else the most visited path)."""
        self.depth_limit = problem.n if depth is None else \
            min(problem.n, max(0, problem.decided_level) + 1 + max(0, depth))
        """Tree levels searched: the decided one and ``depth`` after it; below, the default
        policy alone."""
        self.best = np.full(1, -np.inf)
        """Utility of the best complete plan any iteration evaluated."""
        self.best_at = np.full(1, -1, dtype=np.int64)
        """That plan's option at the decided level (-1: none yet)."""
        if veto is not None and not veto > 0:
            raise ValueError(f"veto must be > 0 or None, got {veto}")
        self.veto = veto
        self.robust = MCTS(problem, c=c, max_nodes=max_nodes) if veto is not None else None
        """The unbounded, most visited tree whose statistics may veto a send (``veto``)."""

    @property
    def iterations(self) -> int:
        return int(self.tree.counters[_kernel.C_ITER])

    @property
    def exhausted(self) -> bool:
        return bool(self.tree.dead[0]) or self.problem.n == 0

    def run(self, iterations: int) -> int:
        """Run up to ``iterations`` more iterations (anytime: call again to continue)."""
        p, t = self.problem, self.tree
        if iterations <= 0 or p.n == 0:
            return 0
        if self.robust is not None:
            self.robust.run(iterations)
        with np.errstate(over="ignore"):
            return int(
                _kernel.search(
                    int(iterations), self.c,
                    p.stream, p.pos, p.nopt, p.size, p.send_t, p.gain, p.nslot, p.stream_markov,
                    p.root_win_t, p.root_win_bytes, float(p.budget_bytes), float(p.window_s),
                    int(p.max_versions), self.top, self.lam,
                    self.plan, int(p.decided_level), self.best, self.best_at,
                    int(self.depth_limit),
                    t.parent, t.depth, t.option, t.visits, t.value, t.delta,
                    t.children, t.tried, t.live, t.dead, t.hkeys, t.hvals, t.counters,
                )
            )

    def best_child(self, node: int) -> int | None:
        """Most visited live child; ties: higher mean score, then send before drop."""
        nopt = int(self.problem.nopt[int(self.tree.depth[node])])
        order = [*range(1, nopt), 0]
        best: tuple[int, float, int] | None = None
        best_node: int | None = None
        for rank, o in enumerate(order):
            ch = int(self.tree.children[node, o])
            if ch < 0 or self.tree.dead[ch]:
                continue
            cand = (int(self.tree.visits[ch]), self.tree.mean(ch), -rank)
            if best is None or cand > best:
                best, best_node = cand, ch
        return best_node

    def _vetoed(self, option: int) -> bool:
        """The unbounded tree's most visited path reaches the decided level and there its
        drop child has more than ``veto`` times the visits of ``option``'s child."""
        robust = self.robust
        assert robust is not None and self.veto is not None
        level = self.problem.decided_level
        path = robust.most_visited_path()
        if not 0 <= level < len(path):
            return False
        t = robust.tree
        node = int(t.parent[path[level]])

        def visits(o: int) -> int:
            ch = int(t.children[node, o])
            return int(t.visits[ch]) if ch >= 0 and not t.dead[ch] else 0

        return visits(0) > self.veto * visits(option)

    def most_visited_path(self) -> list[int]:
        """Nodes from the root's child down, following the most visited child (alg. 2)."""
        path: list[int] = []
        node = 0
        while int(self.tree.depth[node]) < self.problem.n:
            child = self.best_child(node)
            if child is None:
                break
            path.append(child)
            node = child
        return path

    @property
    def seeded(self) -> bool:
        return bool(self.plan[0] >= 0)

    def result(self) -> SearchResult:
        """Seeded: the decided level's option of the best complete plan evaluated (the model is
        deterministic, so the best plan seen is the answer and more iterations can only raise
        its utility); else the most visited path's (alg. 2)."""
        t = self.tree
        path = self.most_visited_path()
        level = self.problem.decided_level
        option: int | None = None
        score = float("nan")
        visits = 0
        if self.best_plan and self.best_at[0] >= 0:
            option = int(self.best_at[0])
            score = float(self.best[0]) / self.top if self.top > 1e-9 else 1.0
            if 0 <= level < len(path) and int(t.option[path[level]]) == option:
                visits = int(t.visits[path[level]])
        elif 0 <= level < len(path):
            chosen = path[level]
            option = int(t.option[chosen])
            score = t.mean(chosen)
            visits = int(t.visits[chosen])
        if option and self.robust is not None and self._vetoed(option):
            option, score, visits = 0, float("nan"), 0
        return SearchResult(
            option=option,
            score=score,
            visits=visits,
            path=tuple(int(t.option[n]) for n in path),
            iterations=self.iterations,
            nodes=t.n_nodes,
            pruned=int(t.counters[_kernel.C_PRUNED]),
            merged=int(t.counters[_kernel.C_MERGED]),
            replaced=int(t.counters[_kernel.C_REPLACED]),
            exhausted=self.exhausted,
        )


def rollout_threshold(problem: Problem, *, chain: bool = False) -> float:
    """Utility per byte the default policy asks for: the density at which the items of the
    horizon, densest first, fill the window budget over the horizon's span.

    Items are valued after their stream's base (what each adds alone). With ``chain`` an item
    is valued after the previous item of its stream instead (what it adds when the stream is
    sent densely). Measured: chain helps on short 4-agent missions (94.6 against 94.0 % of
    the offline optimum) and hurts the 10-agent mostly-low scenario (e.g. 83.9 against
    87.9 % at 83 % drops), so the default is off.
    """
    n = problem.n
    if n == 0:
        return 0.0
    slot = np.zeros(n, dtype=np.int64)
    if chain:
        later = (problem.stream >= 0) & (problem.pos > 0)
        slot[later] = 1 + (problem.pos[later] - 1) * problem.max_versions
    opts = np.arange(1, problem.size.shape[1])
    gains = problem.gain[np.arange(n)[:, None], opts[None, :], slot[:, None]]
    per_byte = gains / np.maximum(1, problem.size[:, 1:])
    per_byte[opts[None, :] >= problem.nopt[:, None]] = 0.0
    density = np.maximum(per_byte.max(axis=1), 0.0)
    first = np.maximum(1, problem.size[:, 1])
    span = float(problem.send_t[-1] - problem.send_t[0])
    capacity = problem.budget_bytes * max(1.0, span / problem.window_s)
    order = np.lexsort((first, density))[::-1]  # densest first; ties: larger first
    over = np.nonzero(np.cumsum(first[order], dtype=np.float64) > capacity)[0]
    return float(density[order[over[0]]]) if len(over) else 0.0


def greedy_option(problem: Problem, level: int) -> int:
    """The fallback rule: the option with the highest gain that fits the window, else drop.

    Earlier levels are taken as dropped (they are other agents' in-flight messages).
    """
    if not 0 <= level < problem.n:
        raise ValueError(f"level {level} outside 0..{problem.n - 1}")
    lo = float(problem.send_t[level]) - problem.window_s
    used = sum(
        int(b) for t, b in zip(problem.root_win_t, problem.root_win_bytes, strict=True) if t >= lo
    )
    best_o, best_g = 0, 0.0
    for o in range(1, int(problem.nopt[level])):
        if used + int(problem.size[level, o]) > problem.budget_bytes + 1e-9:
            continue
        g = float(problem.gain[level, o, 0])
        if g > best_g:
            best_o, best_g = o, g
    return best_o
