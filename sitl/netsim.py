"""Discrete-event simulator of a shared broadcast channel (the ns-3 setup of thesis ch. 5.4).

N agents generate periodic message streams; each agent's policy decides per message (send /
drop / version) at generation time, in simulated time. Sent messages wait in the agent's
FIFO; one shared medium carries one packet at a time at ``capacity_bytes_per_s`` (payload
plus ``overhead_bytes`` per packet), the agent whose head packet waited longest goes next,
and the packet arrives ``propagation_s`` after its transmission ends, or is lost with
probability ``loss``. The medium is a broadcast: the receiver (``ground``) gets the message
and every agent overhears it, so each agent learns what the fleet delivered (its planning
knowledge) at the reception time.

Receiver reports: every ``report_interval_s`` (the ground station's default 0.25 s) each
agent whose messages arrived since the last report gets them as a receiver report
(:class:`~companion.middleware.reports.ReceiverReport`, the entries a real ground station
would send) fed to its policy's constraint by ``companion.middleware.reports.feed_link``, so
an adaptive constraint learns in every simulated run. Policies without a constraint ignore them.
"""

from __future__ import annotations

import heapq
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from companion.middleware.baselines import Policy
from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.incremental import option_message, window_violations
from companion.middleware.reports import ReceiverReport, feed_link
from companion.protocol.records import entry_from_message
from utility_specs.message import Message, MessageKey, Version

__all__ = ["ChannelConfig", "SimAgent", "SimResult", "StreamConfig", "ideal_copies", "simulate"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelConfig:
    capacity_bytes_per_s: float = 250_000.0
    overhead_bytes: int = 64
    """Per packet: headers (UDP/IP/MAC)."""
    propagation_s: float = 0.001
    loss: float = 0.0
    """Probability that a packet is lost."""
    receiver: str = "ground"
    report_interval_s: float | None = 0.25
    """Receiver reports (link samples for each sender's constraint) this often; None: none."""

    def __post_init__(self) -> None:
        if not (self.capacity_bytes_per_s > 0 and self.overhead_bytes >= 0):
            raise ValueError("capacity must be > 0 and overhead >= 0")
        if not (self.propagation_s >= 0 and 0.0 <= self.loss <= 1.0):
            raise ValueError("propagation_s >= 0 and loss in [0, 1] expected")
        if self.report_interval_s is not None and not self.report_interval_s > 0:
            raise ValueError("report_interval_s must be > 0 or None")


@dataclass(frozen=True, slots=True, kw_only=True)
class StreamConfig:
    """One periodic stream of one agent: message k is generated at
    ``phase_s + k·period_s + |N(0, jitter_s)|``."""

    type: str
    period_s: float
    size: int
    phase_s: float = 0.0
    jitter_s: float = 0.0
    data: Callable[[int, np.random.Generator], Mapping[str, Any]] = field(
        default=lambda k, rng: {}
    )
    versions: tuple[Version, ...] = ()
    times: tuple[float, ...] = ()
    """Explicit generation times of messages k = 0, 1, ... (a recorded sequence, e.g. the
    thesis code's own); when given, period, phase and jitter are not used."""


@dataclass(slots=True, kw_only=True)
class SimAgent:
    name: str
    policy: Policy
    streams: Sequence[StreamConfig]
    overheard: bool = True
    """False: traffic outside the information distribution (background, e.g. iperf): it
    shares the medium but no agent's knowledge sees its deliveries."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SimResult:
    generated: list[Message]
    """Every generated message; sent ones carry ``t_sent`` and their version, delivered ones
    ``receiver`` and ``t_rcv``."""
    decide_wall_s: list[float]
    """Wall time of each ``decide`` call, in generation order (for benchmarks)."""
    decide_cpu_s: list[float]
    """CPU time of this thread in each ``decide`` call (load on other processes excluded)."""
    decide_t: list[float]
    """Simulated time of each decision."""
    lost: int
    link_samples: int = 0
    """Link samples handed to the agents' constraints by simulated receiver reports."""

    @property
    def delivered(self) -> list[Message]:
        return [m for m in self.generated if m.t_rcv is not None]

    @property
    def sent(self) -> list[Message]:
        return [m for m in self.generated if m.t_sent is not None]

    @property
    def drop_share(self) -> float:
        """Share of generated messages that were not delivered (dropped or lost)."""
        return 1.0 - len(self.delivered) / len(self.generated) if self.generated else 0.0

    def violations(self, *, window_s: float, budget_bytes: float) -> int:
        """Send instants whose window [t, t + T] carries more than the budget (eq. 5.5/5.7)."""
        return window_violations(
            [(m.t_sent, m.size) for m in self.sent if m.t_sent is not None],
            window_s=window_s, budget_bytes=budget_bytes,
        )


_GEN, _TX_END, _DELIVER, _REPORT = 0, 1, 2, 3


def _report(agent: SimAgent, messages: list[Message], now: float) -> int:
    """Hand ``messages`` (this agent's, delivered) to its policy's constraint as a receiver
    report, through the middleware's one report-to-link-sample path."""
    constraint = getattr(agent.policy, "constraint", None)
    if not isinstance(constraint, GoodputConstraint) or not messages:
        return 0
    entries = tuple(entry_from_message(m, t_rcv=m.t_rcv) for m in messages
                    if m.t_sent is not None and m.t_rcv is not None)
    report = ReceiverReport(entries=entries)
    return feed_link(constraint, report, agent=agent.name, now=now).link_samples


def simulate(
    agents: Sequence[SimAgent],
    *,
    channel: ChannelConfig,
    t_end: float,
    rng: np.random.Generator,
    progress: Callable[[float], None] | None = None,
) -> SimResult:
    """Run the mission in simulated time until ``t_end``; deterministic for a given ``rng``."""
    events: list[tuple[float, int, int, Any]] = []
    counter = 0

    def push(t: float, kind: int, payload: Any) -> None:
        nonlocal counter
        heapq.heappush(events, (t, counter, kind, payload))
        counter += 1

    seqs = {a.name: 0 for a in agents}
    for a_index, agent in enumerate(agents):
        for s_index, stream in enumerate(agent.streams):
            for k, t in enumerate(stream.times):
                if t < t_end:
                    push(t, _GEN, (a_index, s_index, k))
            if stream.times:
                continue
            if stream.period_s <= 0:
                raise ValueError(f"{agent.name}/{stream.type}: period must be > 0")
            k = 0
            while True:
                t = stream.phase_s + k * stream.period_s
                if stream.jitter_s > 0:
                    t += abs(float(rng.normal(0.0, stream.jitter_s)))
                if t >= t_end:
                    break
                push(t, _GEN, (a_index, s_index, k))
                k += 1
    generated: dict[MessageKey, Message] = {}
    order: list[MessageKey] = []
    queues: list[deque[tuple[float, Message]]] = [deque() for _ in agents]
    busy = False
    lost = 0
    wall: list[float] = []
    cpu: list[float] = []
    dec_t: list[float] = []
    next_progress = 0.0
    unreported: list[list[Message]] = [[] for _ in agents]
    index = {a.name: i for i, a in enumerate(agents)}
    link_samples = 0
    if channel.report_interval_s is not None:
        push(channel.report_interval_s, _REPORT, None)

    def start_tx(now: float) -> None:
        nonlocal busy
        heads = [(q[0][0], i) for i, q in enumerate(queues) if q]
        if busy or not heads:
            return
        _, i = min(heads)
        _, m = queues[i].popleft()
        busy = True
        duration = (m.size + channel.overhead_bytes) / channel.capacity_bytes_per_s
        push(now + duration, _TX_END, m)

    while events:
        now, _, kind, payload = heapq.heappop(events)
        if now > t_end:
            break
        if progress is not None and now >= next_progress:
            progress(now / t_end)
            next_progress = now + t_end / 20
        if kind == _GEN:
            a_index, s_index, k = payload
            agent = agents[a_index]
            stream = agent.streams[s_index]
            seq = seqs[agent.name]
            seqs[agent.name] = seq + 1
            m = Message(
                sender=agent.name, seq=seq, type=stream.type, t_gen=now, size=stream.size,
                data=dict(stream.data(k, rng)), versions=stream.versions,
                version=0 if stream.versions else None,
            )
            if stream.versions:
                m = replace(m, size=stream.versions[0].size)
            t0, c0 = time.perf_counter(), time.thread_time()
            decision = agent.policy.decide(m, now)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
            dec_t.append(now)
            if decision.send:
                m = replace(option_message(m, (decision.version or 0) + 1), t_sent=now)
                queues[a_index].append((now, m))
                start_tx(now)
            generated[m.key] = m
            order.append(m.key)
        elif kind == _TX_END:
            busy = False
            m = payload
            if channel.loss > 0 and rng.random() < channel.loss:
                lost += 1
            else:
                push(now + channel.propagation_s, _DELIVER, m)
            start_tx(now)
        elif kind == _DELIVER:
            m = payload.delivered(receiver=channel.receiver, t_rcv=now)
            generated[m.key] = m
            if agents[index[m.sender]].overheard:
                for agent in agents:
                    agent.policy.on_delivered([m], now)
            if channel.report_interval_s is not None and m.sender in index:
                unreported[index[m.sender]].append(m)
        else:
            assert channel.report_interval_s is not None
            for i, agent in enumerate(agents):
                link_samples += _report(agent, unreported[i], now)
                unreported[i] = []
            push(now + channel.report_interval_s, _REPORT, None)
    if progress is not None:
        progress(1.0)
    return SimResult(
        generated=[generated[k] for k in order], decide_wall_s=wall, decide_cpu_s=cpu,
        decide_t=dec_t, lost=lost, link_samples=link_samples
    )


def ideal_copies(messages: Sequence[Message], *, receiver: str = "ground") -> list[Message]:
    """Every message received in its best version with zero delay (the 100 % reference)."""
    out = []
    for m in messages:
        best = m.with_version(0) if m.versions else m
        out.append(best.delivered(receiver=receiver, t_rcv=m.t_gen))
    return out
