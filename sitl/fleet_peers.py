"""`uav-sitl fleet --peers`: peer sharing over a loopback broadcast medium (docs/peers.md).

The launcher (sitl/fleet.py, sitl/fleet_config.py) calls these:
every companion gets a ``[peers]`` table (the medium, ADSB_VEHICLE at 1 Hz into its vehicle,
a ``GET /peers`` endpoint on a free local port), the ground station ``shared_medium``, the
ArduPilot vehicles ``ADSB_TYPE=1``; at the end the launcher asks every companion which peers
it knows and how old each position is, and the summary prints it.
"""

from __future__ import annotations

import json
import math
import socket
import urllib.request
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["companion_peers_table", "format_peers", "poll_peers", "position_age_bound",
           "vehicle_args"]

ADSB_RATE_HZ = 1.0


def loopback_medium() -> str:
    """A broadcast medium on a free loopback port."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    return f"broadcast:127.255.255.255:{port}"


def companion_peers_table(medium: str, http_port: int) -> dict[str, Any]:
    return {"medium": medium, "adsb_rate_hz": ADSB_RATE_HZ, "http": f"127.0.0.1:{http_port}"}


def vehicle_args(flavour: str) -> list[str]:
    """ArduPilot ignores ADSB_VEHICLE until ADSB_TYPE is set; PX4 takes it as is."""
    return ["--param", "ADSB_TYPE=1"] if flavour == "ardupilot" else []


def poll_peers(http_ports: Mapping[str, int], *, timeout_s: float = 2.0
               ) -> dict[str, dict[str, float | None] | None]:
    """Drone -> {peer: position age in s (None: no position yet)}; None when the companion
    did not answer."""
    known: dict[str, dict[str, float | None] | None] = {}
    for drone, port in http_ports.items():
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/peers",
                                        timeout=timeout_s) as resp:
                body = json.loads(resp.read())
        except (OSError, ValueError):
            known[drone] = None
            continue
        known[drone] = {p["drone"]: (p["position"] or {}).get("age_s")
                        for p in body.get("peers", [])}
    return known


def position_age_bound(spec_path: Path) -> float | None:
    """The age at which a position is worth nothing under the spec (eq. 4.12:
    U = 1 - pi v_max^2 age^2 / A = 0, so age = sqrt(A / (pi v_max^2))); None without a
    ``position`` type of utility ``position``."""
    from utility_specs.files import load_spec

    try:
        info = load_spec(spec_path).types.get("position")
    except (OSError, ValueError):
        return None
    if info is None or info.utility.name != "position":
        return None
    params = info.utility.params()
    return math.sqrt(params["area"] / (math.pi * params["v_max"] ** 2))


def format_peers(known: Mapping[str, Mapping[str, float | None] | None],
                 drones: Sequence[str], bound_s: float | None = None) -> list[str]:
    """Summary lines: per drone, the peers it knows with their position ages, and whether
    every age is below ``bound_s`` (:func:`position_age_bound`)."""
    lines = ["peers (position age when the mission ended):"]
    worst: float | None = None
    complete = True
    for drone in drones:
        peers = known.get(drone)
        if peers is None:
            lines.append(f"  {drone}: no answer from its /peers endpoint")
            complete = False
            continue
        missing = [d for d in drones if d != drone and peers.get(d) is None]
        complete = complete and not missing
        parts = [f"{p} {age:.1f} s" for p, age in sorted(peers.items()) if age is not None]
        for age in (a for a in peers.values() if a is not None):
            worst = age if worst is None else max(worst, age)
        lines.append(f"  {drone}: {', '.join(parts) or 'none'}"
                     + (f"; missing {', '.join(missing)}" if missing else ""))
    lines.append(f"  every drone knows every peer: {'yes' if complete else 'no'}"
                 + (f", oldest position {worst:.1f} s" if worst is not None else ""))
    if bound_s is not None:
        within = complete and worst is not None and worst < bound_s
        lines.append(f"  bound from the spec (eq. 4.12, position worth 0): {bound_s:.1f} s: "
                     f"{'every position within it' if within else 'NOT met'}")
    return lines
