"""`uav-sitl fleet --peers` (sitl/fleet_peers.py): the configs it writes and the summary lines."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.config import parse_config
from ground_station.config import config_from_mapping
from sitl.fleet import make_plan, parse_args
from sitl.fleet_config import companion_toml, ground_station_toml
from sitl.fleet_peers import format_peers, position_age_bound, vehicle_args


def test_peers_plan_configures_medium_endpoint_and_station(tmp_path: Path) -> None:
    args = parse_args(["--drones", "3", "--peers", "--spec", "peer_sharing"])
    plan = make_plan(args, tmp_path)
    assert plan.peers_medium is not None and plan.peers_medium.startswith(
        "broadcast:127.255.255.255:")
    assert len(set(plan.peers_http_ports.values())) == 3
    for slot in plan.drones:
        raw = tomllib.loads(companion_toml(plan, slot))
        assert raw["peers"] == {"medium": plan.peers_medium, "adsb_rate_hz": 1.0,
                                "http": f"127.0.0.1:{plan.peers_http_ports[slot.drone_id]}"}
        raw["ground_station"].pop("fleet_key_file")  # not written yet: no keys in this test
        raw["ground_station"].pop("command_public_key_file")
        assert parse_config(raw).peers.medium == plan.peers_medium
    gs = tomllib.loads(ground_station_toml(plan))["ground_station"]
    assert gs["shared_medium"] == plan.peers_medium
    for key in ("fleet_key_file", "command_key_file"):
        gs.pop(key)
    assert config_from_mapping({"ground_station": gs}).shared_medium == plan.peers_medium
    assert vehicle_args("ardupilot") == ["--param", "ADSB_TYPE=1"]
    assert vehicle_args("px4") == []


def test_without_peers_nothing_changes(tmp_path: Path) -> None:
    plan = make_plan(parse_args(["--drones", "2"]), tmp_path)
    assert plan.peers_medium is None
    assert "peers" not in tomllib.loads(companion_toml(plan, plan.drones[0]))
    assert "shared_medium" not in ground_station_toml(plan)


def test_peers_with_netns_use_the_bridges_broadcast(tmp_path: Path) -> None:
    """--netns: every member is on the namespaces' 10.199.0.0/24 bridge, so the medium is its
    broadcast address; each companion's /peers stays on 127.0.0.1 inside its namespace."""
    args = parse_args(["--drones", "3", "--peers", "--netns", "--spec", "peer_sharing"])
    plan = make_plan(args, tmp_path, netns=True)
    assert plan.peers_medium is not None
    kind, address, port = plan.peers_medium.split(":")
    assert (kind, address) == ("broadcast", "10.199.0.255")
    assert int(port) != plan.gs_udp_port
    for slot in plan.drones:
        raw = tomllib.loads(companion_toml(plan, slot))
        assert raw["peers"]["medium"] == plan.peers_medium
        assert raw["peers"]["http"] == f"127.0.0.1:{plan.peers_http_ports[slot.drone_id]}"
    assert tomllib.loads(ground_station_toml(plan))["ground_station"]["shared_medium"] \
        == plan.peers_medium


def test_summary_lines() -> None:
    known = {"drone1": {"drone2": 0.4, "drone3": 1.2}, "drone2": {"drone1": 0.6, "drone3": None},
             "drone3": None}
    lines = format_peers(known, ["drone1", "drone2", "drone3"])
    assert lines[1] == "  drone1: drone2 0.4 s, drone3 1.2 s"
    assert lines[2] == "  drone2: drone1 0.6 s; missing drone3"
    assert lines[3] == "  drone3: no answer from its /peers endpoint"
    assert lines[4] == "  every drone knows every peer: no, oldest position 1.2 s"
    ok = format_peers({"a": {"b": 0.3}, "b": {"a": 0.5}}, ["a", "b"], bound_s=37.6)
    assert ok[-2] == "  every drone knows every peer: yes, oldest position 0.5 s"
    assert ok[-1].endswith("37.6 s: every position within it")
    late = format_peers({"a": {"b": 40.0}, "b": {"a": 0.5}}, ["a", "b"], bound_s=37.6)
    assert late[-1].endswith("NOT met")


def test_age_bound_from_the_spec() -> None:
    from utility_specs.files import builtin_spec

    spec = builtin_spec("peer_sharing")
    # v_max 15 m/s over 1 km²: a position is worth nothing after sqrt(A / (pi v²)) = 37.6 s
    assert position_age_bound(Path(spec.source)) == pytest.approx(37.61, abs=0.01)
    assert position_age_bound(Path(builtin_spec("image_streaming").source)) == pytest.approx(
        37.61, abs=0.01)
