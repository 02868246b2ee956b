"""Incremental node evaluation: the planning problem as flat tables (thesis ch. 5.3, eq. 4.1-4.7).

The tree decides messages one level at a time in generation-time order. Within one stream
(one receiver, one type, one sender when the type is aggregated per sender), what a decision
adds depends only on the previous message of the stream that the path sends:

* ``max`` aggregation (eq. 4.5): sending ``j`` after ``p`` adds
  ``∫_{r_j}^{H} max(U_p, U_j) - U_p dt``; when ``j`` dominates ``p`` (``UtilityFunction.dominates``,
  true for a newer message of a Markovian type) that is ``I_j(r_j, H) - I_p(r_j, H)`` in
  closed form; when ``p`` stays above ``j`` until the horizon, ``j`` adds nothing and the
  stream's state stays ``p`` (an older full image against a newer quarter one); otherwise
  the two-message envelope is integrated exactly by :func:`utility_specs.evaluate.evaluate_stream`;
* ``last`` aggregation (eq. 4.6/4.7): ``p`` stops counting at ``g_j``, ``j`` counts from ``r_j``:
  ``I_j(r_j, H) - I_p(max(g_j, r_p), H)``;
* ``sum`` aggregation (eq. 4.4): each message adds its own integral (independent items).

So a child's utility is its parent's plus one table entry ``gain[level, option, slot]``,
where ``slot`` names the stream's previous sent message (0: the newest message already sent
before the tree). The sum over a path telescopes to the exact :func:`evaluate` value whenever
each newer message dominates the older ones of its stream (every Markovian type in the
library: battery with one depletion rate, position, status...). For types where an older
message can resurface above a newer one (e.g. a red frame followed by a plain one), the pair
envelope is exact and the chain an approximation; that is the Markovian assumption (eq. 5.8).
The tables are built once per decision, so the search itself does O(1) work per node.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt

from utility_specs._envelope import envelope_pair_gains
from utility_specs.curves import Curve, Shape, ShapeCurve
from utility_specs.evaluate import evaluate_stream, occurrences
from utility_specs.message import Message
from utility_specs.spec import InfoType, MissionSpec

__all__ = [
    "FixedItem",
    "PlanItem",
    "Problem",
    "build_problem",
    "option_message",
    "stream_of",
]

_RECEIVER = "_planned"


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanItem:
    """One decision of the tree: a real or forecast message with planned send/receive times."""

    message: Message
    """The message carrying its best version (version 0) when it has versions."""
    send_t: float
    """Planned send time (fleet clock, s): the windows of eq. 5.7 use it."""
    rcv_t: float
    """Planned reception time: send time plus the estimated latency."""
    kind: str = "forecast"
    """``decide`` (the message being decided), ``inflight`` (another agent's message that may
    still arrive) or ``forecast`` (predicted, ch. 5.1)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FixedItem:
    """A message already sent (delivered, or own and in flight): not a decision any more."""

    message: Message
    send_t: float
    rcv_t: float


def stream_of(spec: MissionSpec, message: Message) -> tuple[str, str | None]:
    """The stream a message belongs to at the (single) receiver: (type, sender or None)."""
    info = spec.types[message.type]
    return (message.type, message.sender if info.per_sender else None)


def option_message(message: Message, option: int) -> Message:
    """The message as sent with ``option`` (1 = best version ... ; 0 is drop)."""
    if message.versions and message.version != option - 1:
        return _copy_with_version(message, option - 1)
    return message


_MESSAGE_FIELDS = Message.__slots__


def _copy_with_version(message: Message, version: int) -> Message:
    """``message.with_version(version)`` without re-validating (hot path of every decision):
    a copy of a validated message carrying one of its own versions is valid by construction."""
    if not 0 <= version < len(message.versions):
        raise IndexError(f"version {version} out of range 0..{len(message.versions) - 1}")
    copy = object.__new__(Message)
    for name in _MESSAGE_FIELDS:
        object.__setattr__(copy, name, getattr(message, name))
    object.__setattr__(copy, "version", version)
    object.__setattr__(copy, "size", message.versions[version].size)
    return copy


def n_options(message: Message) -> int:
    return 1 + (len(message.versions) if message.versions else 1)


class Problem:
    """Flat arrays for one decision's tree (read by the search kernel and the exact solver).

    Options of item ``i`` are ``0`` (drop) and ``1..nopt[i]-1`` (send version ``o - 1``).
    ``gain[i, o, slot]`` is the utility (weighted, eq. 4.2) added by sending ``i`` with
    option ``o`` when the previous sent message of its stream is ``slot``: 0 is the stream's
    base (newest fixed message), ``1 + pos*max_versions + v`` is the item at position ``pos``
    of the stream sent as version ``v``. Independent items (``sum`` types) have stream -1 and
    use slot 0 only.
    """

    __slots__ = (
        "budget_bytes",
        "decided_level",
        "force",
        "gain",
        "horizon_end",
        "items",
        "max_opt",
        "max_versions",
        "n_streams",
        "nopt",
        "nslot",
        "pos",
        "root_win_bytes",
        "root_win_t",
        "send_t",
        "size",
        "stream",
        "stream_keys",
        "stream_markov",
        "window_s",
    )

    def __init__(
        self,
        *,
        items: list[PlanItem],
        stream: npt.NDArray[np.int64],
        pos: npt.NDArray[np.int64],
        nopt: npt.NDArray[np.int64],
        size: npt.NDArray[np.int64],
        send_t: npt.NDArray[np.float64],
        gain: npt.NDArray[np.float64],
        nslot: npt.NDArray[np.int64],
        stream_keys: list[tuple[str, str | None]],
        stream_markov: npt.NDArray[np.bool_],
        root_win_t: npt.NDArray[np.float64],
        root_win_bytes: npt.NDArray[np.int64],
        budget_bytes: float,
        window_s: float,
        max_versions: int,
        decided_level: int,
        horizon_end: float,
    ) -> None:
        self.items = items
        self.stream = stream
        self.pos = pos
        self.nopt = nopt
        self.size = size
        self.send_t = send_t
        self.gain = gain
        self.nslot = nslot
        self.stream_keys = stream_keys
        self.stream_markov = stream_markov
        self.root_win_t = root_win_t
        self.root_win_bytes = root_win_bytes
        self.budget_bytes = budget_bytes
        self.window_s = window_s
        self.max_versions = max_versions
        self.max_opt = int(gain.shape[1])
        self.n_streams = len(stream_keys)
        self.decided_level = decided_level
        self.horizon_end = horizon_end
        self.force = np.full(len(items), -1, dtype=np.int64)
        """Per level: the option another agent announced for it (``agreed.py``), -1: free."""

    @property
    def n(self) -> int:
        return len(self.items)

    def next_slot(self, i: int, option: int, slot: int = 0) -> int:
        """The stream's state after sending item ``i`` with ``option`` from state ``slot``:
        the item itself, or the old state when the old message stays above it up to the
        horizon (sending it then adds nothing and changes nothing)."""
        return int(self.nslot[i, option, slot])

    def path_gain(self, choices: Sequence[int]) -> float:
        """Utility added by a path of options (one per level from 0), ignoring the constraint."""
        last = [0] * self.n_streams
        total = 0.0
        for i, option in enumerate(choices):
            if option == 0:
                continue
            s = int(self.stream[i])
            total += float(self.gain[i, option, last[s] if s >= 0 else 0])
            if s >= 0:
                last[s] = self.next_slot(i, option, last[s])
        return total

    def feasible(self, choices: Sequence[int]) -> bool:
        """Eq. 5.5/5.7: every window [t, t + T] starting at a send time holds <= budget bytes."""
        sends = [
            (float(t), int(b))
            for t, b in zip(self.root_win_t, self.root_win_bytes, strict=True)
        ]
        sends += [
            (float(self.send_t[i]), int(self.size[i, o])) for i, o in enumerate(choices) if o != 0
        ]
        return window_violations(sends, window_s=self.window_s, budget_bytes=self.budget_bytes) == 0

    def all_send_norm(self) -> npt.NDArray[np.float64]:
        """norm[d]: utility of sending every item of levels < d in its best version."""
        norm = np.zeros(self.n + 1)
        last = [0] * self.n_streams
        total = 0.0
        for i in range(self.n):
            s = int(self.stream[i])
            total += float(self.gain[i, 1, last[s] if s >= 0 else 0])
            if s >= 0:
                last[s] = self.next_slot(i, 1, last[s])
            norm[i + 1] = total
        return norm


def window_violations(
    sends: Sequence[tuple[float, int]], *, window_s: float, budget_bytes: float
) -> int:
    """Send instants t whose window [t, t + T] (eq. 5.7) holds more than the budget."""
    ordered = sorted(sends)
    violations = 0
    hi = 0
    total = 0
    for lo, (t, _) in enumerate(ordered):
        while hi < len(ordered) and ordered[hi][0] <= t + window_s + 1e-12:
            total += ordered[hi][1]
            hi += 1
        if total > budget_bytes + 1e-9:
            violations += 1
        total -= ordered[lo][1]
    return violations


class _Variant:
    """One message as sent in one version, with its utility curve built once."""

    __slots__ = ("_tails", "curve", "info", "m", "r")

    def __init__(self, info: InfoType, m: Message, r: float) -> None:
        self.info = info
        self.m = m
        self.r = r
        self._tails: dict[float, float] = {}
        try:
            self.curve: Curve | None = info.utility.curve(m)
        except NotImplementedError:  # state-dependent: integrated piecewise by the evaluator
            self.curve = None

    def tail(self, a: float, horizon: float) -> float:
        """∫_a^horizon U, cached per start (one decision has one horizon)."""
        value = self._tails.get(a)
        if value is None:
            value = self._tails[a] = self.integral(a, horizon)
        return value

    def integral(self, a: float, b: float) -> float:
        """∫_a^b U (a >= reception); the exact evaluator when there is no curve."""
        if b <= a:
            return 0.0
        if self.curve is not None:
            return self.curve.integral(a, b)
        occs = occurrences([self.m.delivered(receiver=_RECEIVER, t_rcv=a)])
        return evaluate_stream(self.info, occs, t_start=a, t_end=b)


def _pair_gain(p: _Variant | None, j: _Variant, horizon: float) -> tuple[float, bool]:
    """What sending ``j`` adds to a stream whose previous sent message is ``p`` (unweighted),
    and whether ``j`` becomes the stream's state (False: ``p`` stays above ``j`` until the
    horizon, so ``j`` changes nothing)."""
    info = j.info
    fn = info.utility
    if fn.impulse:
        impulse = getattr(fn, "impulse_value", None)
        return (float(impulse(j.m)) if impulse is not None and j.r <= horizon else 0.0), True
    if info.aggregation == "sum" or p is None:
        return j.tail(j.r, horizon), True
    if info.aggregation == "last":
        return j.tail(j.r, horizon) - p.tail(max(j.m.t_gen, p.r), horizon), True
    # max (eq. 4.5)
    cp, cj = p.curve, j.curve
    if cp is not None and cj is not None and p.r <= j.r:
        if cj.dominates(cp):
            return j.tail(j.r, horizon) - p.tail(j.r, horizon), True
        if j.r >= horizon:
            return 0.0, True
        above = cp.first_above(cj, j.r, horizon)
        if above is None:  # p stays above j until the horizon
            return 0.0, False
        if above <= j.r and cj.first_above(cp, j.r, horizon) is None:
            return j.tail(j.r, horizon) - p.tail(j.r, horizon), True
    start = min(p.r, j.r)
    if start >= horizon:
        return 0.0, True
    occs = occurrences([p.m.delivered(receiver=_RECEIVER, t_rcv=p.r)]) + occurrences(
        [j.m.delivered(receiver=_RECEIVER, t_rcv=j.r)]
    )
    both = evaluate_stream(info, occs, t_start=start, t_end=horizon)
    return both - p.tail(p.r, horizon), True


def _crossing_gains(
    shape: Shape, ps: Sequence[_Variant], js: Sequence[_Variant], horizon: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`_pair_gain` of many ``max`` pairs of one shape at once (unweighted): the exact
    two-message envelope ``∫_{r_j}^{H} max(U_p, U_j) - U_p`` (eq. 4.5), and whether ``j``
    becomes the stream's state (False when ``U_j`` never rises above ``U_p`` before H).

    Between the knots of φ, the critical point of the two curves and ``r_p`` (before which
    ``p`` counts as 0), ``U_j - U_p`` is monotone, so each segment has at most one sign
    change; it is located by the package's one root finder and the positive parts are
    integrated in closed form, all pairs in one compiled loop (the crossing pairs of an image
    stream offered in three versions are hundreds per decision).
    """
    cps = [cast(ShapeCurve, p.curve) for p in ps]
    cjs = [cast(ShapeCurve, j.curve) for j in js]
    return _envelope_gains(
        shape,
        np.array([c.t_gen for c in cps]), np.array([c.scale for c in cps]),
        np.array([p.r for p in ps]),
        np.array([c.t_gen for c in cjs]), np.array([c.scale for c in cjs]),
        np.array([j.r for j in js]),
        horizon,
    )


def _envelope_gains(
    shape: Shape,
    gp: npt.NDArray[np.float64],
    sp: npt.NDArray[np.float64],
    rp: npt.NDArray[np.float64],
    gj: npt.NDArray[np.float64],
    sj: npt.NDArray[np.float64],
    rj: npt.NDArray[np.float64],
    horizon: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`_crossing_gains` on arrays: curves ``s·φ(t - g)`` received at ``r``, by the
    compiled two-message envelope of ``utility_specs`` (one root finder for the package)."""
    assert shape.kernel is not None  # _shape_family admits only shapes with a kernel
    kind, params = shape.kernel
    return envelope_pair_gains(
        kind, np.asarray(params, dtype=np.float64), gp, sp, rp, gj, sj, rj, float(horizon)
    )


_Pred = tuple[int, int, int, "_Variant | None"]
"""(stream, slot, position in the stream or -1 for the base, variant or None)."""
_Item = tuple[int, int, int, int, "_Variant"]
"""(stream, level, option, position in the stream, variant)."""


def _shape_family(preds: list[_Pred], items: list[_Item]) -> Shape | None:
    """The common shape when every curve of a stream is ``scale·φ(t - t_gen)`` of one φ."""
    curves = [v.curve for *_, v in preds if v is not None] + [v.curve for *_, v in items]
    if not curves or not all(isinstance(c, ShapeCurve) for c in curves):
        return None
    shape = cast(ShapeCurve, curves[0]).shape
    if shape.kernel is None or any(cast(ShapeCurve, c).shape is not shape for c in curves):
        return None
    return shape


def _shape_streams(
    shape: Shape,
    preds: list[_Pred],
    items: list[_Item],
    weight: npt.NDArray[np.float64],
    horizon: float,
    gain: npt.NDArray[np.float64],
    nslot: npt.NDArray[np.int64],
) -> None:
    """Vectorised gains of ``max`` streams whose curves are ``scale·φ(t - t_gen)`` of one
    shape (the video family, position), all streams of that shape in one numpy pass over
    the (previous, next) pairs of each stream:

    * dominated pairs (newer and at least as large): eq. 4.5 telescopes, gain I_j - I_p;
    * p still at or above j's arrival value when the horizon ends: φ is non-increasing, so p
      stays above j throughout, j adds nothing and the stream's state stays p;
    * the rest (a crossing inside the horizon, e.g. a full red frame followed by a quarter
      one): the exact two-message envelope, :func:`_envelope_gains`.

    ``weight`` is per stream.
    """

    def arrays(vs: list[_Variant]) -> tuple[npt.NDArray[np.float64], ...]:
        cs = [cast(ShapeCurve, v.curve) for v in vs]
        return (np.array([c.t_gen for c in cs]), np.array([c.scale for c in cs]),
                np.array([v.r for v in vs]), np.array([c.expiry for c in cs]))

    gj, sj, rj, ej = arrays([v for *_, v in items])
    jstream = np.array([st for st, *_ in items])
    level = np.array([i for _, i, *_ in items])
    option = np.array([o for _, _, o, _, _ in items])
    jpos = np.array([q for *_, q, _ in items])
    wj = weight[jstream]
    bj = np.minimum(horizon, ej)
    with np.errstate(all="ignore"):
        jt = np.where(rj < bj, sj * shape.phi_integral_array(rj - gj, np.maximum(bj, rj) - gj), 0.0)
    for st, slot, _, v in preds:
        if v is None:
            mine = jstream == st
            gain[level[mine], option[mine], slot] = (wj * jt)[mine]
    real = [p for p in preds if p[3] is not None]
    if not real:
        return
    gp, sp, rp, ep = arrays([cast(_Variant, v) for *_, v in real])
    pstream = np.array([st for st, *_ in real])
    slots = np.array([slot for _, slot, _, _ in real])
    ppos = np.array([q for _, _, q, _ in real])
    # every (previous p, next j) pair of one stream, as flat index vectors
    k, m = np.nonzero((pstream[:, None] == jstream[None, :]) & (ppos[:, None] < jpos[None, :]))
    gp_k, sp_k, rp_k, gj_m, sj_m, rj_m = gp[k], sp[k], rp[k], gj[m], sj[m], rj[m]
    lv, op, sl = level[m], option[m], slots[k]
    ordered = rp_k <= rj_m
    dom = ordered & (gj_m >= gp_k) & (sj_m >= sp_k)
    b = np.minimum(horizon, ep[k])
    with np.errstate(all="ignore"):
        xa = np.maximum(rj_m - gp_k, 0.0)
        xb = np.maximum(np.maximum(b, rj_m) - gp_k, xa)
        tails = np.where(rj_m < b, sp_k * shape.phi_integral_array(xa, xb), 0.0)
    gain[lv[dom], op[dom], sl[dom]] = (wj[m] * (jt[m] - tails))[dom]
    p_end = sp_k * shape.phi_array(b - gp_k)
    j_start = sj_m * shape.phi_array(rj_m - gj_m)
    above = ordered & ~dom & (p_end >= j_start)
    gain[lv[above], op[above], sl[above]] = 0.0
    nslot[lv[above], op[above], sl[above]] = sl[above]
    rest = ~(dom | above)
    if rest.any():
        g, moves = _envelope_gains(shape, gp_k[rest], sp_k[rest], rp_k[rest], gj_m[rest],
                                   sj_m[rest], rj_m[rest], horizon)
        gain[lv[rest], op[rest], sl[rest]] = wj[m[rest]] * g
        stay = ~moves
        nslot[lv[rest][stay], op[rest][stay], sl[rest][stay]] = sl[rest][stay]


def _fan_out(
    spec: MissionSpec,
    ordered: Sequence[PlanItem],
    options: Sequence[Sequence[_Variant]],
    stream: npt.NDArray[np.int64],
    receivers: Mapping[tuple[str, str | None], Sequence[FixedItem | None]],
    horizon: float,
    gain: npt.NDArray[np.float64],
) -> None:
    """The utility of a message counts at each of its receivers (eq. 4.2, thesis ch. 4/5).

    One datagram on the shared medium reaches every receiver, so after a message of the
    tree the stream's previous message is the same at each: a gain from a slot > 0 counts
    once per receiver. Only the bases differ (what each receiver held before the tree):
    slot 0 is the sum of each receiver's own gain. The stream's next state (``nslot``) is
    the first receiver's; the types shared with peers are Markovian (a newer message
    dominates), where it is the same for all.
    """
    for i, it in enumerate(ordered):
        bases = receivers.get(stream_of(spec, it.message))
        if not bases:
            continue
        info = spec.types[it.message.type]
        if int(stream[i]) < 0:  # sum: independent items, counted at each receiver
            gain[i, :, 0] *= len(bases)
            continue
        gain[i, :, 1:] *= len(bases)
        variants = [None if b is None else _Variant(info, b.message, b.rcv_t) for b in bases]
        for o, variant in enumerate(options[i], start=1):
            gain[i, o, 0] = info.weight * sum(_pair_gain(p, variant, horizon)[0]
                                              for p in variants)


def build_problem(
    spec: MissionSpec,
    *,
    items: Sequence[PlanItem],
    fixed: Sequence[FixedItem],
    horizon_end: float,
    budget_bytes: float,
    window_s: float,
    root_window: Sequence[tuple[float, int]] = (),
    receivers: Mapping[tuple[str, str | None], Sequence[FixedItem | None]] | None = None,
) -> Problem:
    """Tables of one decision: items sorted by send time, gains per (item, option, slot).

    ``fixed`` are messages already sent; the newest one per stream is the stream's base.
    ``root_window`` lists (send time, bytes) of the fleet's sends that still count in
    windows reaching into the tree (eq. 5.7). ``receivers``: streams heard by several
    receivers (a type shared with peers, issue 15), each receiver's base; see
    :func:`_fan_out`. Without it every stream has the one receiver of ``fixed``.
    """
    ordered = sorted(items, key=lambda it: (it.send_t, it.message.t_gen, it.message.sender))
    stream_index: dict[tuple[str, str | None], int] = {}
    stream_keys: list[tuple[str, str | None]] = []
    markov: list[bool] = []
    base: dict[int, _Variant] = {}
    members: dict[int, list[int]] = {}
    n = len(ordered)
    max_versions = max([len(it.message.versions) or 1 for it in ordered] + [1])
    max_opt = 1 + max_versions
    stream = np.full(n, -1, dtype=np.int64)
    pos = np.zeros(n, dtype=np.int64)
    nopt = np.zeros(n, dtype=np.int64)
    size = np.zeros((n, max_opt), dtype=np.int64)
    send_t = np.zeros(n, dtype=np.float64)
    options: list[list[_Variant]] = []
    for i, it in enumerate(ordered):
        m = it.message
        info = spec.types[m.type]
        send_t[i] = it.send_t
        nopt[i] = n_options(m)
        variants = [_Variant(info, option_message(m, o), it.rcv_t) for o in range(1, int(nopt[i]))]
        options.append(variants)
        for o, variant in enumerate(variants, start=1):
            size[i, o] = variant.m.size
        if info.aggregation == "sum":
            continue
        key = stream_of(spec, m)
        s = stream_index.get(key)
        if s is None:
            s = stream_index[key] = len(stream_keys)
            stream_keys.append(key)
            markov.append(info.markovian)
            members[s] = []
        stream[i] = s
        pos[i] = len(members[s])
        members[s].append(i)
    for f in sorted(fixed, key=lambda f: f.message.t_gen):
        if f.message.type not in spec.types:
            continue
        fixed_key = stream_of(spec, f.message)
        if fixed_key in stream_index:
            base[stream_index[fixed_key]] = _Variant(spec.types[f.message.type], f.message,
                                                     f.rcv_t)
    max_pos = max([len(v) for v in members.values()] + [0])
    n_slots = 1 + max_pos * max_versions
    gain = np.zeros((n, max_opt, n_slots), dtype=np.float64)
    nslot = np.empty((n, max_opt, n_slots), dtype=np.int64)
    # sending option o makes the item itself the stream's state; dropping keeps the state
    nslot[:, 1:, :] = (1 + pos[:, None] * max_versions + np.arange(max_opt - 1)[None, :])[
        :, :, None]
    nslot[:, 0, :] = np.arange(n_slots)[None, :]
    h = horizon_end
    vectorised: set[int] = set()
    families: dict[int, tuple[Shape, list[_Pred], list[_Item]]] = {}
    weights = np.array([spec.types[k[0]].weight for k in stream_keys] + [0.0])
    for s_index, idxs in members.items():
        if spec.types[stream_keys[s_index][0]].aggregation != "max":
            continue
        stream_preds: list[_Pred] = [(s_index, 0, -1, base.get(s_index))]
        stream_items: list[_Item] = []
        for q, idx in enumerate(idxs):
            for v, variant in enumerate(options[idx]):
                stream_preds.append((s_index, 1 + q * max_versions + v, q, variant))
                stream_items.append((s_index, idx, v + 1, q, variant))
        shape = _shape_family(stream_preds, stream_items)
        if shape is None:
            continue
        family = families.setdefault(id(shape), (shape, [], []))
        family[1].extend(stream_preds)
        family[2].extend(stream_items)
        vectorised.add(s_index)
    for shape, fam_preds, fam_items in families.values():
        _shape_streams(shape, fam_preds, fam_items, weights, h, gain, nslot)
    for i, it in enumerate(ordered):
        info = spec.types[it.message.type]
        w = info.weight
        s = int(stream[i])
        if s in vectorised:
            continue
        fast = info.aggregation == "max" and not info.utility.impulse
        preds: list[tuple[int, _Variant | None]] = []
        if s >= 0:
            preds.append((0, base.get(s)))
            for q, p_index in enumerate(members[s][: int(pos[i])]):
                for v, earlier in enumerate(options[p_index]):
                    preds.append((1 + q * max_versions + v, earlier))
        r = it.rcv_t
        row = gain[i]
        for o, variant in enumerate(options[i], start=1):
            if s < 0:
                row[o, 0] = w * _pair_gain(None, variant, h)[0]
                continue
            cj = variant.curve
            jt = variant.tail(r, h) if fast else 0.0
            for slot, pv in preds:
                # the common case inline: a newer message that dominates (eq. 4.5 telescopes)
                if fast and pv is not None and cj is not None and pv.curve is not None \
                        and pv.r <= r and cj.dominates(pv.curve):
                    row[o, slot] = w * (jt - pv.tail(r, h))
                    continue
                if fast and pv is None:
                    row[o, slot] = w * jt
                    continue
                g, moves = _pair_gain(pv, variant, h)
                row[o, slot] = w * g
                if not moves:
                    nslot[i, o, slot] = slot
    if receivers:
        _fan_out(spec, ordered, options, stream, receivers, h, gain)
    decided = [i for i, it in enumerate(ordered) if it.kind == "decide"]
    horizon_floor = min([it.send_t for it in ordered], default=0.0) - window_s
    win = sorted((t, b) for t, b in root_window if t >= horizon_floor)
    return Problem(
        items=ordered,
        stream=stream,
        pos=pos,
        nopt=nopt,
        size=size,
        send_t=send_t,
        gain=gain,
        nslot=nslot,
        stream_keys=stream_keys,
        stream_markov=np.array(markov, dtype=np.bool_),
        root_win_t=np.array([t for t, _ in win], dtype=np.float64),
        root_win_bytes=np.array([b for _, b in win], dtype=np.int64),
        budget_bytes=float(budget_bytes) if math.isfinite(budget_bytes) else 1e300,
        window_s=window_s,
        max_versions=max_versions,
        decided_level=decided[0] if decided else -1,
        horizon_end=horizon_end,
    )
