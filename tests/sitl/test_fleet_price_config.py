"""The relay fleet's ``[middleware] price_rate_s`` (docs/adaptive.md, "The decider's lag"):
written for the mcts companions on the shaped relay under the adaptive constraint, and read
back by the companion's own parser and policy builder; nowhere else."""

from __future__ import annotations

from pathlib import Path

from companion.app import build_decider
from companion.config import load_config
from companion.middleware import Middleware
from sitl.fleet import make_plan, parse_args
from sitl.fleet.link import RELAY_PRICE_RATE_S
from sitl.fleet_config import write_run_configs


def _price_rates(tmp_path: Path, *argv: str) -> list[float | None]:
    plan = make_plan(parse_args(["--drones", "2", *argv]), tmp_path / "run")
    write_run_configs(plan)
    rates = []
    for slot in plan.drones:
        config = load_config(slot.config_path)
        decider = build_decider(config)  # the companion accepts what the fleet wrote
        rates.append(decider.config.price_rate_s if isinstance(decider, Middleware) else None)
        assert ("price_rate_s" in config.middleware) == (rates[-1] is not None)
    return rates


def test_the_relay_fleet_prices_the_others_frames_by_their_rates(tmp_path: Path) -> None:
    assert RELAY_PRICE_RATE_S == 3.0
    assert _price_rates(tmp_path / "a") == [3.0, 3.0]  # the demo: relay, adaptive
    assert _price_rates(tmp_path / "b", "--constraint", "aimd") == [3.0, 3.0]


def test_other_links_constraints_and_policies_keep_every_forecast_frame(tmp_path: Path) -> None:
    assert _price_rates(tmp_path / "a", "--goodput", "20000") == [None, None]  # constant
    assert _price_rates(tmp_path / "b", "--relay-rate", "0") == [None, None]  # loopback
    for policy in ("random", "send_all"):
        assert _price_rates(tmp_path / policy, "--policy", policy) == [None, None]

