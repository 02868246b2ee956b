"""``[ground_station] link_rate_bytes_per_s``: the link's rate caps the pacing rate; the fleet
launcher writes its shaped link's rate into every companion."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.config import ConfigError, parse_config
from sitl.fleet import make_plan, parse_args
from sitl.fleet_config import companion_toml


def test_the_link_rate_is_read_and_checked() -> None:
    assert parse_config({"drone": {"id": "d"}}).ground_station.link_rate_bytes_per_s == 0.0
    config = parse_config({"drone": {"id": "d"},
                           "ground_station": {"link_rate_bytes_per_s": 50_000}})
    assert config.ground_station.link_rate_bytes_per_s == 50_000.0
    with pytest.raises(ConfigError, match="link_rate_bytes_per_s: expected a number >= 0"):
        parse_config({"drone": {"id": "d"}, "ground_station": {"link_rate_bytes_per_s": -1}})


@pytest.mark.parametrize(("argv", "rate"), [
    (["--drones", "2"], 50_000.0),  # the default relay: 400 kbit/s
    (["--drones", "2", "--relay-rate", "800000"], 100_000.0),
    (["--netns", "--drones", "2"], 750_000.0),  # 6 Mbit/s
    (["--drones", "2", "--relay-rate", "0"], None),  # no shaped link: nothing written
])
def test_the_fleet_writes_its_link_rate(tmp_path: Path, argv: list[str],
                                        rate: float | None) -> None:
    args = parse_args(argv)
    plan = make_plan(args, tmp_path / "run", netns=args.netns)
    for drone in plan.drones:
        gs = tomllib.loads(companion_toml(plan, drone))["ground_station"]
        assert gs.get("link_rate_bytes_per_s") == rate
