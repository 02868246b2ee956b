"""``examples/ground_station.toml``, the template `--config` names: it loads, every value it
shows is the default (so copying it changes nothing until edited), and it names every key
the station reads (commented where there is no default to show). A newcomer walking the
docs had `uav-ground-station run --config gs.toml` and no file to start from."""

from __future__ import annotations

import re
from pathlib import Path

from ground_station.config import _TYPES, GroundConfig, load_config

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ground_station.toml"


def test_example_loads_to_the_defaults() -> None:
    assert load_config(EXAMPLE) == GroundConfig()


def test_example_names_every_key() -> None:
    named = set(re.findall(r"^(?:# )?([a-z_]+) = ", EXAMPLE.read_text(), re.MULTILINE))
    assert sorted(set(_TYPES) - named) == []
    assert sorted(named - set(_TYPES)) == []
