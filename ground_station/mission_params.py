"""Which of the parameters an operator asked for are in effect on the fleet.

A set_params is all or nothing on a drone (one rejected key changes nothing there), so a
value is in effect when the latest set_params that sets it was not rejected by every drone
that answered it; one every drone rejected sets nothing, and its keys are listed apart. Before
this the mission panel's "params requested" showed ``warp_speed=2`` after ``error 2/2``, the
same as a value the drones had applied.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["FleetParams", "fleet_params"]


@dataclass(frozen=True, slots=True)
class FleetParams:
    in_effect: dict[str, Any] = field(default_factory=dict)
    """Key -> value of the latest set_params of it that some drone applied or may still."""
    rejected: dict[str, Any] = field(default_factory=dict)
    """Key -> value asked later than what is in effect, rejected by every drone."""


def fleet_params(commands: Iterable[tuple[dict[str, Any], list[str]]]) -> FleetParams:
    """``commands``: each set_params' arguments and its drones' results (``done``,
    ``error``, ``no reply``, or a waiting state), in issue order."""
    in_effect: dict[str, Any] = {}
    rejected: dict[str, Any] = {}
    for args, results in commands:
        if results and all(r == "error" for r in results):
            rejected.update(args)
            continue
        in_effect.update(args)
        for key in args:
            rejected.pop(key, None)
    return FleetParams(in_effect=in_effect, rejected=rejected)
