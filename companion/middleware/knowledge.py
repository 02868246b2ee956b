"""What one agent knows about the fleet's messages (thesis alg. 3): a bounded window of history.

Own generated and sent messages, other agents' messages learned from receptions or receiver
reports, latency samples. Everything older than the planning needs (window T, latency,
horizon) is forgotten, so the cost of a decision does not grow with mission length.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

from companion.middleware.forecast import LatencyEstimator, StreamForecaster
from companion.middleware.incremental import FixedItem, PlanItem, option_message, stream_of
from utility_specs.errors import UtilitySpecsError
from utility_specs.message import Message, MessageKey
from utility_specs.spec import MissionSpec

__all__ = ["WORTH_SPAN_S", "FleetKnowledge", "PlanningView", "settle_inflight", "usable"]

WORTH_SPAN_S = 3.0
"""A message's worth (:meth:`FleetKnowledge.worth`) is its utility over this long."""


def usable(spec: MissionSpec, message: Message) -> bool:
    """The message's type is in the spec and its utility can be read from its data (a
    message that cannot be valued must not become the data every forecast repeats)."""
    info = spec.types.get(message.type)
    if info is None:
        return False
    try:
        info.utility.curve(message)
    except NotImplementedError:  # state-dependent: valued against the receiver's state
        return True
    except UtilitySpecsError:
        return False
    return True


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanningView:
    """The inputs of one decision's tree, assembled from what the agent knows."""

    items: list[PlanItem]
    fixed: list[FixedItem]
    root_window: list[tuple[float, int]]
    horizon_end: float
    receivers: dict[tuple[str, str | None], list[FixedItem | None]] = field(default_factory=dict)
    """Per stream of a type shared with peers: one base per receiver (ground first when the
    type is for the ground, then every peer; ``None``: that receiver holds nothing), for
    :func:`~companion.middleware.incremental.build_problem`. Empty for ground-only types."""


class FleetKnowledge:
    """Fleet knowledge of one agent, updated by its own decisions and by deliveries."""

    __slots__ = (
        "_delivered",
        "_fleet",
        "_held",
        "_inflight",
        "_newest",
        "_seen",
        "_seen_order",
        "_sends",
        "agent",
        "forecaster",
        "latency",
        "spec",
    )

    def __init__(self, spec: MissionSpec, *, agent: str, default_latency_s: float,
                 spread_forecasts: bool = True) -> None:
        self.spec = spec
        self.agent = agent
        self.forecaster = StreamForecaster(
            worth=self.worth if spread_forecasts else None,
            declared={name: info.period_s for name, info in spec.types.items()
                      if info.period_s is not None})
        """``spread_forecasts``: a stream's forecasts are drawn from its recent messages'
        worths (:meth:`StreamForecaster.forecast`), so the optimiser sees the value of
        waiting for a better frame; False: copies of the last message (the baselines)."""
        self.latency = LatencyEstimator(default_s=default_latency_s)
        self._delivered: dict[tuple[str, str | None], tuple[Message, float]] = {}
        self._inflight: dict[MessageKey, tuple[Message, float]] = {}
        self._sends: dict[MessageKey, tuple[float, int]] = {}
        self._seen: set[MessageKey] = set()
        self._seen_order: deque[MessageKey] = deque()
        self._newest: dict[tuple[str, str | None], Message] = {}
        """Per stream, the newest message generated here: what the sender knows has changed."""
        self._held: dict[str, dict[tuple[str, str | None], tuple[Message, float]]] = {}
        """Per peer receiver (a drone), per stream: the newest message it reported holding."""
        self._fleet: set[str] = {agent}
        """Every agent known (senders heard of, peers that reported): the peer receivers."""

    # --- updates -------------------------------------------------------------------------
    def use_spec(self, spec: MissionSpec) -> None:
        """Value messages with ``spec`` from now on (a live parameter changed it)."""
        self.spec = spec

    def on_generated(self, message: Message) -> None:
        self.forecaster.observe(message)
        stream = stream_of(self.spec, message)
        newest = self._newest.get(stream)
        if newest is not None and newest.t_gen > message.t_gen:
            return
        self._newest[stream] = message
        known = self._delivered.get(stream)
        if known is not None:
            self._delivered[stream] = (self._as_known(known[0]), known[1])
        for key, (m, t) in list(self._inflight.items()):
            if stream_of(self.spec, m) == stream:
                self._inflight[key] = (self._as_known(m), t)

    def _as_known(self, m: Message) -> Message:
        """``m`` with what the newest own message of its stream tells about it (a status
        whose state has ended since, :meth:`UtilityFunction.superseded`)."""
        newest = self._newest.get(stream_of(self.spec, m))
        if newest is None or newest.t_gen <= m.t_gen:
            return m
        try:
            ended = self.spec.types[m.type].utility.superseded(m, newest)
        except UtilitySpecsError:
            return m
        return m if ended is None else ended

    def on_sent(self, message: Message, *, now: float) -> None:
        self._inflight[message.key] = (message, now)
        self._sends[message.key] = (now, message.size)

    def on_delivered(self, messages: Iterable[Message], *, now: float) -> int:
        """Learn deliveries (own or other agents'); returns how many were new."""
        new = 0
        for m in messages:
            if m.t_rcv is None or not usable(self.spec, m):
                continue
            self._fleet.add(m.sender)
            if m.receiver is not None and m.receiver != "ground" \
                    and self.spec.types[m.type].for_peers:
                self._hold(m.receiver, m)
            if m.key in self._seen:
                continue
            new += 1
            self._seen.add(m.key)
            self._seen_order.append(m.key)
            self.forecaster.observe(m)
            t_sent = m.t_sent if m.t_sent is not None else m.t_gen
            self.latency.update(m.t_rcv - t_sent)
            self._inflight.pop(m.key, None)
            self._sends.setdefault(m.key, (t_sent, m.size))
            stream = stream_of(self.spec, m)
            known = self._delivered.get(stream)
            if known is None or known[0].t_gen < m.t_gen:
                self._delivered[stream] = (self._as_known(m), m.t_rcv)
        while len(self._seen_order) > 4096:
            self._seen.discard(self._seen_order.popleft())
        return new

    def _hold(self, receiver: str, m: Message) -> None:
        """A peer (``receiver``, a drone) holds ``m``: its own reports or our reception."""
        self._fleet.add(receiver)
        held = self._held.setdefault(receiver, {})
        stream = stream_of(self.spec, m)
        known = held.get(stream)
        if known is None or known[0].t_gen < m.t_gen:
            held[stream] = (m, m.t_rcv if m.t_rcv is not None else m.t_gen)

    def peers_of(self, sender: str) -> list[str]:
        """The drones a ``peers`` message of ``sender`` is for: every known agent but it."""
        return sorted(self._fleet - {sender})

    def forget(self, *, now: float, keep_s: float) -> None:
        """Drop what no decision can need any more (older than ``keep_s``)."""
        floor = now - keep_s
        for key in [k for k, (_, t) in self._inflight.items() if t < floor]:
            del self._inflight[key]
        for key in [k for k, (t, _) in self._sends.items() if t < floor]:
            del self._sends[key]
        self.forecaster.forget(floor - 10.0 * keep_s)

    # --- reads ---------------------------------------------------------------------------
    def worth(self, message: Message) -> float | None:
        """What ``message`` in its best version is worth over :data:`WORTH_SPAN_S` after its
        generation (the forecaster ranks a stream's recent messages by it); None when its
        utility is not a curve of the message alone."""
        info = self.spec.types.get(message.type)
        if info is None or info.utility.impulse:
            return None
        try:
            curve = info.utility.curve(option_message(message, 1))
        except (NotImplementedError, UtilitySpecsError):
            return None
        return info.weight * curve.integral(message.t_gen, message.t_gen + WORTH_SPAN_S)

    def sender_rates(self, *, now: float, lag_s: float, window_s: float
                     ) -> dict[str, tuple[float, float]]:
        """Per other agent: (bytes/s, mean message bytes) it is known to have sent over the
        ``window_s`` before the last ``lag_s`` (what has had time to arrive)."""
        hi = now - lag_s
        lo = hi - window_s
        sums: dict[str, list[float]] = {}
        for (sender, _, _), (t, b) in self._sends.items():
            if sender != self.agent and lo <= t <= hi:
                acc = sums.setdefault(sender, [0.0, 0.0])
                acc[0] += b
                acc[1] += 1
        return {sender: (total / window_s, total / count)
                for sender, (total, count) in sums.items()}

    def known_sends(self) -> list[tuple[float, int]]:
        """(send time, bytes) of every send the agent knows of (own, and others' delivered)."""
        return list(self._sends.values())

    def sent_in_window(self, *, now: float, window_s: float) -> int:
        """Bytes the fleet is known to have sent in [now - T, now] (eq. 5.7)."""
        return sum(b for t, b in self._sends.values() if t >= now - window_s - 1e-9)

    def base_message(self, message: Message) -> tuple[Message, float] | None:
        """The newest message of ``message``'s stream already sent (delivered or in flight)."""
        stream = stream_of(self.spec, message)
        best = self._delivered.get(stream)
        mean = self.latency.mean_s
        for m, t_sent in self._inflight.values():
            if stream_of(self.spec, m) == stream and (best is None or m.t_gen > best[0].t_gen):
                best = (m, t_sent + mean)
        return best

    def view(self, message: Message, *, now: float, horizon_s: float, max_items: int,
             window_s: float) -> PlanningView:
        """Items of the tree for deciding ``message`` at ``now`` (alg. 3, line 7)."""
        mean = self.latency.mean_s
        high = max(self.latency.high_s, mean)
        horizon_end = now + horizon_s
        self.forecaster.refresh()
        decided = message.with_version(0) if message.versions else message
        items = [PlanItem(message=decided, send_t=now, rcv_t=now + mean, kind="decide")]
        for key in self.forecaster.streams():
            if key[1] not in self.spec.types:
                continue
            if key[0] != self.agent:
                for m in self.forecaster.forecast(key, t_from=now - high, t_to=now,
                                                  spread=False):
                    items.append(
                        PlanItem(message=m, send_t=m.t_gen, rcv_t=max(m.t_gen + mean, now),
                                 kind="inflight")
                    )
            for m in self.forecaster.forecast(key, t_from=now, t_to=horizon_end):
                items.append(PlanItem(message=m, send_t=m.t_gen, rcv_t=m.t_gen + mean))
        items.sort(key=lambda it: it.send_t)
        if len(items) > max_items:
            keep = [it for it in items if it.kind != "forecast"]
            rest = [it for it in items if it.kind == "forecast"]
            items = sorted(keep + rest[: max(0, max_items - len(keep))], key=lambda it: it.send_t)
        fixed = [FixedItem(message=m, send_t=m.t_sent if m.t_sent is not None else m.t_gen,
                           rcv_t=r) for m, r in self._delivered.values()]
        fixed += [FixedItem(message=m, send_t=t, rcv_t=t + mean)
                  for m, t in self._inflight.values()]
        root_window = [(t, b) for t, b in self._sends.values() if t >= now - window_s - 1e-9]
        return PlanningView(items=items, fixed=fixed, root_window=root_window,
                            horizon_end=horizon_end, receivers=self._receivers(items, fixed))

    def _receivers(self, items: list[PlanItem], fixed: list[FixedItem]
                   ) -> dict[tuple[str, str | None], list[FixedItem | None]]:
        """Per stream shared with peers, what each of its receivers holds (issue 15): the
        ground the newest message known to have arrived or be in flight (the one base of
        the single-receiver model); a peer what it last reported holding, or what is in
        flight (a broadcast reaches it too), or, before its first report, the ground's."""
        out: dict[tuple[str, str | None], list[FixedItem | None]] = {}
        for it in items:
            info = self.spec.types[it.message.type]
            key = stream_of(self.spec, it.message)
            if not info.for_peers or key in out:
                continue
            newest: FixedItem | None = None
            for f in fixed:
                if f.message.type in self.spec.types and stream_of(self.spec, f.message) == key \
                        and (newest is None or f.message.t_gen >= newest.message.t_gen):
                    newest = f
            bases: list[FixedItem | None] = [newest] if "ground" in info.receivers else []
            flying = [FixedItem(message=m, send_t=t, rcv_t=t + self.latency.mean_s)
                      for m, t in self._inflight.values() if stream_of(self.spec, m) == key]
            for peer in self.peers_of(it.message.sender):
                held = self._held.get(peer, {}).get(key)
                if held is None:
                    bases.append(newest)
                    continue
                m, t_rcv = held
                base = FixedItem(message=m, send_t=m.t_sent if m.t_sent is not None
                                 else m.t_gen, rcv_t=t_rcv)
                for f in flying:
                    if f.message.t_gen > base.message.t_gen:
                        base = f
                bases.append(base)
            if bases:
                out[key] = bases
        return out


def settle_inflight(view: PlanningView, *, now: float, rates: dict[str, tuple[float, float]],
                    lag_s: float, keep: int = 0, settle_versions: bool = False) -> PlanningView:
    """The view with what other agents sent in the last ``lag_s`` (not known before it
    arrives) estimated, and their possibly in-flight messages taken as already decided.

    Their senders decided those messages: they are not this agent's to search. Left in the
    tree, a backlog put a hundred of them ahead of the decided message and the search never
    reached it (95 % greedy fallbacks, issue 18). Each sender is assumed to have gone on
    sending at the rate it was last seen to send (``rates``: bytes/s and mean message
    bytes): ``rate · lag_s`` bytes, rounded to whole messages, spread evenly over
    ``[now - lag_s, now]`` join the windows (``root_window``). Whole messages: 8 bytes of a
    fraction blocked a 2048-byte message the budget had exact room for (the fig. 5.7 fleet
    fell from 95 to 76 % of the offline optimum).
    Taking the in-flight messages all as sent starves this agent (a full window of others'
    images that were in fact dropped); taking them all as dropped lets every agent fill the
    same window (the fleet sent 2.5 times its budget in the companion benchmark).

    The newest ``keep`` in-flight messages stay in the tree: a few levels cost the search
    little, and without a backlog (the fig. 5.7 fleet) that is all there is. With
    ``settle_versions`` (the middleware's default since issue 18 round 5) messages with
    versions are always settled: which version their sender chose is unknown, the tree's
    smaller versions of them add nothing over drop (ties), and with four such options per
    level the search spread its visits so that its most visited path fell short of the
    decided message (greedy fallbacks); their bytes join the windows by the sender's rate
    like any settled message's.
    """
    window = list(view.root_window)
    if lag_s > 0:
        for rate, size in rates.values():
            # whole messages: a fraction of one would block a send the budget has room for
            n = math.floor(rate * lag_s / size + 0.5) if size > 0 else 0
            window += [(now - lag_s + (i + 0.5) * lag_s / n, int(size)) for i in range(n)]
    inflight = [it for it in view.items if it.kind == "inflight"]
    plain = [it for it in inflight if not (settle_versions and it.message.versions)]
    kept = {id(it) for it in plain[max(0, len(plain) - keep):]} if keep > 0 else set()
    settled = {id(it) for it in inflight if id(it) not in kept}
    return replace(view, items=[it for it in view.items if id(it) not in settled],
                   root_window=sorted(window))
