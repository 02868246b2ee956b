"""The dashboard's view model tells the truth: field ages, staleness, no rollback, no position."""

from __future__ import annotations

from typing import Any

from ground_station.fleet import FleetView
from utility_specs.message import Message

T0 = 1_700_000_000.0


def _msg(seq: int, type_: str, t_gen: float, **data: Any) -> Message:
    return Message(sender="d1", seq=seq, type=type_, t_gen=t_gen, t_rcv=t_gen + 0.1, size=100,
                   data=data)


def test_every_field_has_an_age_and_is_stale_past_its_bound() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=30.0)
    fv.on_message(_msg(1, "status", T0, mode="GUIDED", armed=True, connected=True,
                       failsafe=False, fix_type=3, since=T0 - 5), now=T0 + 0.1)
    fv.on_message(_msg(2, "position", T0 + 1, lat_deg=50.0, lon_deg=19.0, alt_rel_m=20.0,
                       pose_age_s=0.5), now=T0 + 1.1)
    fv.on_message(_msg(3, "battery", T0 + 2, level=0.8), now=T0 + 2.1)
    d = fv.drone_json(fv.drones["d1"], now=T0 + 4.0)
    assert d["ages"] == {"mode": 4.0, "armed": 4.0, "failsafe": 4.0, "autopilot_connected": 4.0,
                         "gps_fix": 4.0, "position": 3.5, "alt_m": 3.5, "battery": 2.0}
    assert d["stale"] == ["alt_m", "position"]  # > 3 s: three position samples missed
    assert (d["mode"], d["armed"], d["failsafe"], d["autopilot_connected"]) == (
        "GUIDED", True, False, True)
    d = fv.drone_json(fv.drones["d1"], now=T0 + 13.0)
    assert d["stale"] == ["alt_m", "armed", "autopilot_connected", "failsafe", "gps_fix",
                          "mode", "position"]
    assert d["stale_after_s"]["position"] == 3.0 and d["stale_after_s"]["mode"] == 12.0
    assert fv.tick(now=T0 + 13.0)["t"] == T0 + 13.0
    assert fv.snapshot(now=T0 + 13.0)["drones"][0]["stale"] == d["stale"]


def test_an_older_message_never_rolls_a_field_back() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=30.0)
    fv.on_message(_msg(5, "status", T0 + 5, mode="GUIDED", armed=True), now=T0 + 5.1)
    fv.on_message(_msg(4, "status", T0 + 4, mode="STABILIZE", armed=False), now=T0 + 5.2)
    fv.on_message(_msg(6, "image", T0 + 3, lat_deg=1.0, lon_deg=1.0), now=T0 + 5.3)
    fv.on_message(_msg(7, "position", T0 + 6, lat_deg=50.0, lon_deg=19.0), now=T0 + 6.1)
    # a late image geotagged with an older pose does not move the drone back
    fv.on_message(_msg(8, "image", T0 + 6.5, lat_deg=49.0, lon_deg=18.0, pose_age_s=2.0),
                  now=T0 + 6.6)
    d = fv.drone_json(fv.drones["d1"], now=T0 + 7.0)
    assert (d["mode"], d["armed"], d["lat_deg"], d["lon_deg"]) == ("GUIDED", True, 50.0, 19.0)


def test_no_position_is_shown_as_such_until_a_fix_comes() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=30.0)
    fv.on_message(_msg(1, "image", T0, position="none", roll_rad=0.1), now=T0 + 0.1)
    d = fv.drone_json(fv.drones["d1"], now=T0 + 0.5)
    assert (d["no_position"], d["lat_deg"], d["ages"]["position"]) == (True, None, 0.5)
    fv.on_message(_msg(2, "position", T0 + 1, lat_deg=50.0, lon_deg=19.0), now=T0 + 1.1)
    d = fv.drone_json(fv.drones["d1"], now=T0 + 1.5)
    assert (d["no_position"], d["lat_deg"]) == (False, 50.0)
    fv.on_message(_msg(3, "image", T0 + 2, position="none"), now=T0 + 2.1)  # the fix is lost
    assert fv.drone_json(fv.drones["d1"], now=T0 + 2.5)["no_position"] is True
