"""Telemetry as messages: ``position``, ``battery`` and ``status`` from the telemetry state.

Every message goes through the dispatcher (the optimiser decides about it like about an image).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable, Mapping
from typing import Any

from companion.config import TelemetryConfig
from companion.dispatch import Dispatcher
from companion.mission import MissionWindow
from companion.telemetry import (
    GPS_FIX_3D,
    Sample,
    StatusTextSample,
    TelemetrySnapshot,
    TelemetryState,
)

__all__ = ["FAILSAFE_STATES", "IDLE_STATUS_PERIOD_S", "MAX_PENDING_TEXTS", "STATUSTEXT_GAP_S",
           "TelemetryPublisher", "statustext_field"]

Clock = Callable[[], float]

IDLE_STATUS_PERIOD_S = 1.0
"""Status period outside the mission window, when status is all a drone sends: often enough
that the ground station (``link_lost_s`` 3 s) does not take an ended mission for a lost link."""

FAILSAFE_STATES = (5, 6)
"""MAV_STATE_CRITICAL and MAV_STATE_EMERGENCY: the autopilot is in a failsafe."""

STATUSTEXT_GAP_S = 0.5
"""Autopilot texts ride on a status at most this often (a state change still goes at once).
Each STATUSTEXT used to trigger a status: a chatty or hostile autopilot link made a status
per optimiser decision, dozens a second on a radio link meant for about one."""
MAX_PENDING_TEXTS = 20
"""Texts kept between two statuses; beyond that the least severe (oldest first) are dropped
and counted in the text (``+N more``)."""
STATUSTEXT_CHARS = 200


def statustext_field(texts: list[StatusTextSample], dropped: int = 0) -> str:
    """The status's ``statustext``: most severe first (arrival order within a severity), so
    the text cut at :data:`STATUSTEXT_CHARS` always begins with the one whose ``severity``
    the status reports. Oldest first, a flood of INFO texts once pushed an EMERGENCY out of
    the text while its severity stayed: the station showed chatter as an error."""
    ordered = sorted(texts, key=lambda s: s.severity)  # stable: arrival order kept
    suffix = f" (+{dropped} more)" if dropped else ""
    return " | ".join(s.text for s in ordered)[:STATUSTEXT_CHARS - len(suffix)] + suffix


class TelemetryPublisher:
    """Turns the telemetry state into ``position``, ``battery`` and ``status`` messages.

    Position at ``position_rate_hz`` (1 Hz: eq. 4.11's position utility), battery every
    ``battery_period_s`` (data ``level`` in 0..1 for eq. 4.9), mission status every
    ``status_period_s`` and at once when mode, armed state, failsafe, link or mission state
    change. Each status carries ``since``, when its state began (the ``status_change``
    utility: a new state is worth sending at once); while no status of the current state
    has gone out (the constraint's window was full), it is offered again every
    ``STATE_RETRY_S``, not only every period; after ``STATE_RETRIES`` such retries the
    interval doubles up to the period (a dead link does not cost two decisions a second).
    """

    STATE_RETRY_S = 0.5
    STATE_RETRIES = 4

    def __init__(self, settings: TelemetryConfig, *, telemetry: TelemetryState,
                 dispatcher: Dispatcher, mission: MissionWindow, clock: Clock) -> None:
        self._settings = settings
        self._telemetry = telemetry
        self._dispatcher = dispatcher
        self._mission = mission
        self._clock = clock
        self._stopping = asyncio.Event()
        self._status_key: tuple[Any, ...] | None = None
        self.status_extra: Callable[[], Mapping[str, Any]] | None = None
        """More fields for every status message (set by the app)."""
        self._wake = asyncio.Event()
        self._statustexts: list[StatusTextSample] = []
        self._texts_dropped = 0
        self._t_status_sent = -math.inf
        """Loop time of the last status sent (texts wait for ``STATUSTEXT_GAP_S`` after it)."""
        self._since: float | None = None
        """When the current status key began (fleet clock)."""
        self._announced: float | None = None
        """``since`` of the newest state a sent status reported."""
        self._last_position: float | None = None
        self._retries = 0

    def on_sample(self, sample: Sample) -> None:
        if isinstance(sample, StatusTextSample):  # autopilot messages ride on the status
            texts = self._statustexts
            texts.append(sample)
            if len(texts) > MAX_PENDING_TEXTS:  # the least severe goes, oldest first
                del texts[max(range(len(texts)), key=lambda i: (texts[i].severity, -i))]
                self._texts_dropped += 1
            self._wake.set()
            return
        snap = self._telemetry.snapshot()
        if self._status_key is not None and self._status_key != self._key(snap):
            self._wake.set()

    def _key(self, snap: TelemetrySnapshot) -> tuple[Any, ...]:
        failsafe = snap.system_status in FAILSAFE_STATES
        # The fix too: after a reconnection or a reboot the status went out at once with the
        # fix unknown, and the dashboard showed "no fix" beside a fresh position until the
        # next periodic status (5 s later). Whether it is a 3-D fix, not its exact type, so
        # an RTK fix wavering between 5 and 6 does not send a status a second.
        fix = None if snap.gps_fix_type is None else snap.gps_fix_type >= GPS_FIX_3D
        return (snap.mode, snap.armed, failsafe, snap.connected, fix, self._mission.state)

    async def run(self) -> None:
        cfg = self._settings
        loop = asyncio.get_running_loop()
        period_pos = 1.0 / cfg.position_rate_hz if cfg.position_rate_hz > 0 else math.inf
        t_pos = t_bat = t_status = loop.time()
        try:
            while not self._stopping.is_set():
                now_mono = loop.time()
                snap = self._telemetry.snapshot()
                if now_mono >= t_pos:
                    t_pos = now_mono + period_pos
                    if snap.position_problem is None and snap.t_position != self._last_position:
                        self._last_position = snap.t_position  # never the same fix twice
                        await self._dispatcher.submit_telemetry("position", self._position(snap))
                if now_mono >= t_bat:
                    t_bat = now_mono + cfg.battery_period_s
                    if snap.battery_remaining is not None and snap.battery_remaining > 0:
                        await self._dispatcher.submit_telemetry("battery", self._battery(snap))
                if self._wake.is_set():
                    self._wake.clear()
                    if self._status_key is not None and self._key(snap) != self._status_key:
                        t_status = now_mono  # a new state goes at once
                    elif self._statustexts:
                        t_status = min(t_status, self._t_status_sent + STATUSTEXT_GAP_S)
                if now_mono >= t_status:
                    self._t_status_sent = now_mono
                    t_status = now_mono + self._status_period()
                    key = self._key(snap)
                    if key != self._status_key or self._since is None:
                        self._since = self._clock()
                        self._retries = 0
                    self._status_key = key
                    if await self._dispatcher.submit_telemetry("status", self._status(snap)):
                        self._announced = self._since
                    elif self._announced != self._since:  # a new state not told yet
                        backoff = 2.0 ** max(0, self._retries - self.STATE_RETRIES + 1)
                        self._retries += 1
                        t_status = min(t_status, now_mono + self.STATE_RETRY_S * backoff)
                wait = max(0.0, min(t_pos, t_bat, t_status) - loop.time())
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(wait):
                        await self._either(self._stopping, self._wake)
        finally:
            self._stopping.set()

    @staticmethod
    async def _either(a: asyncio.Event, b: asyncio.Event) -> None:
        waits = [asyncio.ensure_future(a.wait()), asyncio.ensure_future(b.wait())]
        try:
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()

    def stop(self) -> None:
        self._stopping.set()

    def _position(self, snap: TelemetrySnapshot) -> dict[str, Any]:
        return snap.geotag(at=self._clock())

    @staticmethod
    def _battery(snap: TelemetrySnapshot) -> dict[str, Any]:
        data: dict[str, Any] = {"level": snap.battery_remaining}
        if snap.battery_v is not None and math.isfinite(snap.battery_v):
            data["battery_v"] = snap.battery_v
        return data

    def _status_period(self) -> float:
        period = self._settings.status_period_s
        return period if self._mission.running else min(period, IDLE_STATUS_PERIOD_S)

    def _status(self, snap: TelemetrySnapshot) -> dict[str, Any]:
        """Mission status; field names are the ones the ground station's fleet view reads."""
        # Not heard, the autopilot's mode, arming and fix are unknown (null), not the last
        # ones heard: across a reboot the station showed the old "armed, 3D fix" as current.
        # After it, a fix not reported yet is null too (a rebooted autopilot has none).
        heard = snap.connected
        data: dict[str, Any] = {"mode": snap.mode if heard else None,
                                "armed": snap.armed if heard else None,
                                "connected": snap.connected, "since": self._since,
                                "failsafe": snap.system_status in FAILSAFE_STATES and heard,
                                "mission": self._mission.state, "autopilot": snap.autopilot,
                                "optimiser_ready": self._dispatcher.optimiser_ready,
                                "fix_type": snap.gps_fix_type if heard else None,
                                # The station judges this drone's silence by it (its own
                                # link_lost_s assumes a status every second or so).
                                "status_period_s": self._status_period()}
        xi = self._dispatcher.constraint_limit()
        if xi is not None:
            data["xi_bytes_per_s"] = xi
        data |= self._dispatcher.link_health()  # Δ and loss for the station
        fallback = self._dispatcher.fallback_share()
        if fallback is not None:
            data["fallback_share"] = fallback
        if self.status_extra is not None:  # e.g. the peers' ages (companion.peers)
            data.update(self.status_extra())
        if self._statustexts:
            data["statustext"] = statustext_field(self._statustexts, self._texts_dropped)
            data["severity"] = min(s.severity for s in self._statustexts)
            self._statustexts.clear()
            self._texts_dropped = 0
        return data
