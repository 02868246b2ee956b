"""Operator checks (audit 12): a station restarted mid-mission raised, for every drone of
the stored mission, "link lost: nothing heard for 6.2 s" and then "link back" (its tiles
were seeded from storage as if heard at their last image), though no drone's link had a
problem. A restored tile is lost (dimmed) until heard, without either alert; a drone that
goes silent after it was heard again is still alerted."""

from __future__ import annotations

from ground_station.fleet import FleetView

T0 = 1_700_000_000.0


def _link_alerts(fleet: FleetView) -> list[tuple[str | None, str]]:
    return [(a.drone, a.text) for a in fleet.alerts if a.kind == "link"]


def test_a_restored_tile_is_lost_until_heard_without_alerts() -> None:
    fleet = FleetView(high_utility=3.0, link_lost_s=3.0)
    state = fleet.restore("drone1", last_heard=T0)
    fleet.restore("drone2", last_heard=T0 - 60)  # never comes back
    assert state.link_lost and state.restored
    fleet.tick(now=T0 + 6.2)
    assert fleet.drones["drone2"].link_lost
    fleet.heard("drone1", now=T0 + 7)
    assert not state.link_lost and not state.restored
    assert _link_alerts(fleet) == []
    fleet.tick(now=T0 + 11)  # heard in this run, then silent: a real loss
    fleet.heard("drone1", now=T0 + 12)
    assert _link_alerts(fleet) == [("drone1", "link lost: nothing heard for 4.0 s"),
                                   ("drone1", "link back")]


def test_a_drone_heard_before_its_tile_is_restored_stays_live() -> None:
    fleet = FleetView(high_utility=3.0, link_lost_s=3.0)
    fleet.heard("drone1", now=T0 + 5)
    state = fleet.restore("drone1", last_heard=T0)
    assert not state.link_lost and state.last_heard == T0 + 5
