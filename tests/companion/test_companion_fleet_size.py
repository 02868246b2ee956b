"""``[middleware] fleet_size``: the companion reads it, checks it and gives it to the mcts
policy (the mission-start share of issue 18, round 7); a live ``set_params`` cannot change it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from companion.app import AppSetupError, build_decider
from companion.config import ConfigError, parse_config
from companion.middleware import Middleware

SCRIPT = Path(sys.executable).parent / "uav-companion"
COMMAND = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "companion.cli"]


def _raw(**middleware: Any) -> dict[str, Any]:
    return {"drone": {"id": "d1"}, "mavlink": {"url": "udpin:127.0.0.1:14550"},
            "constraint": {"name": "constant", "params": {"limit_bytes_per_s": 20000.0}},
            "middleware": middleware}


def test_fleet_size_reaches_the_mcts_policy() -> None:
    decider = build_decider(parse_config(_raw(fleet_size=4, seed=1)))
    assert isinstance(decider, Middleware)
    assert decider.config.fleet_size == 4
    assert build_decider(parse_config(_raw())).config.fleet_size is None  # type: ignore[attr-defined]


def test_fleet_size_is_not_a_live_parameter() -> None:
    """It acts only in the first seconds of a mission: a ground station's set_params is
    refused and changes nothing."""
    decider = build_decider(parse_config(_raw(fleet_size=4)))
    assert isinstance(decider, Middleware)
    result = decider.set_params({"fleet_size": 10}, 0.0)
    assert not result.ok and "fleet_size" in (result.error or "")
    assert decider.config.fleet_size == 4


@pytest.mark.parametrize("value", [0, -3, 2.5, True, "4", [4]])
def test_a_bad_fleet_size_is_a_config_error(value: Any) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(_raw(fleet_size=value), source="c.toml")
    assert str(caught.value) == (f"c.toml: middleware.fleet_size: expected an integer >= 1, "
                                 f"got {value!r}")


def test_other_policies_refuse_fleet_size_by_name() -> None:
    with pytest.raises(AppSetupError, match=r"c\.toml: middleware\.fleet_size: expected one "
                                            r"of policy, seed, "):
        build_decider(parse_config(_raw(policy="send_all", fleet_size=4), source="c.toml"))


def test_check_names_a_bad_fleet_size_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[drone]\nid = "d1"\n[middleware]\nfleet_size = 0\n')
    result = subprocess.run([*COMMAND, "--log-format", "text", "check", "--config", str(path),
                             "--skip-mavlink", "--skip-camera"],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].endswith(
        f"{path}: middleware.fleet_size: expected an integer >= 1, got 0")
    assert "Traceback" not in result.stderr
