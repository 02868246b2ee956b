"""`uav-sitl fleet --peers`: peer sharing over a broadcast medium (docs/peers.md).

On loopback the medium is a free port of 127.255.255.255; with ``--netns`` it is the
broadcast address of the namespaces' shared bridge (10.199.0.255), where every drone and the
ground station has its own address and socket: a datagram crosses the bridge to every
member (only the bridge's port toward the ground station is shaped, so peers hear each other
unshaped; the station's copy queues in the tbf like every other datagram).

The launcher (sitl/fleet.py, sitl/fleet_config.py) calls these:
every companion gets a ``[peers]`` table (the medium, ADSB_VEHICLE at 1 Hz into its vehicle,
a ``GET /peers`` endpoint on a free local port), the ground station ``shared_medium``, the
ArduPilot vehicles ``ADSB_TYPE=1``; at the end the launcher asks every companion which peers
it knows and how old each position is, and the summary prints it.
"""

from __future__ import annotations

import functools
import json
import math
import socket
import threading
import urllib.request
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["companion_peers_table", "format_peers", "loopback_medium", "netns_medium",
           "poll_peers", "position_age_bound", "vehicle_args"]

ADSB_RATE_HZ = 1.0


def loopback_medium() -> str:
    """A broadcast medium on a free loopback port."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    return f"broadcast:127.255.255.255:{port}"


def netns_medium(port: int) -> str:
    """The broadcast medium on the ``--netns`` bridge (sitl.linkemu.SharedMedium's /24)."""
    from sitl.linkemu import GROUND_ADDR

    return f"broadcast:{GROUND_ADDR.rsplit('.', 1)[0]}.255:{port}"


def companion_peers_table(medium: str, http_port: int) -> dict[str, Any]:
    return {"medium": medium, "adsb_rate_hz": ADSB_RATE_HZ, "http": f"127.0.0.1:{http_port}"}


def vehicle_args(flavour: str) -> list[str]:
    """ArduPilot ignores ADSB_VEHICLE until ADSB_TYPE is set; PX4 takes it as is."""
    return ["--param", "ADSB_TYPE=1"] if flavour == "ardupilot" else []


def poll_peers(http_ports: Mapping[str, int], *, timeout_s: float = 2.0,
               namespaces: Mapping[str, str] | None = None,
               ) -> dict[str, dict[str, float | None] | None]:
    """Drone -> {peer: position age in s (None: no position yet)}; None when the companion
    did not answer. ``namespaces`` (``--netns``): drone -> the network namespace its
    companion (and its 127.0.0.1 endpoint) lives in; each is asked from a thread inside it."""
    known: dict[str, dict[str, float | None] | None] = {}
    for drone, port in http_ports.items():
        ns = (namespaces or {}).get(drone)
        url = f"http://127.0.0.1:{port}/peers"
        body = _get_json(url, timeout_s) if ns is None \
            else _in_namespace(ns, functools.partial(_get_json, url, timeout_s), timeout_s + 1.0)
        known[drone] = None if body is None else {
            p["drone"]: (p["position"] or {}).get("age_s") for p in body.get("peers", [])}
    return known


def _get_json(url: str, timeout_s: float) -> dict[str, Any] | None:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            body = json.loads(resp.read())
    except (OSError, ValueError):
        return None
    return body if isinstance(body, dict) else None


def _in_namespace(ns: str, call: Callable[[], dict[str, Any] | None], timeout_s: float
                  ) -> dict[str, Any] | None:
    """``call()`` on a thread that first enters network namespace ``ns`` (setns moves only
    the calling thread, so the launcher's own sockets stay where they are)."""
    from sitl.fleet.netns import _enter_netns

    result: list[dict[str, Any] | None] = [None]

    def run() -> None:
        try:
            _enter_netns(ns)
        except OSError:
            return
        result[0] = call()

    thread = threading.Thread(target=run, name=f"peers-{ns}", daemon=True)
    thread.start()
    thread.join(timeout_s)
    return result[0]


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
