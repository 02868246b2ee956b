"""ADSB_VEHICLE in and out of the simulated autopilot (sitl.vehicle.traffic); mixed into
VehicleCore."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.traffic import TrafficAwareness, TrafficList

__all__ = ["TrafficHandlers"]


class TrafficHandlers:
    """The traffic list's MAVLink side; VehicleCore owns ``awareness``."""

    awareness: TrafficAwareness

    if TYPE_CHECKING:  # provided by VehicleCore
        def _send(self, msg: Any) -> None:
            raise NotImplementedError

        def statustext(self, severity: int, text: str) -> None:
            raise NotImplementedError

    @property
    def traffic(self) -> TrafficList:
        """The vehicles this autopilot knows from ADSB_VEHICLE (sitl.vehicle.traffic)."""
        return self.awareness.traffic

    def _on_adsb_vehicle(self, msg: Any, now: float) -> None:
        self.awareness.on_adsb_vehicle(msg, now)
        self._flush_traffic_texts()

    def _flush_traffic_texts(self) -> None:
        for severity, text in self.awareness.texts:
            self.statustext(severity, text)
        self.awareness.texts.clear()

    def _traffic_tick(self, now: float) -> None:
        """Expire, check avoidance, and send the list to the clients as ADSB_VEHICLE with
        ``tslc`` = age (ArduPilot's SRn_ADSB stream, PX4's ADSB_VEHICLE stream)."""
        self.awareness.tick(now)
        self.awareness.check_avoidance(now)
        self._flush_traffic_texts()
        for vehicle in self.traffic.vehicles.values():
            r = vehicle.report
            self._send(mavlink.MAVLink_adsb_vehicle_message(
                r.icao_address, round(r.lat_deg * 1e7), round(r.lon_deg * 1e7), 1,
                round(r.alt_amsl_m * 1000), round(r.heading_deg * 100) % 36000,
                max(0, min(65535, round(r.hor_velocity_m_s * 100))),
                max(-32768, min(32767, round(r.ver_velocity_m_s * 100))),
                r.callsign.encode()[:8], r.emitter_type,
                max(0, min(255, int(vehicle.age(now)))), r.flags, r.squawk))

