"""A beam dynamic programme over one decision's :class:`Problem`, compiled by numba when present.

The search's default policy values a node by a greedy rollout. At tight budgets that rollout
uses the room a drop frees badly, so the drop child's mean trails the send child's although
the drop leads to the better plan (issue 18, round 13: 7 of 16 sends in one fig. 5.7 run were
drops in the exact optimum of the same decision). The exact optimum
(:func:`~companion.middleware.baselines.offline_optimum`) merges tantamount states, each
stream's last sent message plus the sends still inside the next window (eq. 5.8,
footnote 5), and keeps the best utility per state; this is the same programme keeping only
``width`` states of each level, so its cost is bounded: levels x width x options. With a
width above the number of distinct states it is exact.

Which states a full beam keeps matters at tight budgets: a state that has sent more has more
utility and less room, so keeping the highest utilities keeps the senders and loses the
plans that leave room for a heavier message later (round 14). With a ``price`` (utility per
byte of a window) most of the width is ranked by utility minus the budget the state's sends
still hold, the rest by utility alone (:data:`PRICED_SHARE`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from companion.middleware._kernel import _hash_find, _mix
from utility_specs.jit import jit as _jit

__all__ = ["beam_plan", "canonical_slots", "plan_of"]

_EPS = 1e-9

PRICED_SHARE = 0.75
"""With a ``price``: the share of the beam kept by utility minus the priced budget its sends
still hold; the rest by utility alone. Measured against width 2048 unpriced on the decisions
of one mission each (issue 18, round 14), mean gap of width 128: uniform 9.25 msgs/T 1.62 %
unpriced, 0.03 % all priced, −0.17 % at 0.75; mostly-high 5.5 0.33 / 1.48 / 0.29 %; the
companion's image problems 2.7 / 26.0 / −4.1 %."""


@_jit
def _slot_key(last: Any, n_streams: int) -> Any:
    key = np.uint64(0)
    for s in range(n_streams):
        key = key ^ _mix(1, s * 1048576 + last[s])
    return key


@_jit
def _moved(s: int, slot: int, new_slot: int) -> Any:
    """The change of a state's slot key when stream ``s`` moves from ``slot`` to ``new_slot``."""
    if new_slot == slot:
        return np.uint64(0)
    return _mix(1, s * 1048576 + slot) ^ _mix(1, s * 1048576 + new_slot)


@_jit
def _best(value: Any, cc: int, width: int) -> Any:
    """The indices of the ``width`` largest of ``value[:cc]``, best first, ties in index
    order (a stable sort's first ``width``), sorting only those."""
    if cc <= width:
        return np.arange(cc)
    neg = -value[:cc]
    cut = np.partition(neg, width - 1)[width - 1]
    chosen = np.empty(width, dtype=np.int64)
    r = 0
    for t in range(cc):
        if neg[t] < cut:
            chosen[r] = t
            r += 1
    for t in range(cc):
        if r == width:
            break
        if neg[t] == cut:
            chosen[r] = t
            r += 1
    return chosen[np.argsort(neg[chosen], kind="mergesort")]


@_jit
def _best_of_two(value: Any, rank: Any, cc: int, width: int, k: int) -> Any:
    """The ``k`` best of ``rank[:cc]``, then the ``width - k`` best of ``value`` among the
    rest (0 < k < width < cc)."""
    first = _best(rank, cc, k)
    rest = value[:cc].copy()
    for t in first:
        rest[t] = -np.inf
    second = _best(rest, cc, width - k)
    return np.concatenate((first, second))


@_jit
def beam_plan(
    stream: Any, nopt: Any, size: Any, send_t: Any, gain: Any, nslot: Any, canon: Any,
    root_win_t: Any, root_win_b: Any, budget: float, window_s: float, n_streams: int,
    width: int, plan: Any, force_level: int, force_send: bool, price: float, mix: float,
) -> float:
    """Write into ``plan`` the best plan the beam keeps (one option per level); return its
    utility (-inf: no plan). ``canon[i, slot]``: the slot with the same future as ``slot``
    after level i. At ``force_level`` (-1: none) only sends, or only the drop, are tried.
    With ``price`` > 0 the share ``mix`` of the width is kept by the priced rank."""
    n = stream.shape[0]
    max_opt = size.shape[1]
    cap_w = n + 1
    ns = max(n_streams, 1)
    m = width * max_opt
    # The fleet's fixed sends are the same in every state: their bytes in the window of each
    # level are one number per level, and they need no place in a state's key.
    root_used = np.zeros(max(n, 1), dtype=np.int64)
    for i in range(n):
        for k in range(root_win_t.shape[0]):
            if root_win_t[k] >= send_t[i] - window_s - _EPS:
                root_used[i] += root_win_b[k]
    # The states of two layers, [0] and [1]: the current one (``cur``) and the next, built
    # from the survivors only. A state's own sends still in the window, oldest first: their
    # times, bytes and key terms, with running totals of their bytes, bytes x times and keys.
    last = np.zeros((2, width, ns), dtype=np.int64)
    wt = np.zeros((2, width, cap_w), dtype=np.float64)
    wb = np.zeros((2, width, cap_w), dtype=np.int64)
    wk = np.zeros((2, width, cap_w), dtype=np.uint64)
    wn = np.zeros((2, width), dtype=np.int64)
    wsum = np.zeros((2, width), dtype=np.int64)
    wtsum = np.zeros((2, width), dtype=np.float64)
    wkey = np.zeros((2, width), dtype=np.uint64)
    u = np.zeros((2, width), dtype=np.float64)
    skey = np.zeros((2, width), dtype=np.uint64)  # key of each state's last slots, kept by XOR
    cur = 0
    count = 1
    # per state of this level: where its sends still in the next window start, and what
    # leaves (bytes, key, bytes x times) before it
    keep = np.zeros(width, dtype=np.int64)
    gone_b = np.zeros(width, dtype=np.int64)
    gone_k = np.zeros(width, dtype=np.uint64)
    gone_t = np.zeros(width, dtype=np.float64)
    # the candidates: a parent state and an option each, materialised if they survive
    c_u = np.zeros(m, dtype=np.float64)
    c_rank = np.zeros(m, dtype=np.float64)  # utility minus the priced budget held
    c_par = np.zeros(m, dtype=np.int64)
    c_opt = np.zeros(m, dtype=np.int64)
    c_slot = np.zeros(m, dtype=np.int64)  # each candidate's entry in the hash table
    cc = 0
    size_h = 1
    while size_h < 4 * m:
        size_h *= 2
    hkeys = np.zeros(size_h, dtype=np.uint64)
    hvals = np.full(size_h, -1, dtype=np.int64)
    back_par = np.zeros((max(n, 1), width), dtype=np.int64)
    back_opt = np.zeros((max(n, 1), width), dtype=np.int64)
    skey[cur, 0] = _slot_key(last[cur, 0], n_streams)
    priced = min(width, int(mix * width + 0.5)) if price > 0.0 else 0  # kept by the price
    for i in range(n):
        t_next = send_t[i + 1] if i + 1 < n else np.inf
        lo_next = t_next - window_s - _EPS
        s = stream[i]
        sent_inside = send_t[i] >= lo_next  # a send at level i is still in the next window
        for t in range(cc):  # empty the hash table: only the previous level's entries
            hvals[c_slot[t]] = -1
        cc = 0
        for j in range(count):
            # every own send of the window is inside level i's (they are after lo_i)
            used = root_used[i] + wsum[cur, j]
            f = 0
            gb = 0
            gk = np.uint64(0)
            gt = 0.0
            while f < wn[cur, j] and wt[cur, j, f] < lo_next:
                gb += wb[cur, j, f]
                gk = gk ^ wk[cur, j, f]
                gt += wb[cur, j, f] * wt[cur, j, f]
                f += 1
            keep[j] = f
            gone_b[j] = gb
            gone_k[j] = gk
            gone_t[j] = gt
            # the budget state j's sends still hold at the next level, priced: byte-seconds
            # of the window T to come, at ``price`` per byte of a whole window
            held = 0.0
            if price > 0.0 and i + 1 < n:
                held = price * ((wtsum[cur, j] - gt)
                                + (wsum[cur, j] - gb) * (window_s - t_next)) / window_s
            win_key = skey[cur, j] ^ wkey[cur, j] ^ gk ^ _mix(4, i + 1)  # every option's
            slot = last[cur, j, s] if s >= 0 else 0
            for o in range(nopt[i]):
                if i == force_level and (o != 0) != force_send:
                    continue
                g = 0.0
                if o != 0:
                    if used + size[i, o] > budget + _EPS:
                        continue
                    g = gain[i, o, slot]
                key = win_key
                if s >= 0:
                    key = key ^ _moved(s, slot, canon[i, nslot[i, o, slot] if o != 0 else slot])
                rank = u[cur, j] + g - held
                if o != 0 and sent_inside:
                    key = key ^ _mix(3, 16 * i + o)
                    rank -= price * size[i, o] * (send_t[i] + window_s - t_next) / window_s
                value = u[cur, j] + g
                # tantamount states (same key) keep the better utility
                h = _hash_find(key, hkeys, hvals)
                if h >= 0:
                    t = hvals[h]
                    if value <= c_u[t] + _EPS * (1.0 + abs(c_u[t])):
                        continue
                else:
                    t = cc
                    cc += 1
                    hkeys[-1 - h] = key
                    hvals[-1 - h] = t
                    c_slot[t] = -1 - h
                c_u[t] = value
                c_rank[t] = rank
                c_par[t] = j
                c_opt[t] = o
        if cc == 0:  # only a forced send, and it fits no state
            return -np.inf
        # the beam: the ``width`` best states go on (all of them while they fit)
        if priced == 0 or cc <= width:
            order = _best(c_u, cc, width)
        elif priced == width:
            order = _best(c_rank, cc, width)
        else:
            order = _best_of_two(c_u, c_rank, cc, width, priced)
        nxt = 1 - cur
        count = order.shape[0]
        for r in range(count):
            t = order[r]
            j = c_par[t]
            o = c_opt[t]
            u[nxt, r] = c_u[t]
            back_par[i, r] = j
            back_opt[i, r] = o
            for q in range(ns):
                last[nxt, r, q] = last[cur, j, q]
            skey[nxt, r] = skey[cur, j]
            if s >= 0:
                slot = last[cur, j, s]
                new_slot = canon[i, nslot[i, o, slot] if o != 0 else slot]
                last[nxt, r, s] = new_slot
                skey[nxt, r] ^= _moved(s, slot, new_slot)
            e = 0
            for k in range(keep[j], wn[cur, j]):
                wt[nxt, r, e] = wt[cur, j, k]
                wb[nxt, r, e] = wb[cur, j, k]
                wk[nxt, r, e] = wk[cur, j, k]
                e += 1
            wsum[nxt, r] = wsum[cur, j] - gone_b[j]
            wtsum[nxt, r] = wtsum[cur, j] - gone_t[j]
            wkey[nxt, r] = wkey[cur, j] ^ gone_k[j]
            if o != 0 and sent_inside:
                wt[nxt, r, e] = send_t[i]
                wb[nxt, r, e] = size[i, o]
                wk[nxt, r, e] = _mix(3, 16 * i + o)
                wsum[nxt, r] += size[i, o]
                wtsum[nxt, r] += size[i, o] * send_t[i]
                wkey[nxt, r] ^= wk[nxt, r, e]
                e += 1
            wn[nxt, r] = e
        cur = nxt
    best = 0
    for r in range(count):
        if u[cur, r] > u[cur, best]:
            best = r
    j = best
    for i in range(n - 1, -1, -1):
        plan[i] = back_opt[i, j]
        j = back_par[i, j]
    return u[cur, best] if n > 0 else 0.0


@_jit
def _canonical(stream: Any, gain_bits: Any, nslot: Any, n_streams: int, out: Any) -> None:
    """``out[i, x]``: the smallest slot whose future after level i is the same as slot x's
    (identical gains and transitions for every later item of the stream), from a hash of
    those futures built backwards, one level at a time."""
    n, max_opt, n_slots = gain_bits.shape
    sig = np.zeros((max(n_streams, 1), n_slots), dtype=np.uint64)
    for i in range(n - 1, -1, -1):
        s = stream[i]
        if s < 0:
            for x in range(n_slots):
                out[i, x] = x
            continue
        for x in range(n_slots):
            out[i, x] = x
            for y in range(x):
                if sig[s, y] == sig[s, x]:
                    out[i, x] = y
                    break
        for x in range(n_slots):
            h = sig[s, x]
            for o in range(max_opt):
                h = (h ^ gain_bits[i, o, x]) * np.uint64(0x9E3779B97F4A7C15)
                h = h ^ _mix(5 + o, 1 if nslot[i, o, x] == x else 0)
            sig[s, x] = h


def canonical_slots(problem: Any) -> Any:
    """Per level i, each slot of item i's stream mapped to the smallest slot with the same
    future (identical gains and transitions for every later item of the stream), as an array
    [level, slot]: messages whose utility has run out before the remaining items arrive all
    become one state (used by this beam and by ``baselines.offline_optimum``)."""
    out = np.empty((max(problem.n, 1), problem.gain.shape[2]), dtype=np.int64)
    if problem.n:
        bits = np.ascontiguousarray(problem.gain).view(np.uint64)
        _canonical(problem.stream, bits, problem.nslot, int(problem.n_streams), out)
    return out


def plan_of(problem: Any, width: int, *, force_level: int = -1,
            force_send: bool = False, price: float = 0.0, mix: float = 1.0
            ) -> tuple[Any, float]:
    """(the beam's plan, one option per level; its utility in the model, -inf if none).
    ``price``: utility per byte of a window the budget held by a state's sends is worth
    (0: states kept by utility alone); ``mix``: the share of the width kept by that rank."""
    plan = np.zeros(max(problem.n, 1), dtype=np.int64)
    if problem.n == 0:
        return plan[:0], 0.0
    u = beam_plan(problem.stream, problem.nopt, problem.size, problem.send_t, problem.gain,
                  problem.nslot, canonical_slots(problem), problem.root_win_t,
                  problem.root_win_bytes, float(problem.budget_bytes), float(problem.window_s),
                  int(problem.n_streams), int(width), plan, int(force_level), bool(force_send),
                  float(price), float(mix))
    return plan, float(u)
