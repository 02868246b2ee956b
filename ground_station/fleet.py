"""What the ground station knows about each drone right now: the dashboard's view model.

Sans-I/O: every update takes ``now`` (fleet clock, seconds). The receiver feeds it messages,
the dashboard reads :meth:`FleetView.snapshot`, and :meth:`FleetView.tick` samples the link
charts and raises link-loss alerts.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from utility_specs.message import Message

__all__ = ["Alert", "DroneState", "FleetView", "LatestImage"]

RATE_WINDOW_S = 5.0
"""Frames per second and goodput share are measured over this trailing window."""

_NUMBER = (int, float)


def _num(data: Mapping[str, Any], *keys: str) -> float | None:
    for key in keys:
        value = data.get(key)
        if isinstance(value, _NUMBER) and not isinstance(value, bool) and math.isfinite(value):
            return float(value)
    return None


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
    addr: tuple[str, int] | None = None
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
    fallback_share: float | None = None
    """Share of the drone's decisions not made by its optimiser (greedy fallback, timeout)."""
    delta_s: float | None = None
    loss: float | None = None
    link_lost: bool = False
    reports: list[str] = field(default_factory=list)
    latest_image: LatestImage | None = None
    _image_times: deque[float] = field(default_factory=deque)
    _byte_times: deque[tuple[float, int]] = field(default_factory=deque)
    _window_bytes: int = 0

    def prune(self, now: float) -> None:
        horizon = now - RATE_WINDOW_S
        while self._image_times and self._image_times[0] <= horizon:
            self._image_times.popleft()
        while self._byte_times and self._byte_times[0][0] <= horizon:
            self._window_bytes -= self._byte_times.popleft()[1]

    def fps(self, now: float) -> float:
        self.prune(now)
        return len(self._image_times) / RATE_WINDOW_S

    def goodput_bytes_per_s(self, now: float) -> float:
        self.prune(now)
        return self._window_bytes / RATE_WINDOW_S


class FleetView:
    """Per-drone live state, fleet-wide link series and the alert list.

    Parameters
    ----------
    high_utility
        Images whose utility weight reaches this get ``high = True`` (red border, fig. 7.5).
    link_lost_s
        Silence after which a drone is flagged lost (alert once, cleared when heard again).
    """

    def __init__(
        self,
        *,
        high_utility: float,
        link_lost_s: float,
        series_len: int = 600,
        alerts_len: int = 500,
    ) -> None:
        self.high_utility = high_utility
        self.link_lost_s = link_lost_s
        self.drones: dict[str, DroneState] = {}
        self.alerts: deque[Alert] = deque(maxlen=alerts_len)
        self.series: deque[dict[str, Any]] = deque(maxlen=series_len)
        self.drops: Counter[str] = Counter()
        self._origin: tuple[float, float] | None = None
        self._new_alerts: list[Alert] = []

    # -- inputs -------------------------------------------------------------------------
    def heard(self, drone: str, *, now: float, addr: tuple[str, int] | None = None) -> DroneState:
        state = self.drones.get(drone)
        if state is None:
            state = DroneState(drone=drone, first_heard=now, last_heard=now, addr=addr)
            self.drones[drone] = state
        state.last_heard = max(state.last_heard, now)
        if addr is not None:
            state.addr = addr
        if state.link_lost:
            state.link_lost = False
            self.alert(Alert(t=now, level="info", kind="link", drone=drone, text="link back"))
        return state

    def on_message(
        self,
        message: Message,
        *,
        now: float,
        addr: tuple[str, int] | None = None,
        utility: float | None = None,
        image_id: int | None = None,
    ) -> DroneState:
        """Apply one received message; ``utility`` is given for images."""
        state = self.heard(message.sender, now=now, addr=addr)
        t_rcv = message.t_rcv if message.t_rcv is not None else now
        state.messages += 1
        state.bytes_total += message.size
        state._byte_times.append((now, message.size))
        state._window_bytes += message.size
        latency = t_rcv - message.t_gen
        state.latency_s = (
            latency if state.latency_s is None else 0.8 * state.latency_s + 0.2 * latency
        )
        self.apply_data(state, message.data, now=now)
        if utility is not None:
            state.images += 1
            state._image_times.append(now)
            obj = message.data.get("object")
            state.latest_image = LatestImage(
                image_id=image_id,
                seq=message.seq,
                t_gen=message.t_gen,
                t_rcv=t_rcv,
                size=message.size,
                utility=utility,
                red=_num(message.data, "red"),
                object=bool(obj) if isinstance(obj, bool | int | float) else False,
                high=utility >= self.high_utility,
            )
        state.prune(now)
        return state

    def apply_data(self, state: DroneState, data: Mapping[str, Any], *, now: float) -> None:
        battery = _num(data, "level", "battery", "battery_level", "battery_remaining")
        if battery is not None:
            state.battery = battery / 100.0 if battery > 1.0 else battery
        mode = data.get("mode")
        if isinstance(mode, str):
            state.mode = mode
        armed = data.get("armed")
        if isinstance(armed, bool):
            state.armed = armed
        fix = _num(data, "gps_fix", "fix_type", "fix")
        if fix is not None:
            state.gps_fix = int(fix)
        lat, lon = _num(data, "lat_deg", "lat"), _num(data, "lon_deg", "lon")
        if lat is not None and lon is not None:
            state.lat_deg, state.lon_deg = lat, lon
            state.x_m, state.y_m = self._local(lat, lon)
        x, y = _num(data, "x_m", "x"), _num(data, "y_m", "y")
        if x is not None and y is not None and lat is None:
            state.x_m, state.y_m = x, y
        alt = _num(data, "alt_m", "alt_rel_m", "alt", "relative_alt_m")
        if alt is not None:
            state.alt_m = alt
        heading = _num(data, "heading_deg", "yaw_deg", "hdg_deg")
        if heading is not None:
            state.heading_deg = heading
        xi = _num(data, "xi_bytes_per_s", "xi", "constraint_bytes_per_s", "limit_bytes_per_s")
        if xi is not None:
            state.xi_bytes_per_s = xi
        fallback = _num(data, "fallback_share")
        if fallback is not None and 0.0 <= fallback <= 1.0:
            state.fallback_share = fallback
        delta = _num(data, "delta_s", "delta")
        if delta is not None:
            state.delta_s = delta
        loss = _num(data, "loss", "loss_share", "loss_rate")
        if loss is not None:
            state.loss = loss
        text = data.get("statustext", data.get("text"))
        if isinstance(text, str) and text:
            severity = _num(data, "severity")
            level = "error" if severity is not None and severity <= 3 else "warning"
            if severity is not None and severity >= 6:
                level = "info"
            self.alert(Alert(t=now, level=level, kind="statustext", drone=state.drone, text=text))
        report = data.get("report")
        if isinstance(report, str) and report:
            state.reports.append(report)
            del state.reports[:-10]

    def _local(self, lat: float, lon: float) -> tuple[float, float]:
        """Local east/north metres from the first position seen (equirectangular)."""
        if self._origin is None:
            self._origin = (lat, lon)
        lat0, lon0 = self._origin
        r_earth_m = 6_371_000.0
        x = math.radians(lon - lon0) * r_earth_m * math.cos(math.radians(lat0))
        y = math.radians(lat - lat0) * r_earth_m
        return x, y

    def on_drop(self, reason: str, *, now: float, drone: str | None = None) -> None:
        self.drops[reason] += 1
        n = self.drops[reason]
        # One alert for the first drop of a reason, then at powers of ten: visible, not noisy.
        if n == 1 or math.log10(n).is_integer():
            self.alert(
                Alert(
                    t=now,
                    level="warning",
                    kind="drop",
                    drone=drone,
                    text=f"datagrams dropped ({reason}): {n}",
                )
            )

    def alert(self, alert: Alert) -> None:
        self.alerts.append(alert)
        self._new_alerts.append(alert)

    def take_new_alerts(self) -> list[Alert]:
        """Alerts raised since the last call (the shell broadcasts and stores them)."""
        out, self._new_alerts = self._new_alerts, []
        return out

    # -- periodic -----------------------------------------------------------------------
    def tick(self, *, now: float) -> dict[str, Any]:
        """Sample the link charts and check for link loss; returns the new series point."""
        goodput_total = 0.0
        point_drones: dict[str, dict[str, float | None]] = {}
        latencies: list[float] = []
        for drone, state in self.drones.items():
            if not state.link_lost and now - state.last_heard > self.link_lost_s:
                state.link_lost = True
                self.alert(
                    Alert(
                        t=now,
                        level="error",
                        kind="link",
                        drone=drone,
                        text=f"link lost: nothing heard for {now - state.last_heard:.1f} s",
                    )
                )
            goodput = state.goodput_bytes_per_s(now)
            goodput_total += goodput
            if state.latency_s is not None and not state.link_lost:
                latencies.append(state.latency_s)
            point_drones[drone] = {
                "goodput": goodput,
                "xi": state.xi_bytes_per_s,
                "latency": state.latency_s,
                "delta": state.delta_s,
                "loss": state.loss,
            }
        point = {
            "t": now,
            "goodput": goodput_total,
            "latency": sum(latencies) / len(latencies) if latencies else None,
            "drones": point_drones,
        }
        self.series.append(point)
        return point

    # -- outputs ------------------------------------------------------------------------
    def drone_json(self, state: DroneState, *, now: float) -> dict[str, Any]:
        goodput_total = sum(s.goodput_bytes_per_s(now) for s in self.drones.values())
        own = state.goodput_bytes_per_s(now)
        out: dict[str, Any] = {
            "drone": state.drone,
            "addr": list(state.addr) if state.addr else None,
            "messages": state.messages,
            "images": state.images,
            "bytes_total": state.bytes_total,
            "fps": state.fps(now),
            "goodput_bytes_per_s": own,
            "goodput_share": own / goodput_total if goodput_total > 0 else 0.0,
            "latency_s": state.latency_s,
            "battery": state.battery,
            "mode": state.mode,
            "armed": state.armed,
            "gps_fix": state.gps_fix,
            "lat_deg": state.lat_deg,
            "lon_deg": state.lon_deg,
            "alt_m": state.alt_m,
            "x_m": state.x_m,
            "y_m": state.y_m,
            "heading_deg": state.heading_deg,
            "xi_bytes_per_s": state.xi_bytes_per_s,
            "fallback_share": state.fallback_share,
            "delta_s": state.delta_s,
            "loss": state.loss,
            "last_heard": state.last_heard,
            "age_s": now - state.last_heard,
            "link_lost": state.link_lost,
            "reports": list(state.reports),
            "latest_image": asdict(state.latest_image) if state.latest_image else None,
        }
        return out

    def snapshot(self, *, now: float) -> dict[str, Any]:
        return {
            "t": now,
            "drones": [self.drone_json(s, now=now) for s in self.drones.values()],
            "drops": dict(self.drops),
            "alerts": [asdict(a) for a in list(self.alerts)[-50:]],
            "series": list(self.series)[-120:],
        }
