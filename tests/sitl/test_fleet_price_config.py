"""The relay fleet's ``[middleware] price_rate_s`` (docs/adaptive.md, "The decider's lag"):
written for the mcts companions on the shaped relay under the adaptive constraint, and read
back by the companion's own parser and policy builder; nowhere else."""

from __future__ import annotations

from pathlib import Path

from sitl.fleet.link import RELAY_PRICE_RATE_S
from tests.sitl.fleet_written import middleware_values


def _price_rates(tmp_path: Path, *argv: str) -> list[float | None]:
    return middleware_values(tmp_path, "price_rate_s", "--drones", "2", *argv)


def test_the_relay_fleet_prices_the_others_frames_by_their_rates(tmp_path: Path) -> None:
    assert RELAY_PRICE_RATE_S == 3.0
    assert _price_rates(tmp_path / "a") == [3.0, 3.0]  # the demo: relay, adaptive
    assert _price_rates(tmp_path / "b", "--constraint", "aimd") == [3.0, 3.0]


def test_other_links_constraints_and_policies_keep_every_forecast_frame(tmp_path: Path) -> None:
    assert _price_rates(tmp_path / "a", "--goodput", "20000") == [None, None]  # constant
    assert _price_rates(tmp_path / "b", "--relay-rate", "0") == [None, None]  # loopback
    for policy in ("random", "send_all"):
        assert _price_rates(tmp_path / policy, "--policy", policy) == [None, None]

