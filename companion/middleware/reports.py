"""A receiver report as the middleware learns from it: deliveries and link observations.

One report feeds two things (thesis alg. 3 and ch. 6.1): the delivered-set knowledge of the
optimiser (every entry, any agent's) and the goodput constraint's link statistics (this
agent's own entries as :class:`LinkSample`, its clock echo as a :class:`RoundTrip` with the
report's own send and receive times). :func:`feed_link` is the second half alone, for
shells that have a constraint but no optimiser (the link emulator's probe sender, the
adaptive study); :meth:`Middleware.on_report` does both.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample, RoundTrip
from companion.middleware.errors import LinkStatsError
from companion.protocol.events import ReportReceived
from companion.protocol.records import ClockEcho, ReportEntry, report_messages
from utility_specs.errors import UtilitySpecsError
from utility_specs.message import Message

__all__ = ["LinkFeed", "ReceiverReport", "ReportLearned", "deliveries", "feed_link",
           "link_observations"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ReceiverReport:
    """A decoded receiver report with the times of its own trip (NTP t3 and t4)."""

    entries: Sequence[ReportEntry] = ()
    """What arrived at the receiver since its previous report (any agent's messages)."""
    echoes: Sequence[ClockEcho] = ()
    """Per sender, its latest datagram's send time and the receiver's reception time."""
    t_sent: float | None = None
    """When the receiver sent the report (receiver's clock); None: no round trips."""
    t_rcv: float | None = None
    """When the report arrived here (this agent's clock); None: no round trips."""
    receiver: str = "ground"
    """Who received the listed messages."""

    @classmethod
    def from_event(cls, event: ReportReceived, *, receiver: str = "ground") -> ReceiverReport:
        """The report of one decoded datagram (``companion.protocol``); ``receiver``: a
        peer drone's id when a peer sent it on the shared medium (issue 15)."""
        return cls(entries=event.report.entries, echoes=event.report.echoes,
                   t_sent=event.t_sent, t_rcv=event.t_rcv, receiver=receiver)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkFeed:
    """What the constraint learned from one report."""

    link_samples: int = 0
    other_samples: int = 0
    """Other agents' entries handed over for the fleet's goodput (``fleet_goodput``)."""
    round_trips: int = 0
    bad_round_trips: int = 0
    """Echoes whose times are impossible (reception before sending): skipped."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ReportLearned:
    """What the middleware learned from one report (also added to its ``counters``)."""

    delivered: int = 0
    """Entries new to the delivered-set knowledge."""
    bad_entries: int = 0
    """Entries whose utility cannot be read: skipped, the others still count."""
    link: LinkFeed = LinkFeed()


def deliveries(report: ReceiverReport) -> tuple[list[Message], int]:
    """The report's entries as delivered messages, and how many could not be (one by one:
    a bad entry is counted, the others still count)."""
    messages: list[Message] = []
    bad = 0
    for entry in report.entries:
        try:
            messages += report_messages([entry], receiver=report.receiver)
        except UtilitySpecsError:
            bad += 1
    return messages, bad


def link_observations(report: ReceiverReport, *, agent: str, others: bool = False
                      ) -> tuple[list[LinkSample], list[RoundTrip], int]:
    """``agent``'s own entries as link samples, its echoes as round trips, and how many
    echoes were impossible. Entries without ``t_sent`` carry no latency: skipped. With
    ``others``, the other agents' entries too, in report order, marked ``own=False`` (they
    count in the fleet's goodput only)."""
    trips: list[RoundTrip] = []
    bad = 0
    if report.t_sent is not None and report.t_rcv is not None:
        for echo in report.echoes:
            if echo.sender != agent:
                continue
            try:
                trips.append(RoundTrip(t_sent=echo.t_sent, t_remote_rcv=echo.t_rcv,
                                       t_remote_sent=report.t_sent, t_rcv=report.t_rcv))
            except LinkStatsError:
                bad += 1
    samples = [LinkSample(t_sent=e.t_sent, t_rcv=e.t_rcv, size=e.size, sender=e.sender,
                          seq=e.seq, own=e.sender == agent)
               for e in report.entries
               if (others or e.sender == agent) and e.t_sent is not None]
    return samples, trips, bad


def feed_link(constraint: GoodputConstraint, report: ReceiverReport, *, agent: str,
              now: float) -> LinkFeed:
    """Hand ``agent``'s link observations of ``report`` to ``constraint``: round trips first
    (they refine the clock offset the samples' latencies are read with), then the samples
    as one batch (one model update per own sample). A constraint whose link statistics
    count the fleet's goodput (``fleet_goodput``) gets the other agents' entries too."""
    samples, trips, bad = link_observations(report, agent=agent,
                                            others=constraint.fleet_goodput)
    for trip in trips:
        constraint.on_round_trip(trip, now=now)
    if samples:
        constraint.on_samples(samples, now=now)
    own = sum(1 for s in samples if s.own)
    return LinkFeed(link_samples=own, other_samples=len(samples) - own,
                    round_trips=len(trips), bad_round_trips=bad)
