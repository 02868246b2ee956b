"""``[ground_station] link_rate_bytes_per_s``: the rate each message's datagrams are paced at;
the fleet launcher writes its shaped link's rate (``--netns``, or the relay's) into every
companion."""

from __future__ import annotations

import time
import tomllib
from pathlib import Path
from typing import Any

import pytest

from companion.app import CompanionApp
from companion.config import ConfigError, parse_config
from companion.middleware.decider import Decision
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
    (["--netns", "--drones", "2"], 750_000.0),  # 6 Mbit/s
    (["--netns", "--drones", "2", "--link-rate", "2000000"], 250_000.0),
    (["--drones", "2"], 50_000.0),  # the relay's 400 kbit/s (docs/adaptive.md, narrow link)
    (["--drones", "2", "--relay-rate", "0"], None),  # no shaped link: nothing written
])
def test_the_fleet_writes_its_link_rate(tmp_path: Path, argv: list[str],
                                        rate: float | None) -> None:
    args = parse_args(argv)
    plan = make_plan(args, tmp_path / "run", netns=args.netns)
    for drone in plan.drones:
        gs = tomllib.loads(companion_toml(plan, drone))["ground_station"]
        assert gs.get("link_rate_bytes_per_s") == rate


class _Transport:
    """Records what the app sets; sends nothing."""

    def __init__(self) -> None:
        self.paced_at: float | None = None

    def pace(self, rate_bytes_per_s: float) -> None:
        self.paced_at = rate_bytes_per_s

    async def run(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def send_message(self, *_: Any, **__: Any) -> int:
        return 1

    def send_status(self, *_: Any) -> int:
        return 1


class _SendAll:
    def decide(self, message: Any, now: float) -> Decision:
        return Decision(send=True, reason="test")

    def get_timer(self) -> float | None:
        return None


@pytest.mark.parametrize(("configured", "paced_at"), [(0.0, None), (50_000.0, 50_000.0)])
def test_the_companion_paces_at_the_configured_link_rate(
        tmp_path: Path, configured: float, paced_at: float | None) -> None:
    config = parse_config({"drone": {"id": "d1"}, "camera": {"enabled": False},
                           "mission": {"log": str(tmp_path / "log.jsonl")},
                           "ground_station": {"link_rate_bytes_per_s": configured}})
    made: list[_Transport] = []

    def factory(on_event: Any) -> _Transport:
        made.append(_Transport())
        return made[-1]

    CompanionApp(config, decider=_SendAll(), transport_factory=factory,  # type: ignore[arg-type]
                 clock=time.time)
    (transport,) = made
    assert transport.paced_at == paced_at  # 0 (unknown): every message's datagrams leave at once
