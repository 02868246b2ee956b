"""Exact total utility of a set of received messages (eq. 4.1-4.7, 4.33).

The integral of eq. 4.2 is computed piece by piece between the breakpoints where something
changes - a reception, a better version replacing a worse one, a utility reaching its cap or
zero, two messages' utilities crossing, the receiver's state changing - and within a piece in
closed form. There is no fixed time step: the result is exact up to floating point.

Short streams (the optimiser's two- and three-message ones) go through curve objects; long
``max`` streams through the same sweep on flat arrays, compiled by numba
(:mod:`utility_specs._envelope`), which is what keeps a whole mission in milliseconds.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import attrgetter

import numpy as np

from utility_specs._envelope import JIT, max_envelope_integral
from utility_specs.curves import Curve
from utility_specs.errors import MessageError
from utility_specs.functions import UtilityFunction
from utility_specs.message import Message, MessageKey, StateHistory
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
_COMPILED_FROM = 8
"""Streams this long take the compiled sweep; on shorter ones the call costs more than it
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


_start = attrgetter("start")
_t_rcv = attrgetter("t_rcv")


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
        raw = _stream_total(
            info, streams[key], t_start, t_end, states.get(receiver, _EMPTY_HISTORY)
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


def _stream_total(
    info: InfoType, stream: list[Message], t0: float, t1: float, history: StateHistory
) -> float:
    """:func:`evaluate_stream` for received messages; copies of one message collapse by
    eq. 4.33. A long ``max`` stream without copies goes to the compiled sweep directly."""
    if len({m.key for m in stream}) == len(stream):
        if info.aggregation == "max" and JIT and len(stream) >= _COMPILED_FROM:
            stream.sort(key=_t_rcv)
            starts = [m.t_rcv for m in stream]
            value = _compiled_max(info.utility, stream, starts, None, t0, t1)  # type: ignore[arg-type]
            if value is not None:
                return value
        inf = math.inf
        occs = [_Occurrence(m, m.t_rcv, inf) for m in stream]  # type: ignore[arg-type]
    else:
        groups: dict[MessageKey, list[Message]] = defaultdict(list)
        for m in stream:
            groups[m.key].append(m)
        occs = [o for group in groups.values() for o in occurrences(group)]
    return evaluate_stream(info, occs, t_start=t0, t_end=t1, history=history)


def _compiled_max(
    fn: UtilityFunction,
    messages: Sequence[Message],
    starts: Sequence[float],
    untils: Sequence[float] | None,
    t0: float,
    t1: float,
) -> float | None:
    """Eq. 4.5 by the compiled sweep (copies sorted by start), or None if ``fn`` has no
    family form."""
    family = fn.family(messages)
    if family is None:
        return None
    n = len(messages)
    return max_envelope_integral(
        family,
        np.array(starts, dtype=np.float64),
        np.full(n, math.inf) if untils is None else np.array(untils, dtype=np.float64),
        np.array([m.t_gen for m in messages], dtype=np.float64),
        t0,
        t1,
    )


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
        by_id = {(p.key, p.version, p.t_rcv): p for p in prepared}
        occs = [
            _Occurrence(by_id[(o.m.key, o.m.version, o.m.t_rcv)], o.start, o.until)
            for o in occs
        ]
    if fn.state_dependent:
        if info.aggregation == "sum":
            return _sum_piecewise_constant(fn, occs, t_start, t_end, history)
        return _piecewise_constant(info, fn, occs, t_start, t_end, history)
    if info.aggregation == "max" and JIT and len(occs) >= _COMPILED_FROM:
        occs = sorted(occs, key=_start)
        value = _compiled_max(
            fn, [o.m for o in occs], [o.start for o in occs], [o.until for o in occs],
            t_start, t_end,
        )
        if value is not None:
            return value
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
    best: dict[MessageKey, tuple[float, Message]] = {}
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


def _max(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """Eq. 4.5: integral of the upper envelope of the received messages' utilities.

    A sweep over receptions keeps the candidates that may still lead; a new message is not
    admitted if a candidate stays above it until it expires (or the mission ends), and it
    evicts the candidates it stays above, so the set stays small.
    """
    occs = sorted(occs, key=_start)
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


def _max_with_versions(occs: Sequence[_Occurrence], t0: float, t1: float) -> float:
    """:func:`_max` when better versions replace copies: their ``until`` ends a piece too."""
    times = sorted({o.start for o in occs} | {o.until for o in occs if o.until < t1} | {t0, t1})
    candidates: list[_Occurrence] = []
    index, n = 0, len(occs)
    total = 0.0
    for a, b in itertools.pairwise(times):
        # first drop who has ended: a copy replaced at a must not veto its successor
        candidates[:] = [c for c in candidates if c.until > a and c.curve.expiry > a]  # type: ignore[union-attr]
        while index < n and occs[index].start <= a:
            _admit(candidates, occs[index], t1)
            index += 1
        if b <= t0 or a >= t1:
            continue
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


def _sum_piecewise_constant(
    fn: UtilityFunction,
    occs: Sequence[_Occurrence],
    t0: float,
    t1: float,
    history: StateHistory,
) -> float:
    """``sum`` of a state-dependent utility: each copy on its own, one state at a time.

    A value depends on (message, state) only, so between two state changes each live copy
    contributes its value times its overlap; all copies live in a state are valued at once.
    """
    by_start = sorted(occs, key=_start)
    starts = [o.start for o in by_start]
    total = 0.0
    for a, b in itertools.pairwise([t0, *history.change_times(t0, t1), t1]):
        live = [o for o in by_start[: bisect.bisect_left(starts, b)] if o.until > a]
        if not live:
            continue
        middle = 0.5 * (a + b)
        values = fn.values([o.m for o in live], middle, history.at(middle))
        total += math.fsum(
            v * (min(o.until, b) - max(o.start, a))
            for o, v in zip(live, values, strict=True)
            if v
        )
    return total


def _piecewise_constant(
    info: InfoType,
    fn: UtilityFunction,
    occs: Sequence[_Occurrence],
    t0: float,
    t1: float,
    history: StateHistory,
) -> float:
    """``max`` and ``last`` of a state-dependent utility: constant between receptions,
    replacements, generations and state changes.

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
            if not dirty:
                level = max(level, value)
            index += 1
        if last:
            if gens[0] > middle:
                continue
            newest = by_gen[bisect.bisect_right(gens, middle) - 1].m.key
            level = max((v for o, v in live.values() if o.m.key == newest), default=0.0)
        elif dirty:
            values = [v for _, v in live.values()]
            level = max(values, default=0.0)
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
    best: dict[MessageKey, Message] = {}
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
