"""The MCTS inner loop (algorithms 1 and 3) on flat arrays, compiled by numba when present.

Everything the loop touches is an array of the :class:`~companion.middleware.mcts.Tree` or of
the :class:`~companion.middleware.incremental.Problem`; nodes are integer indices. The path
state (each stream's last sent message, the sends inside the goodput window, the Zobrist key
of the state) is rebuilt while descending from the root, O(1) per level, so no node stores a
copy of it. Without numba the same code runs as plain Python (about 100 times slower).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from utility_specs.jit import JIT
from utility_specs.jit import jit as _jit

__all__ = [
    "C_DEAD",
    "C_ITER",
    "C_MERGED",
    "C_NODES",
    "C_PRUNED",
    "C_REPLACED",
    "JIT",
    "NO_CHILD",
    "REJ_MERGED",
    "REJ_PRUNED",
    "knapsack_plan",
    "search",
]

NO_CHILD = -1
REJ_PRUNED = -2
"""The child would break the goodput window constraint (eq. 5.5): pruned with its subtree."""
REJ_MERGED = -3
"""The child is tantamount to a better node on its level (eq. 5.8/5.9): merged away."""
REJ_DEAD = -4
"""The child was replaced by a better tantamount node, or has no live descendants."""

C_NODES, C_ITER, C_PRUNED, C_MERGED, C_REPLACED, C_DEAD = 0, 1, 2, 3, 4, 5

_EPS = 1e-9


@_jit
def _mix(tag: int, value: int) -> Any:
    """splitmix64 of (tag, value): Zobrist keys without a random table."""
    z = np.uint64(tag) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(value)
    z = z + np.uint64(0x632BE59BD9B4E019)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@_jit
def _score(u: float, top: float) -> float:
    """Node score S(v) in [0, 1] (eq. 5.2, normalised as explained in mcts.py)."""
    if top <= _EPS:
        return 1.0
    s = u / top
    if s < 0.0:
        return 0.0
    if s > 1.0:
        return 1.0
    return s


@_jit
def _rollout(
    d0: int, last: Any, r_last: Any, win_t: Any, win_b: Any, head: int, tail: int, wbytes: int,
    stream: Any, pos: Any, nopt: Any, size: Any, send_t: Any, gain: Any, nslot: Any,
    budget: float,
    window_s: float, maxv: int, lam: float, r_win_t: Any, r_win_b: Any,
    plan: Any, dlevel: int, pick: Any, force: Any,
) -> float:
    """Default policy from level ``d0`` on (the simulation step of alg. 1): send the option
    with the highest gain whose utility per byte reaches ``lam`` and that fits the window.

    With ``plan[0] >= 0`` it follows the knapsack plan instead (level i's option ``plan[i]``
    when it fits the window, else drop). ``pick[0]`` gets the option taken at ``dlevel``.
    A level with ``force[i] >= 0`` (another agent's announced plan, ``agreed.py``) takes that
    option when it fits the window, else drop."""
    n = stream.shape[0]
    for s in range(last.shape[0]):
        r_last[s] = last[s]
    h = 0
    t_ = 0
    for k in range(head, tail):
        r_win_t[t_] = win_t[k]
        r_win_b[t_] = win_b[k]
        t_ += 1
    total = 0.0
    for i in range(d0, n):
        lim = send_t[i] - window_s - _EPS
        while h < t_ and r_win_t[h] < lim:
            wbytes -= r_win_b[h]
            h += 1
        s = stream[i]
        slot = r_last[s] if s >= 0 else 0
        best_o = 0
        best_g = 0.0
        if force[i] >= 0:
            o = force[i]
            if o > 0 and wbytes + size[i, o] <= budget + _EPS:
                best_o = o
                best_g = gain[i, o, slot]
        elif plan[0] >= 0:
            o = plan[i]
            if o > 0 and wbytes + size[i, o] <= budget + _EPS:
                best_o = o
                best_g = gain[i, o, slot]
        else:
            for o in range(1, nopt[i]):
                sz = size[i, o]
                g = gain[i, o, slot]
                if g <= best_g or g < lam * sz or wbytes + sz > budget + _EPS:
                    continue
                best_o = o
                best_g = g
        if i == dlevel:
            pick[0] = best_o
        if best_o != 0:
            total += best_g
            r_win_t[t_] = send_t[i]
            r_win_b[t_] = size[i, best_o]
            t_ += 1
            wbytes += size[i, best_o]
            if s >= 0:
                r_last[s] = nslot[i, best_o, slot]
    return total


@_jit
def _backprop(node: int, score: float, parent: Any, visits: Any, value: Any) -> None:
    while node >= 0:
        visits[node] += 1
        value[node] += score
        node = parent[node]


@_jit
def _kill(node: int, parent: Any, option: Any, children: Any, tried: Any, nopt: Any,
          depth: Any, live: Any, dead: Any, counters: Any) -> None:
    """Mark ``node`` dead and every ancestor left without a live child."""
    while node >= 0 and not dead[node]:
        dead[node] = True
        counters[C_DEAD] += 1
        p = parent[node]
        if p < 0:
            return
        live[p] -= 1
        children[p, option[node]] = REJ_DEAD
        if live[p] > 0 or tried[p] < nopt[depth[p]]:
            return
        node = p


@_jit
def _abs_utility(node: int, parent: Any, delta: Any) -> float:
    u = 0.0
    while node >= 0:
        u += delta[node]
        node = parent[node]
    return u


@_jit
def _hash_find(key: Any, hkeys: Any, hvals: Any) -> Any:
    mask = hkeys.shape[0] - 1
    h = np.int64(key & np.uint64(mask))
    while hvals[h] != -1:
        if hkeys[h] == key:
            return h
        h = (h + 1) & mask
    return -1 - h  # free slot, encoded


@_jit
def knapsack_plan(
    nopt: Any, size: Any, send_t: Any, gain: Any, root_win_t: Any, root_win_b: Any,
    budget: float, window_s: float, plan: Any,
) -> None:
    """Write into ``plan`` the knapsack-greedy baseline's option for every level, each level
    decided in turn like :class:`~companion.middleware.baselines.KnapsackGreedy` does: the
    level's densest version is sent when it makes the utility-per-byte cut among the later
    items of the next window T, in the room the window (root sends and the plan's earlier
    sends) leaves. The search starts from this plan, so it can only improve on it."""
    n = nopt.shape[0]
    dens = np.zeros(n, dtype=np.float64)
    best = np.zeros(n, dtype=np.int64)
    for i in range(n):
        for o in range(1, nopt[i]):
            d = gain[i, o, 0] / max(1, size[i, o])
            if d > 0.0 and d >= dens[i]:
                dens[i] = d
                best[i] = o
    order = np.argsort(-dens, kind="mergesort")
    for i in range(n):
        plan[i] = 0
        if best[i] == 0:
            continue
        lo = send_t[i] - window_s - _EPS
        used = 0
        for k in range(root_win_t.shape[0]):
            if root_win_t[k] >= lo:
                used += root_win_b[k]
        for j in range(i):
            if plan[j] > 0 and send_t[j] >= lo:
                used += size[j, plan[j]]
        room = budget - used
        hi = send_t[i] + window_s
        for j in order:
            if j == i:
                if size[i, best[i]] <= room + _EPS:
                    plan[i] = best[i]
                break
            if send_t[j] < send_t[i] or send_t[j] > hi or dens[j] <= dens[i]:
                continue
            sz = size[j, best[j]]
            if sz <= room + _EPS:
                room -= sz


@_jit
def _option_at(t: int, first: int, n_opt: int) -> int:
    """The t-th option to expand: ``first`` (when >= 0), then versions best first, drop last."""
    if first >= 0:
        if t == 0:
            return first
        k = t - 1
        if k >= (first - 1 if first > 0 else n_opt - 1):
            k += 1
        t = k
    return t + 1 if t < n_opt - 1 else 0


@_jit
def _option_on_path(node: int, level: int, parent: Any, depth: Any, option: Any) -> int:
    """Option taken at ``level`` on the path from the root to ``node`` (depth > level)."""
    while depth[node] > level + 1:
        node = parent[node]
    return int(option[node])


@_jit
def search(
    n_iter: int,
    c: float,
    # problem
    stream: Any, pos: Any, nopt: Any, size: Any, send_t: Any, gain: Any, nslot: Any,
    markov: Any,
    root_win_t: Any, root_win_b: Any, budget: float, window_s: float, maxv: int, top: float,
    lam: float, plan: Any, dlevel: int, best_u: Any, best_at: Any, depth_limit: int,
    force: Any, force_tree: bool,
    # tree
    parent: Any, depth: Any, option: Any, visits: Any, value: Any, delta: Any,
    children: Any, tried: Any, live: Any, dead: Any, hkeys: Any, hvals: Any, counters: Any,
) -> int:
    """Run up to ``n_iter`` MCTS iterations; return how many ran (fewer: tree exhausted).

    With a knapsack ``plan`` (``plan[0] >= 0``) its option is expanded first at every node and
    a leaf is valued by the better of the two default policies (greedy above ``lam``, the
    plan). Either way ``best_u[0]`` keeps the best complete plan's utility seen so far and
    ``best_at[0]`` its option at ``dlevel`` (-1: none yet).

    Nodes at depth ``depth_limit`` (< n) are leaves: valued by the default policy from there
    on every visit, never expanded; a budget that covers the bounded tree then answers the
    same for every larger budget.

    ``force`` (one entry per level, -1: free) fixes levels to another agent's announced
    option (``agreed.py``): in the default policy always, and with ``force_tree`` in the tree
    too, where such a level gets the one child (drop only when the option does not fit) and
    the descent goes on through it in the same iteration."""
    n = stream.shape[0]
    n_streams = markov.shape[0]
    n_root = root_win_t.shape[0]
    cap = n_root + n + 1
    last = np.zeros(max(n_streams, 1), dtype=np.int64)
    win_t = np.zeros(cap, dtype=np.float64)
    win_b = np.zeros(cap, dtype=np.int64)
    win_id = np.zeros(cap, dtype=np.int64)
    r_last = np.zeros(max(n_streams, 1), dtype=np.int64)
    r_win_t = np.zeros(cap, dtype=np.float64)
    r_win_b = np.zeros(cap, dtype=np.int64)
    noplan = np.full(1, -1, dtype=np.int64)
    pick = np.zeros(1, dtype=np.int64)
    pick2 = np.zeros(1, dtype=np.int64)
    seeded = plan[0] >= 0
    max_nodes = parent.shape[0]
    done = 0
    for _ in range(n_iter):
        if dead[0] or counters[C_NODES] >= max_nodes:
            break
        done += 1
        counters[C_ITER] += 1
        for s in range(n_streams):
            last[s] = 0
        head = 0
        tail = n_root
        wbytes = 0
        for k in range(n_root):
            win_t[k] = root_win_t[k]
            win_b[k] = root_win_b[k]
            win_id[k] = 16 * (n + k)
            wbytes += root_win_b[k]
        key = np.uint64(0)
        u = 0.0
        node = 0
        while True:
            d = depth[node]
            full_tree = d < n and tried[node] < nopt[d] and counters[C_NODES] >= max_nodes
            if d == n or d >= depth_limit or full_tree:
                total = u
                if d < n:
                    if full_tree:  # fixed levels descended: no room left to expand
                        lim = send_t[d] - window_s - _EPS
                        while head < tail and win_t[head] < lim:
                            wbytes -= win_b[head]
                            head += 1
                    pick[0] = -1
                    total += _rollout(d, last, r_last, win_t, win_b, head, tail, wbytes, stream,
                                      pos, nopt, size, send_t, gain, nslot, budget, window_s,
                                      maxv, lam, r_win_t, r_win_b, noplan, dlevel, pick, force)
                if total > best_u[0]:
                    best_u[0] = total
                    best_at[0] = _option_on_path(node, dlevel, parent, depth, option) \
                        if d > dlevel else pick[0]
                _backprop(node, _score(total, top), parent, visits, value)
                break
            lim = send_t[d] - window_s - _EPS
            while head < tail and win_t[head] < lim:
                wbytes -= win_b[head]
                head += 1
            s = stream[d]
            fixed = force_tree and force[d] >= 0
            if tried[node] < nopt[d]:
                created = -1
                cu = u
                while tried[node] < nopt[d]:
                    t = tried[node]
                    tried[node] += 1
                    o = _option_at(t, plan[d] if seeded else -1, nopt[d])
                    sz = size[d, o]
                    if fixed:
                        f = force[d]
                        if o != f and (o != 0 or f == 0
                                       or wbytes + size[d, f] <= budget + _EPS):
                            continue
                    if o != 0 and wbytes + sz > budget + _EPS:
                        children[node, o] = REJ_PRUNED
                        counters[C_PRUNED] += 1
                        continue
                    g = 0.0
                    ckey = key
                    if o != 0:
                        if s >= 0:
                            old = last[s]
                            new = nslot[d, o, old]
                            g = gain[d, o, old]
                            ckey = ckey ^ _mix(1, s * 1048576 + old) ^ _mix(1, s * 1048576 + new)
                            if not markov[s]:
                                ckey = ckey ^ _mix(2, d * 16 + o)
                        else:
                            g = gain[d, o, 0]
                            ckey = ckey ^ _mix(2, d * 16 + o)
                    full = ckey ^ _mix(4, d + 1)
                    if d + 1 < n:
                        nlim = send_t[d + 1] - window_s - _EPS
                        for k in range(head, tail):
                            if win_t[k] >= nlim:
                                full = full ^ _mix(3, win_id[k])
                        if o != 0 and send_t[d] >= nlim:
                            full = full ^ _mix(3, 16 * d + o)
                    cu = u + g
                    h = _hash_find(full, hkeys, hvals)
                    rival = hvals[h] if h >= 0 else -1
                    if rival >= 0 and dead[rival]:
                        rival = -1
                    if rival >= 0:
                        ru = _abs_utility(rival, parent, delta)
                        if cu <= ru + _EPS * (1.0 + abs(ru)):
                            children[node, o] = REJ_MERGED
                            counters[C_MERGED] += 1
                            continue
                    cn = counters[C_NODES]
                    counters[C_NODES] += 1
                    parent[cn] = node
                    depth[cn] = d + 1
                    option[cn] = o
                    delta[cn] = g
                    children[node, o] = cn
                    live[node] += 1
                    if rival >= 0:
                        # The new node is better: it takes over the rival's subtree (same state,
                        # so the same future) and statistics; the rival is removed.
                        counters[C_MERGED] += 1
                        counters[C_REPLACED] += 1
                        for oo in range(children.shape[1]):
                            ch = children[rival, oo]
                            children[cn, oo] = ch
                            if ch >= 0:
                                parent[ch] = cn
                            children[rival, oo] = NO_CHILD
                        tried[cn] = tried[rival]
                        live[cn] = live[rival]
                        live[rival] = 0
                        visits[cn] = visits[rival]
                        value[cn] = value[rival]
                        hvals[h] = cn
                        _kill(rival, parent, option, children, tried, nopt, depth, live, dead,
                              counters)
                    else:
                        hk = -1 - h
                        hkeys[hk] = full
                        hvals[hk] = cn
                    created = cn
                    break
                if created >= 0 and fixed:
                    continue  # one child: descend through it (selection picks it)
                if created >= 0:
                    # the child's state: apply its decision to copies of the path state
                    o = option[created]
                    rt = tail
                    rw = wbytes
                    if o != 0:
                        win_t[rt] = send_t[d]
                        win_b[rt] = size[d, o]
                        rt += 1
                        rw += size[d, o]
                    old = last[s] if s >= 0 else 0
                    if o != 0 and s >= 0:
                        last[s] = nslot[d, o, old]
                    pick[0] = -1
                    rest = _rollout(d + 1, last, r_last, win_t, win_b, head, rt, rw, stream, pos,
                                    nopt, size, send_t, gain, nslot, budget, window_s, maxv, lam,
                                    r_win_t, r_win_b, noplan, dlevel, pick, force)
                    if seeded:
                        pick2[0] = -1
                        rest2 = _rollout(d + 1, last, r_last, win_t, win_b, head, rt, rw, stream,
                                         pos, nopt, size, send_t, gain, nslot, budget, window_s,
                                         maxv, lam, r_win_t, r_win_b, plan, dlevel, pick2,
                                         force)
                        if rest2 > rest:
                            rest = rest2
                            pick[0] = pick2[0]
                    if s >= 0:
                        last[s] = old
                    if cu + rest > best_u[0]:
                        best_u[0] = cu + rest
                        if d >= dlevel:
                            best_at[0] = _option_on_path(created, dlevel, parent, depth, option)
                        else:
                            best_at[0] = pick[0]
                    _backprop(created, _score(cu + rest, top), parent, visits, value)
                    break
                if live[node] == 0:
                    _kill(node, parent, option, children, tried, nopt, depth, live, dead,
                          counters)
                    break
                continue
            # selection (eq. 5.3): highest UCT; ties go to the earlier option (send first)
            best = -1
            best_v = -1.0
            lnp = math.log(max(visits[node], 1))
            for t in range(nopt[d]):
                o = t + 1 if t < nopt[d] - 1 else 0
                ch = children[node, o]
                if ch < 0 or dead[ch]:
                    continue
                nv = visits[ch]
                if nv == 0:  # a fixed level's child, created this iteration
                    best = ch
                    break
                v = value[ch] / nv + c * math.sqrt(lnp / nv)
                if v > best_v:
                    best_v = v
                    best = ch
            if best < 0:
                _kill(node, parent, option, children, tried, nopt, depth, live, dead, counters)
                break
            o = option[best]
            if o != 0:
                win_t[tail] = send_t[d]
                win_b[tail] = size[d, o]
                win_id[tail] = 16 * d + o
                wbytes += size[d, o]
                tail += 1
                if s >= 0:
                    old = last[s]
                    new = nslot[d, o, old]
                    last[s] = new
                    key = key ^ _mix(1, s * 1048576 + old) ^ _mix(1, s * 1048576 + new)
                    if not markov[s]:
                        key = key ^ _mix(2, d * 16 + o)
                else:
                    key = key ^ _mix(2, d * 16 + o)
            u += delta[best]
            node = best
    return done
