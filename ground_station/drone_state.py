"""One drone as the dashboard shows it (:class:`DroneState`), its latest image, the alerts an
operator sees, and the windows and staleness limits the view uses. Data only; the
:class:`~ground_station.fleet.FleetView` updates it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from companion.protocol import Address
from utility_specs.data_fields import first_number

__all__ = ["IMAGE_RATE_WINDOW_S", "MAX_STATUS_PERIOD_S", "RATE_WINDOW_S", "Alert", "DroneState",
           "LatestImage", "declared_status_period", "lost_after_s"]

RATE_WINDOW_S = 5.0
IMAGE_RATE_WINDOW_S = 30.0
"""A tile's images per second count this long (RATE_WINDOW_S once the drone is new): on the
demo's narrow link a drone gets an image through every 3-5 s, and over 5 s its tile read
"fps 0.0" between them while its images kept arriving."""
"""Frames per second and goodput share are measured over this trailing window."""

SNAPSHOT_SERIES_VALUES = 1800
"""Per-drone chart values a snapshot carries at most (bounds ``/api/fleet`` by fleet size;
120 points for up to 15 drones: 128 full tiles and the history stay under 300 kB)."""
STALE_AFTER_S: Mapping[str, float] = {"position": 3.0, "alt_m": 3.0, "heading_deg": 3.0}
"""A field older than this is marked stale on the dashboard (position 1 Hz: three missed)."""
DEFAULT_STALE_AFTER_S = 12.0
"""Every other field (status every 5 s, battery every 5 s): two missed and some slack."""
MAX_STATUS_PERIOD_S = 60.0
"""The longest status period a drone's word is taken for: a drone still counts as lost after
2.5 of these (150 s) of silence whatever it says."""


def declared_status_period(data: Mapping[str, Any]) -> float | None:
    """The ``status_period_s`` a drone's status says it keeps, if it is one to take."""
    period = first_number(data, "status_period_s")
    return period if period is not None and 0.0 < period <= MAX_STATUS_PERIOD_S else None


def lost_after_s(link_lost_s: float, status_period_s: float | None) -> float:
    """Silence that makes a drone lost: ``link_lost_s``, or 2.5 of the status periods the
    drone says it keeps when that is longer. A drone set to a status every 5 s was called
    lost and back every few seconds on a healthy link."""
    if status_period_s is None:
        return link_lost_s
    return max(link_lost_s, 2.5 * status_period_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class Alert:
    """Something an operator should see: autopilot STATUSTEXT, link loss, drops, disk errors."""

    t: float
    level: str
    """``info``, ``warning`` or ``error``."""
    text: str
    drone: str | None = None
    kind: str = "info"
    """``statustext``, ``link``, ``drop``, ``storage``, ``mission``..."""


@dataclass(slots=True, kw_only=True)
class LatestImage:
    image_id: int | None
    seq: int
    t_gen: float
    t_rcv: float
    size: int
    utility: float
    red: float | None
    object: bool
    high: bool


@dataclass(slots=True, kw_only=True)
class DroneState:
    """One tile of the dashboard."""

    drone: str
    first_heard: float
    last_heard: float
    addr: Address | None = None
    messages: int = 0
    images: int = 0
    bytes_total: int = 0
    latency_s: float | None = None
    battery: float | None = None
    mode: str | None = None
    armed: bool | None = None
    gps_fix: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    x_m: float | None = None
    y_m: float | None = None
    heading_deg: float | None = None
    xi_bytes_per_s: float | None = None
    status_period_s: float | None = None
    """How often the drone says it sends its status (None: it does not say); a drone that
    sends it less often than ``link_lost_s`` allows is judged by its own period."""
    fallback_share: float | None = None
    """Share of the drone's decisions not made by its optimiser (greedy fallback, timeout)."""
    delta_s: float | None = None
    loss: float | None = None
    link_lost: bool = False
    restored: bool = False
    """Seeded from storage when the station started, not heard since: shown lost (dimmed)
    without a "link lost" alert, and back without a "link back" one (the station was down,
    not the drone's link)."""
    failsafe: bool | None = None
    autopilot_connected: bool | None = None
    optimiser_ready: bool | None = None
    mission: str | None = None
    """The drone's own mission window (``idle``, ``running``, ``ended``) from its status:
    a drone that runs no mission while the station's does shows it on its tile."""
    """The drone's optimiser has warmed up (numba compiled); None: its statuses do not say."""
    no_position: bool = False
    """The newest word on the position is "none" (no fix, no estimator origin)."""
    peers: dict[str, float] | None = None
    """The drone's own peers and the age of each one's position when its status was
    observed (shared medium, docs/peers.md); None: it reports none."""
    field_t: dict[str, float] = field(default_factory=dict)
    """Per telemetry field, when the drone observed the value shown (its age's origin)."""
    reports: list[str] = field(default_factory=list)
    latest_image: LatestImage | None = None
    _image_times: deque[float] = field(default_factory=deque)
    _byte_times: deque[tuple[float, int]] = field(default_factory=deque)
    _window_bytes: int = 0

    def prune(self, now: float) -> None:
        horizon = now - RATE_WINDOW_S
        while self._image_times and self._image_times[0] <= now - IMAGE_RATE_WINDOW_S:
            self._image_times.popleft()
        while self._byte_times and self._byte_times[0][0] <= horizon:
            self._window_bytes -= self._byte_times.popleft()[1]

    def fps(self, now: float) -> float:
        self.prune(now)
        span = min(IMAGE_RATE_WINDOW_S, max(RATE_WINDOW_S, now - self.first_heard))
        return len(self._image_times) / span

    def goodput_bytes_per_s(self, now: float) -> float:
        self.prune(now)
        return self._window_bytes / RATE_WINDOW_S
