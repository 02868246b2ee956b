"""Simulated MAVLink multicopters: a pure physics core, a sans-I/O MAVLink endpoint and a thin
asyncio shell (``uav-sitl vehicle``). See docs/sitl.md.

Names are imported lazily (PEP 562), so that ``uav-sitl vehicle`` can set ``MAVLINK20=1``
before anything imports pymavlink.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = [
    "ARDUPILOT",
    "DEFAULT_HOME",
    "FLAVOURS",
    "PX4",
    "Airframe",
    "Flavour",
    "FlightController",
    "MissionItem",
    "Mode",
    "Setpoint",
    "SimClock",
    "VehicleConfig",
    "VehicleCore",
    "VehicleEndpoint",
    "VehicleState",
    "start_vehicles",
    "step",
]

_WHERE = {
    "ARDUPILOT": "flavour", "FLAVOURS": "flavour", "PX4": "flavour", "Flavour": "flavour",
    "Mode": "flavour", "DEFAULT_HOME": "core", "VehicleConfig": "core", "VehicleCore": "core",
    "FlightController": "autopilot", "MissionItem": "mission", "Airframe": "physics",
    "Setpoint": "physics", "VehicleState": "physics", "step": "physics", "SimClock": "shell",
    "VehicleEndpoint": "shell", "start_vehicles": "shell",
}

if TYPE_CHECKING:
    from sitl.vehicle.autopilot import FlightController
    from sitl.vehicle.core import DEFAULT_HOME, VehicleConfig, VehicleCore
    from sitl.vehicle.flavour import ARDUPILOT, FLAVOURS, PX4, Flavour, Mode
    from sitl.vehicle.mission import MissionItem
    from sitl.vehicle.physics import Airframe, Setpoint, VehicleState, step
    from sitl.vehicle.shell import SimClock, VehicleEndpoint, start_vehicles


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'sitl.vehicle' has no attribute {name!r}")
    return getattr(importlib.import_module(f"sitl.vehicle.{module}"), name)
