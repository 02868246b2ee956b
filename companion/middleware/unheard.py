"""Streams the mission spec names but this agent has not heard of yet (issue 18).

Other agents learn of a stream only from its deliveries. An agent whose stream the others
have not heard of finds every window full of their plans and never gets a message out (a
starvation loop); announcing it over the budget is a planned window violation. Instead each
agent plans for the streams the spec says may exist: a type of the mission that no known
message has had is forecast as one stream at the fleet's median period, carrying the data and
size of the newest known message valued by the same utility function. The tree then leaves
room for it where it is worth it (a heavy type) and not where it is not (a light one), so the
real stream's first message finds room within the budget. Once a message of the type is
known, the ordinary forecast takes over.

With a declared roster (which agent flies which types, round 9) nothing is guessed: each
stream of the roster not yet heard from its agent is forecast under the agent's name
(``?`` + agent), at the period of a known stream of the same type (every drone flies the
same types in the product) or the fleet's median period.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

from companion.middleware.incremental import PlanItem
from companion.middleware.knowledge import PlanningView
from utility_specs.message import Message
from utility_specs.spec import MissionSpec

__all__ = ["UNHEARD_PREFIX", "Roster", "UnheardStreams", "check_roster"]

Roster = Mapping[str, tuple[str, ...]]
"""Agent name -> the types it generates (a mission's declared fleet)."""

UNHEARD_PREFIX = "?"
"""Sender name of a forecast unheard stream: ``?`` + its type (no real agent is named so)."""


@dataclass(slots=True)
class UnheardStreams:
    """Which types of the spec are known, and a template message per utility function."""

    heard: set[str] = field(default_factory=set)
    heard_streams: set[tuple[str, str]] = field(default_factory=set)
    """(sender, type) of every known message: what a roster's stream needs to be heard."""
    templates: dict[str, Message] = field(default_factory=dict)
    """Per utility function name: the newest known message valued by it."""

    def observe(self, spec: MissionSpec, message: Message) -> None:
        info = spec.types.get(message.type)
        if info is None:
            return
        self.heard.add(message.type)
        self.heard_streams.add((message.sender, message.type))
        name = info.utility.name
        known = self.templates.get(name)
        if known is None or known.t_gen <= message.t_gen:
            self.templates[name] = message

    def unheard(self, spec: MissionSpec) -> list[str]:
        return [t for t in spec.types if t not in self.heard]

    def plausible(self, spec: MissionSpec, *, unheard_agents: int | None) -> bool:
        """May every unheard type be flown? Without a declared fleet (None) the spec is
        all there is; with one, only if the unheard agents can fly them, one type each (the
        fig. 5.7 fleets: agent i sends battery_i). A spec that names more types than the
        fleet flies (the offline-optimum missions: 4 agents, 10 types) would otherwise have
        the agents leave room for streams that never come (61.5 % of the optimum, round 5;
        capped this way, 92.5 %, round 8)."""
        return unheard_agents is None or len(self.unheard(spec)) <= max(0, unheard_agents)

    def items(self, spec: MissionSpec, *, now: float, horizon_end: float, period_s: float | None,
              latency_s: float) -> list[PlanItem]:
        """Forecast messages of every unheard type with a template, at ``period_s`` from half
        a period after ``now`` (the phase is unknown: its expected place)."""
        if period_s is None or not period_s > 0:
            return []
        out: list[PlanItem] = []
        for type_name in self.unheard(spec):
            info = spec.types[type_name]
            template = self.templates.get(info.utility.name)
            if template is None or info.for_peers:
                continue
            out += _periodic(template, sender=UNHEARD_PREFIX + type_name, type_name=type_name,
                             now=now, period_s=period_s, horizon_end=horizon_end,
                             latency_s=latency_s)
        return out

    def roster_items(self, spec: MissionSpec, roster: Roster, *, agent: str, now: float,
                     horizon_end: float, period_of: Callable[[str], float | None],
                     latency_s: float) -> list[PlanItem]:
        """Forecast messages of every stream of ``roster`` (but ``agent``'s own) that no
        known message came from, at ``period_of(type)`` from half a period after ``now``."""
        out: list[PlanItem] = []
        for peer, types in roster.items():
            if peer == agent:
                continue
            for type_name in types:
                info = spec.types.get(type_name)
                if info is None or info.for_peers or (peer, type_name) in self.heard_streams:
                    continue
                template = self.templates.get(info.utility.name)
                period = period_of(type_name)
                if template is None or period is None or not period > 0:
                    continue
                out += _periodic(template, sender=UNHEARD_PREFIX + peer, type_name=type_name,
                                 now=now, period_s=period, horizon_end=horizon_end,
                                 latency_s=latency_s)
        return out

    def add_to(self, view: PlanningView, spec: MissionSpec, *, now: float,
               period_s: float | None, latency_s: float, max_items: int,
               extra: list[PlanItem] | None = None) -> PlanningView:
        """``view`` with the unheard streams' forecast messages (``extra`` if given, else
        :meth:`items`); at most ``max_items`` levels (the latest forecast ones go first)."""
        if extra is None:
            extra = self.items(spec, now=now, horizon_end=view.horizon_end,
                               period_s=period_s, latency_s=latency_s)
        if not extra:
            return view
        items = sorted([*view.items, *extra], key=lambda it: it.send_t)
        while len(items) > max_items:
            last = max((i for i, it in enumerate(items) if it.kind == "forecast"), default=None)
            if last is None:
                break
            del items[last]
        return replace(view, items=items)


def _periodic(template: Message, *, sender: str, type_name: str, now: float, period_s: float,
              horizon_end: float, latency_s: float) -> list[PlanItem]:
    """A forecast stream with ``template``'s data: one message per ``period_s`` from half a
    period after ``now`` (the phase is unknown: its expected place) to ``horizon_end``."""
    first = Message(sender=sender, seq=-1, type=type_name, t_gen=now + 0.5 * period_s,
                    size=template.size, data=template.data, versions=template.versions,
                    version=0 if template.versions else None)
    out: list[PlanItem] = []
    k, t = 0, first.t_gen
    while t <= horizon_end:
        m = first if k == 0 else replace(first, seq=-1 - k, t_gen=t)
        out.append(PlanItem(message=m, send_t=t, rcv_t=t + latency_s))
        k += 1
        t = first.t_gen + k * period_s
    return out


def check_roster(roster: object, spec: MissionSpec, *, agent: str | None = None) -> str | None:
    """Why ``roster`` is not a roster of ``spec`` (one line), or None: a non-empty mapping of
    agent names to non-empty lists of distinct types of the spec, naming ``agent`` if given."""
    if not isinstance(roster, Mapping) or not roster:
        return "roster must map agent names to lists of the types they generate"
    for name, types in roster.items():
        if not isinstance(name, str) or not name or name.startswith(UNHEARD_PREFIX):
            return f"roster: agent name {name!r} must be a non-empty string not starting " \
                   f"with {UNHEARD_PREFIX!r}"
        if not isinstance(types, list | tuple) or not types \
                or not all(isinstance(t, str) for t in types) or len(set(types)) != len(types):
            return f"roster.{name}: expected a non-empty list of distinct types, got {types!r}"
        unknown = [t for t in types if t not in spec.types]
        if unknown:
            return f"roster.{name}: {unknown[0]!r} is not a type of the mission spec " \
                   f"{spec.name!r}"
    if agent is not None and agent not in roster:
        return f"roster does not name this agent ({agent})"
    return None
