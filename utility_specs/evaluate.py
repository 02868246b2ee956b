"""Exact total utility of a set of received messages (eq. 4.1-4.7, 4.33).

The integral of eq. 4.2 is computed piece by piece between the breakpoints where something
changes - a reception, a better version replacing a worse one, a utility reaching its cap or
zero, two messages' utilities crossing, the receiver's state changing - and within a piece in
closed form. There is no fixed time step: the result is exact up to floating point.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from utility_specs.curves import Curve, FloatArray, Shape, ShapeCurve, StepCurve
from utility_specs.errors import MessageError
from utility_specs.functions import UtilityFunction
from utility_specs.message import Message, StateHistory
from utility_specs.spec import InfoType, MissionSpec

__all__ = [
    "Evaluation",
    "StreamKey",
    "aggregate_at",
    "evaluate",
    "evaluate_stream",
    "occurrences",
]

StreamKey = tuple[str, str, str | None]
"""(receiver, type, sender); sender is None when the type is not aggregated per sender."""

_EMPTY_HISTORY = StateHistory()
_VECTORISE_FROM = 48
"""Streams this long go through numpy; on shorter ones its call overhead costs more than it
saves (the optimiser evaluates many two- and three-message streams)."""
_MAX_SWITCHES = 1_000_000


@dataclass(frozen=True, slots=True, kw_only=True)
class Evaluation:
    """U(M) with its breakdown; per-type and per-receiver values include the weights ω_p."""

    total: float
    per_type: Mapping[str, float] = field(default_factory=dict)
    per_receiver: Mapping[str, float] = field(default_factory=dict)
    per_stream: Mapping[StreamKey, float] = field(default_factory=dict)
    t_start: float = 0.0
    t_end: float = 0.0

    def as_dict(self) -> dict[str, object]:
        return {
            "total": self.total,
            "per_type": dict(self.per_type),
            "per_receiver": dict(self.per_receiver),
        }


@dataclass(slots=True)
class _Occurrence:
    """A received copy counting on [start, until): later a better version may replace it."""

    m: Message
    start: float
    until: float
    curve: Curve | None = None


def occurrences(copies: Iterable[Message]) -> list[_Occurrence]:
    """Best-version-so-far timeline of one message at one receiver (eq. 4.33).

    A copy counts from its reception until a strictly better version arrives; a later copy
    that is not better is ignored.
    """
    out: list[_Occurrence] = []
    for m in sorted(copies, key=lambda c: (c.t_rcv, -c.quality)):
        assert m.t_rcv is not None
        if out and m.quality <= out[-1].m.quality:
            continue
        if out:
            out[-1].until = m.t_rcv
        out.append(_Occurrence(m, m.t_rcv, math.inf))
    return out


def evaluate(
    messages: Iterable[Message],
    spec: MissionSpec,
    *,
    t_end: float,
    t_start: float = 0.0,
    states: Mapping[str, StateHistory] | None = None,
    ignore_unknown_types: bool = False,
) -> Evaluation:
    """U(M) = Σ_g Σ_p ω_p ∫ A_p(M_g, t, H_g(t)) dt over [t_start, t_end] (eq. 4.1/4.2).

    Only copies with a receiver and ``t_rcv <= t_end`` count as received. ``states`` maps an
    agent to its history H_g, read by state-dependent utilities (eq. 4.18-4.22).
    """
    if not (math.isfinite(t_end) and math.isfinite(t_start) and t_end >= t_start):
        raise ValueError(f"need finite t_start <= t_end, got [{t_start}, {t_end}]")
    states = states or {}
    types = spec.types
    streams: dict[StreamKey, list[Message]] = defaultdict(list)
    per_sender = {name: info.per_sender for name, info in types.items()}
    for m in messages:
        split = per_sender.get(m.type)
        if split is None:
            if ignore_unknown_types:
                continue
            raise MessageError(
                f"message {m.sender}/{m.seq} has type {m.type!r}, which spec {spec.name!r} "
                f"does not define (types: {', '.join(types)})"
            )
        t_rcv = m.t_rcv
        if t_rcv is None or t_rcv > t_end or m.receiver is None:
            continue
        streams[(m.receiver, m.type, m.sender if split else None)].append(m)

    per_stream: dict[StreamKey, float] = {}
    per_type: dict[str, float] = dict.fromkeys(spec.types, 0.0)
    per_receiver: dict[str, float] = defaultdict(float)
    for key in sorted(streams, key=lambda k: (k[0], k[1], k[2] or "")):
        receiver, type_name, _ = key
        info = spec.types[type_name]
        raw = evaluate_stream(
            info, _timeline(streams[key]), t_start=t_start, t_end=t_end,
            history=states.get(receiver, _EMPTY_HISTORY),
        )
        value = info.weight * raw
        per_stream[key] = value
        per_type[type_name] += value
        per_receiver[receiver] += value
    return Evaluation(
        total=math.fsum(per_stream.values()),
        per_type=per_type,
        per_receiver=dict(per_receiver),
        per_stream=per_stream,
        t_start=t_start,
        t_end=t_end,
    )


def _timeline(stream: list[Message]) -> list[_Occurrence]:
    """Occurrences of a stream's messages; copies of one message collapse by eq. 4.33."""
    if len({(m.sender, m.seq) for m in stream}) == len(stream):
        inf = math.inf
        return [_Occurrence(m, m.t_rcv, inf) for m in stream]  # type: ignore[arg-type]
    groups: dict[tuple[str, int], list[Message]] = defaultdict(list)
    for m in stream:
        groups[(m.sender, m.seq)].append(m)
    return [o for group in groups.values() for o in occurrences(group)]


def evaluate_stream(
    info: InfoType,
    occs: Sequence[_Occurrence],
    *,
    t_start: float,
    t_end: float,
    history: StateHistory = _EMPTY_HISTORY,
) -> float:
    """∫ A_p over [t_start, t_end] for one stream, without the weight ω_p."""
    if not occs:
        return 0.0
    fn = info.utility
    if fn.impulse:
        return _impulses(fn, occs, t_start, t_end)
    prepared = fn.prepare([o.m for o in occs])
    if prepared is not None:
        by_id = {(p.sender, p.seq, p.version, p.t_rcv): p for p in prepared}
        occs = [
            _Occurrence(by_id[(o.m.sender, o.m.seq, o.m.version, o.m.t_rcv)], o.start, o.until)
            for o in occs
        ]
    if fn.state_dependent:
        return _piecewise_constant(info, fn, occs, t_start, t_end, history)
    if (
        info.aggregation == "max"
        and len(occs) >= _VECTORISE_FROM
        and all(o.until == math.inf for o in occs)
    ):
        occs = sorted(occs, key=lambda o: o.start)
        family = fn.shape_scales([o.m for o in occs])
        if family is not None:
            return _max_shape_family(fn, occs, family[0], family[1], t_start, t_end)
    for o in occs:
        o.curve = fn.curve(o.m)
    if info.aggregation == "sum":
        return math.fsum(
            o.curve.integral(max(o.start, t_start), min(o.until, t_end))  # type: ignore[union-attr]
            for o in occs
        )
    if info.aggregation == "last":
        return _last(occs, t_start, t_end)
    return _max(occs, t_start, t_end)


def _impulses(fn: UtilityFunction, occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """Eq. 4.34: each message counts once, at its first reception, with its best version."""
    best: dict[tuple[str, int], tuple[float, Message]] = {}
    for o in occs:
        first = best.get(o.m.key)
        start = o.start if first is None else min(first[0], o.start)
        keep = o.m if first is None or o.m.quality > first[1].quality else first[1]
        best[o.m.key] = (start, keep)
    assert hasattr(fn, "impulse_value")
    return math.fsum(fn.impulse_value(m) for start, m in best.values() if t0 <= start <= t1)


def _last(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """Eq. 4.6/4.7: on [g_i, g_next) only the newest *generated* message counts.

    A message generated but not yet received leaves a gap: it is already the newest, and
    brings nothing until it arrives. Messages never received do not exist for the receiver.
    """
    by_gen = sorted(occs, key=lambda o: (o.m.t_gen, o.m.sender, o.m.seq, o.start))
    gens: list[tuple[float, list[_Occurrence]]] = []
    for o in by_gen:
        if gens and gens[-1][1][0].m.key == o.m.key:
            gens[-1][1].append(o)
        else:
            gens.append((o.m.t_gen, [o]))
    total = 0.0
    for i, (g, group) in enumerate(gens):
        window_end = gens[i + 1][0] if i + 1 < len(gens) else math.inf
        for o in group:
            assert o.curve is not None
            total += o.curve.integral(max(g, o.start, t0), min(window_end, o.until, t1))
    return total


def _newest_leads(occs: Sequence[_Occurrence]) -> bool:
    """True when the newest generated message always leads (one shape, one scale)."""
    first = occs[0].curve
    if isinstance(first, StepCurve):
        return all(isinstance(o.curve, StepCurve) and o.until == math.inf for o in occs)
    if not isinstance(first, ShapeCurve):
        return False
    return all(
        isinstance(o.curve, ShapeCurve) and first.same_family(o.curve) and o.until == math.inf
        for o in occs
    )


def _max_newest_leads(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """Eq. 4.5 when the newest generated message leads, for curves already built."""
    first = occs[0].curve
    starts = [o.start for o in occs]
    gens = [o.m.t_gen for o in occs]
    if isinstance(first, StepCurve):
        ordered = np.sort(np.asarray(starts, dtype=np.float64))
        ends = np.append(ordered[1:], t1)
        return float(np.sum(np.maximum(np.clip(ends, t0, t1) - np.clip(ordered, t0, t1), 0.0)))
    assert isinstance(first, ShapeCurve)
    return first.scale * _newest_leads_integral(first.shape, starts, gens, t0, t1)


def _newest_leads_integral(
    shape: Shape, starts: Sequence[float], gens: Sequence[float], t0: float, t1: float
) -> float:
    """∫ φ(t - newest t_gen received so far) over [t0, t1]: one vectorised pass.

    Between two receptions the envelope of equally scaled curves is the received message
    with the latest generation time.
    """
    start_arr = np.asarray(starts, dtype=np.float64)
    gen_arr = np.asarray(gens, dtype=np.float64)
    order = np.argsort(start_arr, kind="stable")
    start_arr, gen_arr = start_arr[order], gen_arr[order]
    leader_gen = np.maximum.accumulate(gen_arr)
    ends = np.append(start_arr[1:], t1)
    a = np.clip(start_arr, t0, t1)
    b = np.clip(ends, t0, t1)
    xa = a - leader_gen
    xb = np.maximum(b - leader_gen, xa)
    return float(np.sum(shape.phi_integral_array(xa, xb)))


def _max_shape_family(
    fn: UtilityFunction,
    occs: Sequence[_Occurrence],
    shape: Shape,
    scales: Sequence[float],
    t0: float,
    t1: float,
) -> float:
    """Eq. 4.5 for scale(m)·φ(t - t_gen) streams (``occs`` sorted by reception)."""
    if min(scales) == max(scales):
        if scales[0] <= 0:
            return 0.0
        gens = [o.m.t_gen for o in occs]
        return scales[0] * _newest_leads_integral(shape, [o.start for o in occs], gens, t0, t1)
    return _max_shapes(occs, shape, t0, t1, scales=scales, make_curve=fn.curve)


def _max(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """Eq. 4.5: integral of the upper envelope of the received messages' utilities.

    A sweep over receptions keeps the candidates that may still lead; a new message is not
    admitted if a candidate stays above it until it expires (or the mission ends), and it
    evicts the candidates it stays above, so the set stays small.
    """
    long = len(occs) >= _VECTORISE_FROM
    if long and _newest_leads(occs):
        return _max_newest_leads(occs, t0, t1)
    occs = sorted(occs, key=lambda o: o.start)
    if any(o.until != math.inf for o in occs):
        return _max_with_versions(occs, t0, t1)
    candidates: list[_Occurrence] = []
    total = 0.0
    n = len(occs)
    for i, o in enumerate(occs):
        _admit(candidates, o, t1)
        lo = max(o.start, t0)
        hi = min(occs[i + 1].start if i + 1 < n else t1, t1)
        if hi <= lo or not candidates:
            continue
        if len(candidates) == 1:
            total += candidates[0].curve.integral(lo, hi)  # type: ignore[union-attr]
            continue
        candidates[:] = [c for c in candidates if c.curve.expiry > lo]  # type: ignore[union-attr]
        if candidates:
            total += _envelope_integral(candidates, lo, hi)
    return total


def _max_shapes(
    occs: Sequence[_Occurrence],
    shape: Shape,
    t0: float,
    t1: float,
    *,
    scales: Sequence[float],
    make_curve: Callable[[Message], Curve],
) -> float:
    """:func:`_max` for one shape with per-message scales (the video family), mostly in numpy.

    Between two receptions the candidates are a short staircase (each older one has a
    higher scale; a newer message with at least the scale of an older one dominates it).
    On most pieces no candidate can overtake the leader - every curve is non-increasing, so
    one that starts below where the leader ends never does - and the piece is the leader's
    closed-form integral, done for all pieces at once. The rest take the exact path.
    """
    n = len(occs)
    gens = [o.m.t_gen for o in occs]
    x_zero = shape.x_zero
    pieces_lo: list[float] = []
    pieces_hi: list[float] = []
    flat: list[int] = []
    sizes: list[int] = []
    # The staircase, oldest first: generation times rise and scales fall along it.
    stair: list[int] = []
    for i in range(n):
        g, s = gens[i], scales[i]
        if s > 0:
            if not stair or g >= gens[stair[-1]]:
                while stair and scales[stair[-1]] <= s:
                    stair.pop()
                if not stair or scales[stair[-1]] > s:
                    stair.append(i)
            elif not any(gens[j] >= g and scales[j] >= s for j in stair):
                # received out of generation order: insert where it belongs
                stair = [j for j in stair if not (g >= gens[j] and s >= scales[j])]
                stair.append(i)
                stair.sort(key=gens.__getitem__)
        lo = occs[i].start if occs[i].start > t0 else t0
        hi = occs[i + 1].start if i + 1 < n else t1
        if hi > t1:
            hi = t1
        if hi <= lo:
            continue
        while stair and gens[stair[0]] + x_zero <= lo:
            stair.pop(0)
        if stair:
            pieces_lo.append(lo)
            pieces_hi.append(hi)
            flat.extend(stair)
            sizes.append(len(stair))
    if not sizes:
        return 0.0
    count = len(sizes)
    width = max(sizes)
    lo_arr = np.asarray(pieces_lo, dtype=np.float64)
    hi_arr = np.asarray(pieces_hi, dtype=np.float64)
    size_arr = np.asarray(sizes, dtype=np.int64)
    index = np.full((count, width), -1, dtype=np.int64)
    row_of = np.repeat(np.arange(count), size_arr)
    col_of = np.arange(len(flat)) - np.repeat(np.cumsum(size_arr) - size_arr, size_arr)
    index[row_of, col_of] = flat
    valid = index >= 0
    g_all = np.asarray(gens, dtype=np.float64)
    s_all = np.asarray(scales, dtype=np.float64)
    g_cand = np.where(valid, g_all[index], 0.0)
    s_cand = np.where(valid, s_all[index], 0.0)
    at_lo = np.where(valid, s_cand * shape.phi_array(lo_arr[:, None] - g_cand), -np.inf)
    best = at_lo.max(axis=1)
    # ties go to the newest message, which decays last
    tied = at_lo >= best[:, None]
    leader = np.argmax(np.where(tied, g_cand, -np.inf), axis=1)
    rows = np.arange(count)
    g_lead, s_lead = g_cand[rows, leader], s_cand[rows, leader]
    lead_at_hi = s_lead * shape.phi_array(hi_arr - g_lead)
    challengers = valid & (at_lo > (lead_at_hi * (1.0 + 1e-12) + 1e-12)[:, None])
    challengers[rows, leader] = False
    hard = np.flatnonzero(challengers.any(axis=1))
    if hard.size:
        challengers[hard] &= _may_overtake(
            shape, lo_arr[hard], hi_arr[hard], g_cand[hard], s_cand[hard],
            g_lead[hard], s_lead[hard],
        )
    simple = ~challengers.any(axis=1)
    total = float(np.sum(
        s_lead[simple]
        * shape.phi_integral_array(lo_arr[simple] - g_lead[simple], hi_arr[simple] - g_lead[simple])
    ))
    for row in np.flatnonzero(~simple).tolist():
        chosen = [occs[j] for j in index[row][valid[row]].tolist()]
        for o in chosen:
            if o.curve is None:
                o.curve = make_curve(o.m)
        total += _envelope_integral(chosen, pieces_lo[row], pieces_hi[row])
    return total


def _may_overtake(
    shape: Shape,
    lo: FloatArray,
    hi: FloatArray,
    g: FloatArray,
    s: FloatArray,
    g_lead: FloatArray,
    s_lead: FloatArray,
) -> NDArray[np.bool_]:
    """Whether each candidate rises above its piece's leader somewhere in [lo, hi].

    Between the knots of both curves and their critical point the difference is monotone, so
    its maximum over the piece is at one of those points: checking them is exact.
    """
    lo2, hi2 = lo[:, None], hi[:, None]
    gl, sl = g_lead[:, None], s_lead[:, None]
    points = [np.broadcast_to(lo2, g.shape), np.broadcast_to(hi2, g.shape)]
    for x in shape.x_knots:
        points += [g + x, np.broadcast_to(gl + x, g.shape)]
    critical = shape.critical_array(
        np.broadcast_to(sl, g.shape), np.broadcast_to(gl, g.shape), s, g
    )
    if critical is not None:
        points.append(np.where(np.isnan(critical), lo2, critical))
    t = np.clip(np.stack(points, axis=-1), lo2[..., None], hi2[..., None])
    leader_values = sl[..., None] * shape.phi_array(t - gl[..., None])
    gap = s[..., None] * shape.phi_array(t - g[..., None]) - leader_values
    above: NDArray[np.bool_] = gap > 1e-12 * (1.0 + np.abs(leader_values))
    return np.asarray(above.any(axis=-1), dtype=np.bool_)


def _max_with_versions(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """:func:`_max` when better versions replace copies: their ``until`` ends a piece too."""
    times = sorted({o.start for o in occs} | {o.until for o in occs if o.until < t1} | {t0, t1})
    candidates: list[_Occurrence] = []
    index, n = 0, len(occs)
    total = 0.0
    for a, b in itertools.pairwise(times):
        while index < n and occs[index].start <= a:
            _admit(candidates, occs[index], t1)
            index += 1
        if b <= t0 or a >= t1:
            continue
        if candidates:
            candidates[:] = [c for c in candidates if c.until > a and c.curve.expiry > a]  # type: ignore[union-attr]
        if candidates:
            total += _envelope_integral(candidates, max(a, t0), min(b, t1))
    return total


def _admit(candidates: list[_Occurrence], new: _Occurrence, horizon: float) -> None:
    """Add ``new`` to the envelope candidates, dropping whoever can no longer lead."""
    curve = new.curve
    assert curve is not None
    start = new.start
    end = min(curve.expiry, horizon)
    if end <= start:
        return
    kept: list[_Occurrence] = []
    for c in candidates:
        other = c.curve
        assert other is not None
        if other.dominates(curve):
            return  # never above c
        if not curve.dominates(other):
            kept.append(c)
    if not kept:
        candidates[:] = [new]
        return
    if curve.evict_bounded:
        # A line may never dominate outright and still stay on top for as long as it matters.
        new_start, new_end = curve.value(start), curve.value(end)
        survivors = []
        for c in kept:
            other = c.curve
            assert other is not None
            if other.expiry >= end and other.first_above(curve, start, end) is None:
                return  # it never rises above c while it could count
            other_end = min(other.expiry, horizon)
            if curve.expiry >= other_end and (
                curve.first_above(
                    other, start, other_end, self_lo=new_start,
                    self_hi=new_end if other_end == end else None,
                )
                is None
            ):
                continue
            survivors.append(c)
        kept = survivors
    kept.append(new)
    candidates[:] = kept


def _envelope_integral(candidates: Sequence[_Occurrence], a: float, b: float) -> float:
    curves: list[Curve] = [c.curve for c in candidates]  # type: ignore[misc]
    if len(curves) == 1:
        return curves[0].integral(a, b)
    leader = curves[0]
    best = (leader.value(a), leader.t_gen)
    for c in curves[1:]:
        key = (c.value(a), c.t_gen)
        if key > best:
            leader, best = c, key
    cursor, total = a, 0.0
    for _ in range(_MAX_SWITCHES):
        switch_at, challenger = b, None
        leader_at_cursor = leader.value(cursor)
        leader_at_end = leader.value(b)
        for c in curves:
            if c is leader:
                continue
            t = leader.first_above(
                c, cursor, switch_at, self_lo=leader_at_cursor,
                self_hi=leader_at_end if switch_at == b else None,
            )
            if t is not None and t < switch_at:
                switch_at, challenger = t, c
        total += leader.integral(cursor, switch_at)
        if challenger is None:
            return total
        leader, cursor = challenger, switch_at
    raise RuntimeError("max envelope did not settle; a utility's critical points are wrong")


def _piecewise_constant(
    info: InfoType,
    fn: UtilityFunction,
    occs: Sequence[_Occurrence],
    t0: float,
    t1: float,
    history: StateHistory,
) -> float:
    """State-dependent utilities are constant between receptions and state changes.

    Values depend on (message, state) only, so while the state stays the same only a new
    message needs evaluating and the aggregate is updated, not recomputed.
    """
    cuts = {t0, t1, *history.change_times(t0, t1)}
    for o in occs:
        cuts.update(t for t in (o.start, o.until, o.m.t_gen) if t0 < t < t1)
    times = sorted(cuts)
    by_gen = sorted(occs, key=lambda o: (o.m.t_gen, o.m.sender, o.m.seq))
    gens = [o.m.t_gen for o in by_gen]
    by_start = sorted(occs, key=lambda o: o.start)
    last = info.aggregation == "last"
    summing = info.aggregation == "sum"
    total = 0.0
    live: dict[int, tuple[_Occurrence, float]] = {}
    level = 0.0
    state: Mapping[str, object] | None = None
    index = 0
    next_until = math.inf
    for a, b in itertools.pairwise(times):
        middle = 0.5 * (a + b)
        now_state = history.at(middle)
        dirty = now_state is not state
        state = now_state
        if dirty:
            entries = list(live.values())
            values = fn.values([o.m for o, _ in entries], middle, state)
            live = {id(o): (o, v) for (o, _), v in zip(entries, values, strict=True)}
        if middle >= next_until:
            live = {k: v for k, v in live.items() if middle < v[0].until}
            next_until = min((v[0].until for v in live.values()), default=math.inf)
            dirty = True
        while index < len(by_start) and by_start[index].start <= middle:
            o = by_start[index]
            value = fn.value(o.m, middle, state)
            live[id(o)] = (o, value)
            next_until = min(next_until, o.until)
            if summing and not dirty:
                level += value
            elif not dirty:
                level = max(level, value)
            index += 1
        if last:
            if gens[0] > middle:
                continue
            newest = by_gen[bisect.bisect_right(gens, middle) - 1].m.key
            level = max((v for o, v in live.values() if o.m.key == newest), default=0.0)
        elif dirty:
            values = [v for _, v in live.values()]
            level = (math.fsum(values) if summing else max(values)) if values else 0.0
        total += level * (b - a)
    return total


def aggregate_at(
    info: InfoType,
    messages: Sequence[Message],
    t: float,
    state: Mapping[str, object] | None = None,
) -> float:
    """A_p(M, t, s) of eq. 4.4-4.7 at one instant, straight from the definitions.

    The slow, literal reading of the model: the plots draw it and the tests integrate it
    numerically to check the exact evaluator. ``messages`` is one stream at one receiver.
    """
    fn = info.utility
    state = state or {}
    prepared = fn.prepare(list(messages)) or list(messages)
    received = [m for m in prepared if m.t_rcv is not None and m.t_rcv <= t]
    # eq. 4.33: of several copies of one message only the best version received so far counts
    best: dict[tuple[str, int], Message] = {}
    for m in received:
        held = best.get(m.key)
        if held is None or m.quality > held.quality:
            best[m.key] = m
    if info.aggregation == "last":
        generated = [m for m in prepared if m.t_rcv is not None and m.t_gen <= t]
        if not generated:
            return 0.0
        newest = max(generated, key=lambda m: (m.t_gen, m.sender, m.seq))
        held = best.get(newest.key)
        return fn.value(held, t, state) if held is not None else 0.0
    values = [fn.value(m, t, state) for m in best.values()]
    if not values:
        return 0.0
    return math.fsum(values) if info.aggregation == "sum" else max(values)
