"""The dashboard shows, per drone, which peers it knows and how old each is (issue 15)."""

from __future__ import annotations

from companion.peers import PeerServices, PeersSettings, PeerTable
from ground_station.fleet import FleetView
from utility_specs.message import Message


def test_a_status_carries_the_peer_ages_and_the_tile_ages_them() -> None:
    view = FleetView(high_utility=None, link_lost_s=5.0)
    state = view.heard("drone1", now=100.0)
    view.apply_data(state, {"mode": "AUTO", "peers": {"drone3": 1.2, "drone2": 0.4}},
                    now=100.0)
    assert view.drone_json(state, now=100.0)["peers"] == {"drone2": 0.4, "drone3": 1.2}
    # two seconds later the same positions are two seconds older at the drone
    assert view.drone_json(state, now=102.0)["peers"] == {"drone2": 2.4, "drone3": 3.2}
    # an older status does not take the tile back; junk values are skipped
    view.apply_data(state, {"peers": {"drone2": 9.0}}, now=103.0, t_obs=99.0)
    view.apply_data(state, {"peers": {"drone2": 0.1, "bad": "x", "neg": -1, "nan": float("nan")}},
                    now=104.0)
    assert view.drone_json(state, now=104.0)["peers"] == {"drone2": 0.1}
    other = view.heard("drone9", now=104.0)
    assert view.drone_json(other, now=104.0)["peers"] is None  # reports none: not shown


def test_the_companion_status_carries_its_peers_only_on_a_medium() -> None:
    now = [200.0]
    services = PeerServices(PeersSettings(medium="broadcast:127.255.255.255:14700"),
                            own_id="drone1", clock=lambda: now[0])
    assert services.status_fields() == {"peers": {}}
    services.table.on_message(Message(sender="drone2", seq=1, type="position", t_gen=199.0,
                                      size=30, data={"lat_deg": 47.0, "lon_deg": 8.0}),
                              now=199.1)
    services.table.on_message(Message(sender="drone3", seq=1, type="battery", t_gen=198.0,
                                      size=30, data={"level": 0.5}), now=198.5)
    # drone2's position is 1 s old; drone3 sent no position: the age of its last word
    assert services.status_fields() == {"peers": {"drone2": 1.0, "drone3": 1.5}}
    off = PeerServices(PeersSettings(), own_id="drone1", clock=lambda: now[0])
    assert off.status_fields() == {}
    assert PeerTable("a").ages(0.0) == {}
