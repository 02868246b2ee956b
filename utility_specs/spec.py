"""Mission specs: which information types a mission has and what each is worth.

A spec is a TOML file (``utility_specs/missions/*.toml``)::

    [mission]
    name = "telemetry"

    [types.battery]
    utility = "battery"          # a name from utility_specs.functions.FUNCTIONS
    aggregation = "max"          # sum | max | last (eq. 4.4-4.7)
    weight = 1.0                 # ω_p of eq. 4.2
    per_sender = true            # aggregate each sender's stream on its own
    markovian = true             # only the newest message matters (eq. 5.8)
    params = { depletion_rate = 0.01 }
    receivers = ["ground"]       # who it is for: "ground", "peers" (every other drone), or both
    period_s = 1.0               # optional: a source's nominal period (the optimiser's prior)

    [mission.roster]             # optional: which agent generates which types
    uav0 = ["battery"]

Reading the file is a thin edge (:func:`load_spec`); :func:`parse_spec` validates a mapping
and every error names the file, the key and what was expected.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import PurePath
from typing import Any, Literal, cast

from utility_specs.errors import SpecError
from utility_specs.functions import UtilityFunction, make_function

__all__ = [
    "AGGREGATIONS",
    "RECEIVERS",
    "InfoType",
    "MissionSpec",
    "parse_spec",
]

Aggregation = Literal["sum", "max", "last"]
AGGREGATIONS: tuple[Aggregation, ...] = ("sum", "max", "last")
Receiver = Literal["ground", "peers"]
RECEIVERS: tuple[Receiver, ...] = ("ground", "peers")
"""``ground``: the ground station; ``peers``: every other drone (over the shared medium)."""
_TYPE_KEYS = {"utility", "aggregation", "weight", "per_sender", "markovian", "params",
              "receivers", "period_s"}


@dataclass(frozen=True, slots=True, kw_only=True)
class InfoType:
    """One information type p: its utility function, aggregation and weight ω_p."""

    name: str
    utility: UtilityFunction
    aggregation: Aggregation
    weight: float = 1.0
    per_sender: bool = False
    markovian: bool = False
    receivers: tuple[Receiver, ...] = ("ground",)
    """Who the type is for; the utility of a message counts at each receiver (eq. 4.2)."""
    period_s: float | None = None
    """Nominal period of one source of the type (seconds), if the mission knows it: how
    often the optimiser expects a stream of the type that has not shown its own period yet
    to send (one heard of once, or a roster's stream not heard yet). None: not declared."""

    @property
    def for_peers(self) -> bool:
        """Sent on the shared medium, so every other drone hears it."""
        return "peers" in self.receivers

    def __post_init__(self) -> None:
        if self.aggregation not in AGGREGATIONS:
            raise SpecError(f"type {self.name!r}: aggregation must be one of {AGGREGATIONS}")
        if self.aggregation not in self.utility.aggregations:
            raise SpecError(
                f"type {self.name!r}: utility {self.utility.name!r} supports aggregation "
                f"{sorted(self.utility.aggregations)}, not {self.aggregation!r}"
            )
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise SpecError(f"type {self.name!r}: weight must be a finite number >= 0")
        if self.period_s is not None and not (math.isfinite(self.period_s) and self.period_s > 0):
            raise SpecError(f"type {self.name!r}: period_s must be a finite number > 0")
        if (not self.receivers or len(set(self.receivers)) != len(self.receivers)
                or not set(self.receivers) <= set(RECEIVERS)):
            raise SpecError(f"type {self.name!r}: receivers must be a non-empty list of "
                            f"distinct {list(RECEIVERS)}")


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionSpec:
    """The model instance of one mission (sec. 4.2): its information types."""

    name: str
    types: Mapping[str, InfoType]
    t_end: float | None = None
    """Default mission end (seconds) when the log does not say."""
    source: str = "<memory>"
    extra: Mapping[str, Any] = field(default_factory=dict)
    """Other keys of the [mission] table, for the tools that read them."""
    roster: Mapping[str, tuple[str, ...]] | None = None
    """``[mission.roster]``: agent name -> the types it generates (the declared fleet; the
    optimiser plans exactly for the streams it has not heard yet). None: not declared."""

    def __getitem__(self, type_name: str) -> InfoType:
        return self.types[type_name]


def _expect(cond: bool, source: str, key: str, expected: str, got: object) -> None:
    if not cond:
        raise SpecError(f"{source}: {key}: expected {expected}, got {got!r}")


def parse_spec(raw: Mapping[str, Any], *, source: str = "<memory>") -> MissionSpec:
    """Validate a parsed TOML mapping into a :class:`MissionSpec`."""
    _expect(isinstance(raw, Mapping), source, "<root>", "a table", raw)
    unknown = set(raw) - {"mission", "types"}
    _expect(not unknown, source, ", ".join(sorted(unknown)), "only [mission] and [types]", "")
    mission = raw.get("mission", {})
    _expect(isinstance(mission, Mapping), source, "mission", "a table", mission)
    name = mission.get("name", PurePath(source).stem)
    _expect(isinstance(name, str) and bool(name), source, "mission.name", "a string", name)
    t_end = mission.get("t_end")
    if t_end is not None:
        _expect(
            isinstance(t_end, int | float) and not isinstance(t_end, bool) and t_end > 0,
            source,
            "mission.t_end",
            "a number > 0 (seconds)",
            t_end,
        )
    types_raw = raw.get("types")
    _expect(
        isinstance(types_raw, Mapping) and bool(types_raw),
        source,
        "types",
        "at least one [types.NAME] table",
        types_raw,
    )
    types: dict[str, InfoType] = {}
    for type_name, table in cast(Mapping[str, Any], types_raw).items():
        types[type_name] = _parse_type(type_name, table, source)
    extra = {k: v for k, v in mission.items() if k not in {"name", "t_end", "roster"}}
    roster = _parse_roster(mission.get("roster"), types, source)
    return MissionSpec(
        name=name,
        types=types,
        t_end=float(t_end) if t_end is not None else None,
        source=source,
        extra=extra,
        roster=roster,
    )


def _parse_roster(raw: Any, types: Mapping[str, InfoType], source: str
                  ) -> dict[str, tuple[str, ...]] | None:
    if raw is None:
        return None
    _expect(isinstance(raw, Mapping) and bool(raw), source, "mission.roster",
            "a table of agent = [types]", raw)
    roster: dict[str, tuple[str, ...]] = {}
    for agent, listed in cast(Mapping[str, Any], raw).items():
        key = f"mission.roster.{agent}"
        _expect(isinstance(listed, list) and bool(listed)
                and all(isinstance(t, str) for t in listed) and len(set(listed)) == len(listed),
                source, key, "a non-empty list of distinct type names", listed)
        unknown = [t for t in listed if t not in types]
        _expect(not unknown, source, key, f"types of this spec {sorted(types)}", unknown)
        _expect(not agent.startswith("?"), source, key, "an agent name not starting with '?'",
                agent)
        roster[agent] = tuple(listed)
    return roster


def _parse_type(type_name: str, table: Any, source: str) -> InfoType:
    key = f"types.{type_name}"
    _expect(isinstance(table, Mapping), source, key, "a table", table)
    unknown = sorted(set(table) - _TYPE_KEYS)
    _expect(not unknown, source, f"{key}.{','.join(unknown)}", f"one of {sorted(_TYPE_KEYS)}", "")
    utility = table.get("utility")
    _expect(isinstance(utility, str), source, f"{key}.utility", "a utility name", utility)
    aggregation = table.get("aggregation")
    _expect(
        aggregation in AGGREGATIONS, source, f"{key}.aggregation", " | ".join(AGGREGATIONS),
        aggregation,
    )
    weight = table.get("weight", 1.0)
    _expect(
        isinstance(weight, int | float) and not isinstance(weight, bool) and weight >= 0,
        source,
        f"{key}.weight",
        "a number >= 0",
        weight,
    )
    flags = {}
    for flag in ("per_sender", "markovian"):
        value = table.get(flag, False)
        _expect(isinstance(value, bool), source, f"{key}.{flag}", "true or false", value)
        flags[flag] = value
    params = table.get("params", {})
    _expect(isinstance(params, Mapping), source, f"{key}.params", "a table", params)
    receivers = table.get("receivers", ["ground"])
    _expect(
        isinstance(receivers, list) and bool(receivers)
        and all(isinstance(r, str) and r in RECEIVERS for r in receivers)
        and len(set(receivers)) == len(receivers),
        source, f"{key}.receivers",
        '["ground"], ["peers"] or ["ground", "peers"]', receivers,
    )
    period = table.get("period_s")
    _expect(
        period is None or (isinstance(period, int | float) and not isinstance(period, bool)
                           and math.isfinite(period) and period > 0),
        source, f"{key}.period_s", "a number > 0 (seconds)", period,
    )
    try:
        function = make_function(cast(str, utility), params)
        return InfoType(
            name=type_name,
            utility=function,
            aggregation=cast(Aggregation, aggregation),
            weight=float(weight),
            per_sender=flags["per_sender"],
            markovian=flags["markovian"],
            receivers=cast(tuple[Receiver, ...], tuple(receivers)),
            period_s=None if period is None else float(period),
        )
    except SpecError as exc:
        raise SpecError(f"{source}: {key}: {exc}") from None
