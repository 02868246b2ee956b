"""Eq. 4.5 for a whole stream on flat arrays: the exact integral of the max envelope.

Every message of a stream has the same utility function, so its curves form one *family*:
a line ``max(0, a - b·(t - g))``, a step, or ``a·φ(t - g)`` for one shape φ. The sweep is
the one of :func:`utility_specs.evaluate._max` (receptions and replacements cut the mission
into pieces; on each piece the envelope switches leader at exact crossings, found by
regula falsi between the knots and critical points, where every difference is monotone),
written on floats and integers so that numba compiles it. The curve objects stay the general
path: a new utility function needs only its :class:`~utility_specs.curves.Curve` (value,
integral, knots, critical points) and works everywhere; :meth:`UtilityFunction.family` is the
opt-in to this kernel for the known kinds. Without numba the evaluator keeps to the curve
objects, which are faster than this code run as plain Python. Tests hold the two paths equal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from utility_specs.jit import JIT
from utility_specs.jit import jit as _jit

__all__ = [
    "CAPPED_LOG",
    "EXPONENTIAL",
    "JIT",
    "LINE",
    "QUADRATIC",
    "STEP",
    "Family",
    "envelope_pair_gains",
    "falsi_point",
    "falsi_update",
    "max_envelope_integral",
]

STEP, LINE, QUADRATIC, EXPONENTIAL, CAPPED_LOG = 0, 1, 2, 3, 4
"""Family kinds; the shape parameters ``p`` are (c,), (rate,) and (k, l, x_cap, x_zero)."""

_NEVER = math.inf
_MAX_SWITCHES = 1_000_000


@dataclass(frozen=True, slots=True)
class Family:
    """A stream's curves: the kind, the shared shape parameters and per-message a and b."""

    kind: int
    shape: tuple[float, ...]
    a: list[float]
    """Line: value at generation. Shapes and steps: the scale."""
    b: list[float]
    """Line: decrease per second. Unused (0) otherwise."""


@_jit
def _value(kind: int, p: NDArray[np.float64], g: float, a: float, b: float, t: float) -> float:
    x = t - g
    if kind == LINE:
        v = a - b * x
        return v if v > 0.0 else 0.0
    if kind == STEP:
        return a
    if kind == QUADRATIC:
        v = float(1.0 - p[0] * x * x)
        return a * v if v > 0.0 else 0.0
    if kind == EXPONENTIAL:
        return a * math.exp(-float(p[0]) * x)
    if x <= p[2]:
        return a
    if x >= p[3]:
        return 0.0
    return float(a * (p[1] - p[0] * math.log2(x)))


@_jit
def _expiry(kind: int, p: NDArray[np.float64], g: float, a: float, b: float) -> float:
    """From this time on the value is 0 for good."""
    if a <= 0.0:
        return g
    if kind == LINE:
        return g + a / b if b > 0.0 else math.inf
    if kind == QUADRATIC:
        return float(g + 1.0 / math.sqrt(p[0]))
    if kind == CAPPED_LOG:
        return float(g + p[3])
    return math.inf


@_jit
def _integral(
    kind: int, p: NDArray[np.float64], g: float, a: float, b: float, lo: float, hi: float
) -> float:
    hi = min(hi, _expiry(kind, p, g, a, b))
    if hi <= lo:
        return 0.0
    xa, xb = lo - g, hi - g
    if kind == LINE:
        return a * (xb - xa) - 0.5 * b * (xb * xb - xa * xa)
    if kind == STEP:
        return a * (xb - xa)
    if kind == QUADRATIC:
        return float(a * ((xb - xa) - p[0] * (xb**3 - xa**3) / 3.0))
    if kind == EXPONENTIAL:
        return float(a * (math.exp(-p[0] * xa) - math.exp(-p[0] * xb)) / p[0])
    k, level, x_cap = p[0], p[1], p[2]  # eq. 4.28's k and l
    total = 0.0
    if xa < x_cap:
        end = min(xb, x_cap)
        total += end - xa
        xa = end
    if xb > xa:
        total += level * (xb - xa) - (k / math.log(2.0)) * (
            (xb * math.log(xb) - xb) - (xa * math.log(xa) - xa)
        )
    return a * total


@_jit
def _splits(
    kind: int,
    p: NDArray[np.float64],
    g1: float,
    a1: float,
    g2: float,
    a2: float,
    lo: float,
    hi: float,
    out: NDArray[np.float64],
) -> int:
    """Knots of both shape curves and their critical point inside (lo, hi), sorted, in ``out``.

    Between two of these (and lo, hi) the difference of the curves is monotone.
    """
    n = 0
    for g in (g1, g2):
        if kind == QUADRATIC:
            knot = g + 1.0 / math.sqrt(p[0])
            if lo < knot < hi:
                out[n] = knot
                n += 1
        elif kind == CAPPED_LOG:
            for knot in (g + p[2], g + p[3]):
                if lo < knot < hi:
                    out[n] = knot
                    n += 1
    # d/dt of the difference vanishes where a1·(t - g1) = a2·(t - g2) (quadratic) or where
    # a1/(t - g1) = a2/(t - g2) (capped log); exponentials and lines have none
    critical = math.nan
    if a1 != a2:
        if kind == QUADRATIC:
            critical = (a1 * g1 - a2 * g2) / (a1 - a2)
        elif kind == CAPPED_LOG:
            critical = (a1 * g2 - a2 * g1) / (a1 - a2)
    if lo < critical < hi:
        out[n] = critical
        n += 1
    for i in range(1, n):  # insertion sort: at most five points
        key = out[i]
        j = i - 1
        while j >= 0 and out[j] > key:
            out[j + 1] = out[j]
            j -= 1
        out[j + 1] = key
    return n


@_jit
def _gap(
    kind: int, p: NDArray[np.float64], g1: float, a1: float, b1: float,
    g2: float, a2: float, b2: float, t: float,
) -> float:
    """How far curve 2 is above curve 1 at t, less a relative tolerance (> 0: strictly above)."""
    mine = _value(kind, p, g1, a1, b1, t)
    return _value(kind, p, g2, a2, b2, t) - mine - 1e-12 * (1.0 + abs(mine))


ROOT_BRACKET_S = 1e-6
"""Width to which a crossing is bracketed. A crossing misplaced by δ moves the integral by
O(δ²·slope), so a microsecond (1e-12 of utility for slopes up to 1/s) is exact for every
purpose."""


@_jit
def falsi_point(left: float, right: float, g_left: float, g_right: float) -> float:
    """The next point to try in the bracket (left, right), or NaN once it is narrow enough.

    The one root finder of the package (regula falsi with the Illinois modification): the
    compiled kernels here and :meth:`utility_specs.curves.Curve._root` drive it with their own
    gap function, ``gap(left) <= 0 < gap(right)``. It keeps the bracket and converges
    superlinearly on the smooth monotone segments between knots and critical points.
    """
    width = right - left
    if width <= max(ROOT_BRACKET_S, 4e-16 * abs(right)):
        return math.nan
    t = right - g_right * width / (g_right - g_left)
    if not left < t < right:
        t = 0.5 * (left + right)
    return t


@_jit
def falsi_update(
    left: float, right: float, g_left: float, g_right: float, side: int, t: float, gap: float
) -> tuple[float, float, float, float, int]:
    """The bracket after evaluating ``gap`` at ``t`` (Illinois: halve the stale end's gap)."""
    if gap > 0:
        if side == 1:
            g_left *= 0.5
        return left, t, g_left, gap, 1
    if side == -1:
        g_right *= 0.5
    return t, right, gap, g_right, -1


@_jit
def _root(
    kind: int, p: NDArray[np.float64], g1: float, a1: float, b1: float,
    g2: float, a2: float, b2: float, left: float, right: float,
) -> float:
    """Smallest t in (left, right] with gap > 0, given gap(left) <= 0 < gap(right)."""
    g_left = _gap(kind, p, g1, a1, b1, g2, a2, b2, left)
    g_right = _gap(kind, p, g1, a1, b1, g2, a2, b2, right)
    side = 0
    for _ in range(200):
        t = falsi_point(left, right, g_left, g_right)
        if t != t:
            break
        left, right, g_left, g_right, side = falsi_update(
            left, right, g_left, g_right, side, t, _gap(kind, p, g1, a1, b1, g2, a2, b2, t)
        )
    return right


@_jit
def _first_above(
    kind: int, p: NDArray[np.float64], g1: float, a1: float, b1: float,
    g2: float, a2: float, b2: float, lo: float, hi: float, scratch: NDArray[np.float64],
) -> float:
    """First time in [lo, hi] at which curve 2 is strictly above curve 1, or inf."""
    mine_lo = _value(kind, p, g1, a1, b1, lo)
    other_lo = _value(kind, p, g2, a2, b2, lo)
    gap_lo = other_lo - mine_lo
    if gap_lo > 1e-12 * (1.0 + abs(mine_lo)):
        return lo
    if kind == LINE:
        # two lines: linear until the first expiry, then one of them is 0
        expiry1, expiry2 = _expiry(kind, p, g1, a1, b1), _expiry(kind, p, g2, a2, b2)
        first_expiry = min(expiry1, expiry2)
        end = min(first_expiry, hi)
        if end > lo:
            mine_end = a1 - b1 * (end - g1)
            gap_end = a2 - b2 * (end - g2) - mine_end
            if gap_end > 1e-12 * (1.0 + abs(mine_end)):
                return lo + (end - lo) * (-gap_lo) / (gap_end - gap_lo)
        if first_expiry < hi and expiry1 < expiry2:
            return max(lo, first_expiry)
        return _NEVER
    # every curve is non-increasing: one starting at or below where curve 1 ends stays below
    if kind == STEP or other_lo <= _value(kind, p, g1, a1, b1, hi):
        return _NEVER
    n = _splits(kind, p, g1, a1, g2, a2, lo, hi, scratch)
    previous = lo
    for i in range(n + 1):
        t = scratch[i] if i < n else hi
        if _gap(kind, p, g1, a1, b1, g2, a2, b2, t) > 0:
            return _root(kind, p, g1, a1, b1, g2, a2, b2, previous, t)
        previous = t
    return _NEVER


@_jit
def _dominates(
    kind: int, p: NDArray[np.float64], g1: float, a1: float, b1: float,
    g2: float, a2: float, b2: float,
) -> bool:
    """A cheap sufficient test: curve 1 >= curve 2 at every time both are defined."""
    if kind == STEP:
        return a1 >= a2
    if kind == LINE:
        t0 = max(g1, g2)
        return b1 <= b2 and a1 - b1 * (t0 - g1) >= a2 - b2 * (t0 - g2)
    # φ is non-increasing: the newer of two curves with the larger scale is never lower
    return g1 >= g2 and a1 >= a2


@_jit
def _admit(
    kind: int, p: NDArray[np.float64], start: NDArray[np.float64], until: NDArray[np.float64],
    gen: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64],
    expiry: NDArray[np.float64], horizon: float, new: int, cand: NDArray[np.int64], m: int,
    scratch: NDArray[np.float64],
) -> int:
    """Add ``new`` to the ``m`` candidates, dropping whoever can no longer lead; new count.

    A candidate whose copy a better version replaces later stays sound to compare against:
    the replacement is at least as good.
    """
    s = start[new]
    end = min(expiry[new], horizon)
    if end <= s or until[new] <= s:
        return m
    g, an, bn = gen[new], a[new], b[new]
    kept = 0
    for i in range(m):
        c = cand[i]
        if _dominates(kind, p, gen[c], a[c], b[c], g, an, bn):
            return m
        if _dominates(kind, p, g, an, bn, gen[c], a[c], b[c]):
            continue
        if kind == LINE:
            # A line may never dominate outright and still stay on top for as long as
            # it matters: a newer, steeper battery line over an older, flatter one.
            if expiry[c] >= end and _first_above(
                kind, p, gen[c], a[c], b[c], g, an, bn, s, end, scratch
            ) == _NEVER:
                return m
            c_end = min(expiry[c], horizon)
            if expiry[new] >= c_end and _first_above(
                kind, p, g, an, bn, gen[c], a[c], b[c], s, c_end, scratch
            ) == _NEVER:
                continue
        cand[kept] = c
        kept += 1
    cand[kept] = new
    return kept + 1


@_jit
def _piece(
    kind: int, p: NDArray[np.float64], gen: NDArray[np.float64], a: NDArray[np.float64],
    b: NDArray[np.float64], cand: NDArray[np.int64], m: int, lo: float, hi: float,
    scratch: NDArray[np.float64],
) -> float:
    """∫ max over the candidates on [lo, hi]: follow the leader from crossing to crossing."""
    leader = cand[0]
    best = _value(kind, p, gen[leader], a[leader], b[leader], lo)
    for i in range(1, m):
        c = cand[i]
        v = _value(kind, p, gen[c], a[c], b[c], lo)
        if v > best or (v == best and gen[c] > gen[leader]):  # ties: the newest decays last
            leader, best = c, v
    cursor, total = lo, 0.0
    for _ in range(_MAX_SWITCHES):
        switch_at, challenger = hi, -1
        for i in range(m):
            c = cand[i]
            if c == leader:
                continue
            t = _first_above(
                kind, p, gen[leader], a[leader], b[leader], gen[c], a[c], b[c],
                cursor, switch_at, scratch,
            )
            if t < switch_at:
                switch_at, challenger = t, c
        total += _integral(kind, p, gen[leader], a[leader], b[leader], cursor, switch_at)
        if challenger < 0:
            return total
        leader, cursor = challenger, switch_at
    raise RuntimeError("max envelope did not settle")


@_jit
def _sweep(
    kind: int, p: NDArray[np.float64], start: NDArray[np.float64], until: NDArray[np.float64],
    gen: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64],
    t0: float, t1: float,
) -> float:
    n = start.shape[0]
    expiry = np.empty(n)
    for i in range(n):
        expiry[i] = _expiry(kind, p, gen[i], a[i], b[i])
    cand = np.empty(n + 1, dtype=np.int64)
    scratch = np.empty(8)
    m, i, total = 0, 0, 0.0
    now = start[0] if n else t1
    while now < t1:
        kept = 0  # first drop who has ended: a copy replaced now must not veto its successor
        for j in range(m):
            c = cand[j]
            if until[c] > now and expiry[c] > now:
                cand[kept] = c
                kept += 1
        m = kept
        while i < n and start[i] <= now:
            m = _admit(kind, p, start, until, gen, a, b, expiry, t1, i, cand, m, scratch)
            i += 1
        following = start[i] if i < n else t1
        for j in range(m):
            following = min(following, until[cand[j]])
        following = min(following, t1)
        lo = max(now, t0)
        if m and following > lo:
            total += _piece(kind, p, gen, a, b, cand, m, lo, following, scratch)
        now = following
    return total


@_jit
def _pair_gain(
    kind: int, p: NDArray[np.float64], gp: float, sp: float, rp: float,
    gj: float, sj: float, rj: float, horizon: float, scratch: NDArray[np.float64],
) -> tuple[float, bool]:
    """∫_{min(rp, rj)}^{horizon} max(U_p, U_j) - U_p for two curves ``s·φ(t - g)`` of one
    family received at r (U_p counts from r_p on), and whether U_j is ever on top."""
    lo = min(rj, horizon)
    n = _splits(kind, p, gp, sp, gj, sj, lo, horizon, scratch)
    if lo < rp < horizon:  # p starts counting at r_p: one more cut, kept sorted
        j = n - 1
        while j >= 0 and scratch[j] > rp:
            scratch[j + 1] = scratch[j]
            j -= 1
        scratch[j + 1] = rp
        n += 1
    total, above = 0.0, False
    a = lo
    for i in range(n + 1):
        b = scratch[i] if i < n else horizon
        if b <= a:
            continue
        if a < rp:  # p not received yet: j alone
            total += _integral(kind, p, gj, sj, 0.0, a, b)
            if _value(kind, p, gj, sj, 0.0, a) > 1e-12:
                above = True
        else:
            d_a = _gap(kind, p, gp, sp, 0.0, gj, sj, 0.0, a)
            d_b = _gap(kind, p, gp, sp, 0.0, gj, sj, 0.0, b)
            x1, x2 = a, b
            if d_a <= 0.0 and d_b > 0.0:  # j rises above p inside the segment
                x1 = _root(kind, p, gp, sp, 0.0, gj, sj, 0.0, a, b)
            elif d_a > 0.0 and d_b <= 0.0:  # p rises above j inside the segment
                x2 = _root(kind, p, gj, sj, 0.0, gp, sp, 0.0, a, b)
            elif d_a <= 0.0:
                x2 = x1
            if x2 > x1:
                above = True
                total += _integral(kind, p, gj, sj, 0.0, x1, x2) - _integral(
                    kind, p, gp, sp, 0.0, x1, x2
                )
        a = b
    return max(total, 0.0), above or rp > rj or rj >= horizon


@_jit
def envelope_pair_gains(
    kind: int, p: NDArray[np.float64], gp: NDArray[np.float64], sp: NDArray[np.float64],
    rp: NDArray[np.float64], gj: NDArray[np.float64], sj: NDArray[np.float64],
    rj: NDArray[np.float64], horizon: float,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """What a message j adds after a message p of its stream, for many (p, j) pairs at once.

    Eq. 4.5 for two messages: ``∫_{r_j}^{H} max(U_p, U_j) - U_p`` with U_p counting from
    r_p on, exact (crossings by the one root finder), and whether j becomes the stream's
    state (False when U_j never rises above U_p before H). Times are taken relative to the
    horizon (exact by Sterbenz) so that brackets can shrink below the resolution of epoch
    times.
    """
    n = gp.shape[0]
    gains = np.empty(n)
    moves = np.empty(n, dtype=np.bool_)
    scratch = np.empty(8)
    for k in range(n):
        gains[k], moves[k] = _pair_gain(
            kind, p, gp[k] - horizon, sp[k], rp[k] - horizon, gj[k] - horizon, sj[k],
            rj[k] - horizon, 0.0, scratch,
        )
    return gains, moves


def max_envelope_integral(
    family: Family,
    start: NDArray[np.float64],
    until: NDArray[np.float64],
    gen: NDArray[np.float64],
    t0: float,
    t1: float,
) -> float:
    """∫ over [t0, t1] of the max over received copies (eq. 4.5), copies sorted by ``start``.

    Copy i counts on [start_i, until_i) (eq. 4.33: until a better version arrives).
    """
    return float(_sweep(
        family.kind, np.asarray(family.shape, dtype=np.float64), start, until, gen,
        np.asarray(family.a, dtype=np.float64), np.asarray(family.b, dtype=np.float64),
        float(t0), float(t1),
    ))
