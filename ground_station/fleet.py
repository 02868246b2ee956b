"""What the ground station knows about each drone right now: the dashboard's view model.

Sans-I/O: every update takes ``now`` (fleet clock, seconds). The receiver feeds it messages,
the dashboard reads :meth:`FleetView.snapshot`, and :meth:`FleetView.tick` samples the link
charts and raises link-loss alerts.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

from companion.protocol import Address
from ground_station.clock_watch import ClockWatch
from ground_station.drone_state import (
    DEFAULT_STALE_AFTER_S,
    RATE_WINDOW_S,
    SNAPSHOT_SERIES_VALUES,
    STALE_AFTER_S,
    Alert,
    DroneState,
    LatestImage,
    declared_status_period,
    lost_after_s,
)
from ground_station.medium_hint import StatusUnheard
from utility_specs.data_fields import first_number
from utility_specs.message import Message

__all__ = ["RATE_WINDOW_S", "Alert", "DroneState", "FleetView", "LatestImage"]


def _peer_ages(state: DroneState, now: float) -> dict[str, float] | None:
    """Each peer's position age at the drone, now: as reported plus the status's own age."""
    if state.peers is None:
        return None
    since = max(0.0, now - state.field_t.get("peers", now))
    return {peer: round(age + since, 1) for peer, age in sorted(state.peers.items())}


class FleetView:
    """Per-drone live state, fleet-wide link series and the alert list.

    Parameters
    ----------
    high_utility
        Images whose utility weight reaches this get ``high = True`` (red border, fig. 7.5);
        None: none does (a spec whose images cannot gain over plain video).
    link_lost_s
        Silence after which a drone is flagged lost (alert once, cleared when heard again).
    forget_after_s
        Silence after which a drone's tile is dropped (counted in ``forgotten``): the view
        holds the fleet that flies now, not every sender id ever heard.
    max_drones
        Most tiles held; a new drone beyond this evicts the least recently heard one.
    """

    def __init__(
        self,
        *,
        high_utility: float | None,
        link_lost_s: float,
        series_len: int = 600,
        alerts_len: int = 500,
        forget_after_s: float = 600.0,
        max_drones: int = 128,
        clock_tolerance_s: float = 30.0,
    ) -> None:
        if max_drones < 1 or not forget_after_s > 0:
            raise ValueError("max_drones must be >= 1 and forget_after_s > 0")
        self.high_utility = high_utility
        self.link_lost_s = link_lost_s
        self.forget_after_s = forget_after_s
        self.max_drones = max_drones
        self.clocks = ClockWatch(clock_tolerance_s)
        self.forgotten = 0
        """Tiles dropped so far (silent too long, or evicted by newer drones)."""
        self._forgotten_ids: list[str] = []
        self._back_ids: list[str] = []
        self.drones: dict[str, DroneState] = {}
        self.alerts: deque[Alert] = deque(maxlen=alerts_len)
        self.series: deque[dict[str, Any]] = deque(maxlen=series_len)
        self.drops: Counter[str] = Counter()
        self._origin: tuple[float, float] | None = None
        self._new_alerts: list[Alert] = []
        self.status_unheard: StatusUnheard | None = None
        """Set by the app: a drone heard 30 s without a status is told (a medium unheard)."""

    def set_origin(self, lat: float, lon: float) -> None:
        """Local coordinates around this point (the scene's home) instead of the first fix."""
        self._origin = (lat, lon)

    def is_high(self, utility: float) -> bool:
        return self.high_utility is not None and utility >= self.high_utility

    # -- inputs -------------------------------------------------------------------------
    def heard(self, drone: str, *, now: float, addr: Address | None = None) -> DroneState:
        state = self.drones.get(drone)
        if state is None:
            if len(self.drones) >= self.max_drones:
                self._forget(min(self.drones.values(), key=lambda s: s.last_heard).drone)
            state = DroneState(drone=drone, first_heard=now, last_heard=now, addr=addr)
            self.drones[drone] = state
        state.last_heard = max(state.last_heard, now)
        if addr is not None:
            state.addr = addr
        if state.link_lost:
            state.link_lost = False
            self._back_ids.append(drone)
            if state.restored:
                state.restored = False
            else:
                self.alert(Alert(t=now, level="info", kind="link", drone=drone,
                                 text="link back"))
        return state

    def restore(self, drone: str, *, last_heard: float) -> DroneState:
        """A drone's tile from storage at a restart: lost until heard, with no alert either
        way (every restart raised "link lost" then "link back" for every drone)."""
        state = self.heard(drone, now=last_heard)
        if state.last_heard <= last_heard:  # not heard in this run yet
            state.link_lost = state.restored = True
        return state

    def on_message(
        self,
        message: Message,
        *,
        now: float,
        addr: Address | None = None,
        utility: float | None = None,
        image_id: int | None = None,
    ) -> DroneState:
        """Apply one received message; ``utility`` is given for images."""
        state = self.heard(message.sender, now=now, addr=addr)
        if self.status_unheard is not None:
            self.status_unheard.on_message(message.sender, message.type, now)
        t_rcv = message.t_rcv if message.t_rcv is not None else now
        state.messages += 1
        state.bytes_total += message.size
        state._byte_times.append((now, message.size))
        state._window_bytes += message.size
        latency = t_rcv - message.t_gen
        state.latency_s = (
            latency if state.latency_s is None else 0.8 * state.latency_s + 0.2 * latency
        )
        self.apply_data(state, message.data, now=now, t_obs=message.t_gen)
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
                red=first_number(message.data, "red"),
                object=bool(obj) if isinstance(obj, bool | int | float) else False,
                high=self.is_high(utility),
            )
        state.prune(now)
        return state

    def apply_data(self, state: DroneState, data: Mapping[str, Any], *, now: float,
                   t_obs: float | None = None) -> None:
        """Apply a message's fields observed at ``t_obs`` (default ``now``).

        A value older than the one shown (a late image's geotag, a reordered status) is
        ignored, so that the tile never goes back in time; each field keeps its
        observation time for its age. A position's observation time is the message's minus
        its ``pose_age_s``.
        """
        t = now if t_obs is None else t_obs

        def newer(name: str, at: float = t) -> bool:
            if at < state.field_t.get(name, -math.inf):
                return False
            state.field_t[name] = at
            return True

        battery = first_number(data, "level", "battery", "battery_level", "battery_remaining")
        if battery is not None and newer("battery"):
            state.battery = battery / 100.0 if battery > 1.0 else battery
        # A null says unknown (the companion does not hear its autopilot, or it rebooted
        # and has not said yet): the tile shows "–", not the last value as current.
        mode = data.get("mode", ...)
        if (mode is None or isinstance(mode, str)) and newer("mode"):
            state.mode = mode
        armed = data.get("armed", ...)
        if (armed is None or isinstance(armed, bool)) and newer("armed"):
            state.armed = armed
        failsafe = data.get("failsafe")
        if isinstance(failsafe, bool) and newer("failsafe"):
            state.failsafe = failsafe
        connected = data.get("connected")
        if isinstance(connected, bool) and newer("autopilot_connected"):
            state.autopilot_connected = connected
        ready = data.get("optimiser_ready")
        if isinstance(ready, bool) and newer("optimiser_ready"):
            state.optimiser_ready = ready
        window = data.get("mission")
        if window in ("idle", "running", "ended") and newer("mission"):
            state.mission = str(window)
        fix = first_number(data, "gps_fix", "fix_type", "fix")
        if fix is not None and newer("gps_fix"):
            state.gps_fix = int(fix)
        elif fix is None and data.get("fix_type", ...) is None and newer("gps_fix"):
            state.gps_fix = None
        t_pose = t - max(0.0, first_number(data, "pose_age_s") or 0.0)
        lat, lon = first_number(data, "lat_deg", "lat"), first_number(data, "lon_deg", "lon")
        if lat is not None and lon is not None and not (abs(lat) <= 90 and abs(lon) <= 180):
            lat = lon = None  # not a place: never drawn, never the map's origin
        if data.get("position") == "none":
            if newer("position", t_pose):
                state.no_position = True
        elif lat is not None and lon is not None and newer("position", t_pose):
            state.no_position = False
            state.lat_deg, state.lon_deg = lat, lon
            state.x_m, state.y_m = self._local(lat, lon)
        x, y = first_number(data, "x_m", "x"), first_number(data, "y_m", "y")
        if x is not None and y is not None and lat is None and newer("position", t_pose):
            state.x_m, state.y_m = x, y
        alt = first_number(data, "alt_m", "alt_rel_m", "alt", "relative_alt_m")
        if alt is not None and newer("alt_m", t_pose):
            state.alt_m = alt
        heading = first_number(data, "heading_deg", "yaw_deg", "hdg_deg")
        if heading is not None and newer("heading_deg", t_pose):
            state.heading_deg = heading
        xi = first_number(data, "xi_bytes_per_s", "xi", "constraint_bytes_per_s",
                          "limit_bytes_per_s")
        if xi is not None and newer("xi_bytes_per_s"):
            state.xi_bytes_per_s = xi
        period = declared_status_period(data)
        if period is not None:
            state.status_period_s = period
        fallback = first_number(data, "fallback_share")
        if fallback is not None and 0.0 <= fallback <= 1.0:
            state.fallback_share = fallback
        peers = data.get("peers")
        if isinstance(peers, Mapping) and newer("peers"):
            state.peers = {str(k): float(v) for k, v in list(peers.items())[:64]
                           if isinstance(v, int | float) and not isinstance(v, bool)
                           and math.isfinite(v) and v >= 0}
        delta = first_number(data, "delta_s", "delta")
        if delta is not None and newer("delta_s"):
            state.delta_s = delta
        loss = first_number(data, "loss", "loss_share", "loss_rate")
        if loss is not None and newer("loss"):
            state.loss = loss
        text = data.get("statustext", data.get("text"))
        if isinstance(text, str) and text:
            severity = first_number(data, "severity")
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

    def on_drop(self, reason: str, *, now: float, drone: str | None = None,
                skew_s: float | None = None) -> None:
        self.drops[reason] += 1
        if drone is not None and skew_s is not None:  # refused for its clock: name it
            if (text := self.clocks.refused(drone, skew_s, now)) is not None:
                self.alert(Alert(t=now, level="error", kind="clock", drone=drone, text=text))
            return
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

    def _forget(self, drone: str) -> None:
        del self.drones[drone]
        self.forgotten += 1
        self._forgotten_ids.append(drone)

    def forget_silent(self, *, now: float) -> None:
        """Drop the tiles of drones silent for ``forget_after_s``."""
        for drone in [d for d, s in self.drones.items()
                      if now - s.last_heard > self.forget_after_s]:
            self._forget(drone)

    def take_forgotten(self) -> list[str]:
        """Drones forgotten since the last call (the shell forgets them elsewhere too)."""
        out, self._forgotten_ids = self._forgotten_ids, []
        return out

    def take_back(self) -> list[str]:
        """Drones heard again since the last call after a link loss (or, restored from
        storage, for the first time since the station started)."""
        out, self._back_ids = self._back_ids, []
        return out

    def take_new_alerts(self) -> list[Alert]:
        """Alerts raised since the last call (the shell broadcasts and stores them)."""
        out, self._new_alerts = self._new_alerts, []
        return out

    # -- periodic -----------------------------------------------------------------------
    def tick(self, *, now: float) -> dict[str, Any]:
        """Sample the link charts and check for link loss; returns the new series point."""
        self.forget_silent(now=now)
        for drone, text in self.status_unheard.check(now) if self.status_unheard else ():
            self.alert(Alert(t=now, level="warning", kind="config", drone=drone, text=text))
        goodput_total = 0.0
        point_drones: dict[str, dict[str, float | None]] = {}
        latencies: list[float] = []
        for drone, state in self.drones.items():
            if not state.link_lost and now - state.last_heard > lost_after_s(self.link_lost_s,
                                                                      state.status_period_s):
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
    def goodput_total(self, *, now: float) -> float:
        return sum(s.goodput_bytes_per_s(now) for s in self.drones.values())

    def drone_json(
        self, state: DroneState, *, now: float, goodput_total: float | None = None
    ) -> dict[str, Any]:
        """One tile; pass ``goodput_total`` when building many (it costs a pass over all)."""
        if goodput_total is None:
            goodput_total = self.goodput_total(now=now)
        own = state.goodput_bytes_per_s(now)
        ages = {name: round(max(0.0, now - t), 3) for name, t in state.field_t.items()}
        slow = max(DEFAULT_STALE_AFTER_S, 2.5 * (state.status_period_s or 0.0))
        stale_after = {name: STALE_AFTER_S.get(name, slow) for name in ages}
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
            "failsafe": state.failsafe,
            "autopilot_connected": state.autopilot_connected,
            "optimiser_ready": state.optimiser_ready,
            "mission": state.mission,
            "no_position": state.no_position,
            "peers": _peer_ages(state, now),
            "ages": ages,
            "stale_after_s": stale_after,
            "t": now,
            "stale": sorted(name for name, age in ages.items() if age > stale_after[name]),
            "reports": list(state.reports),
            "latest_image": asdict(state.latest_image) if state.latest_image else None,
        }
        return out

    def snapshot(self, *, now: float) -> dict[str, Any]:
        total = self.goodput_total(now=now)
        return {
            "t": now,
            "drones": [self.drone_json(s, now=now, goodput_total=total)
                       for s in self.drones.values()],
            "forgotten": self.forgotten,
            "drops": dict(self.drops),
            "alerts": [asdict(a) for a in list(self.alerts)[-50:]],
            "series": self._recent_series(),
        }

    def _recent_series(self) -> list[dict[str, Any]]:
        """The latest chart points (at most 120) within ``SNAPSHOT_SERIES_VALUES`` per-drone
        values: with many drones the snapshot carries a shorter history, not more bytes."""
        out: list[dict[str, Any]] = []
        budget = SNAPSHOT_SERIES_VALUES
        for point in reversed(self.series):
            budget -= max(1, len(point["drones"]))
            if len(out) == 120 or (budget < 0 and len(out) >= 2):
                break
            out.append(point)
        out.reverse()
        return out
