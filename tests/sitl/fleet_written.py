"""What ``uav-sitl fleet`` writes into each companion's ``[middleware]`` table, read back by
the companion's own parser and policy builder (so the companion accepts it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from companion.app import build_decider
from companion.config import load_config
from companion.middleware import Middleware
from sitl.fleet import make_plan, parse_args
from sitl.fleet_config import write_run_configs


def middleware_values(tmp_path: Path, key: str, *argv: str) -> list[Any]:
    """Per drone, the mcts policy's ``key`` as built from the written config (None: not
    written, or another policy); the table holds ``key`` exactly when it is not None."""
    plan = make_plan(parse_args(list(argv)), tmp_path / "run")
    write_run_configs(plan)
    values = []
    for slot in plan.drones:
        config = load_config(slot.config_path)
        decider = build_decider(config)
        values.append(getattr(decider.config, key) if isinstance(decider, Middleware) else None)
        assert (key in config.middleware) == (values[-1] is not None)
    return values
