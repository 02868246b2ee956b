"""``[middleware] dp_seed``: the width of the programme that seeds every search (issue 18,
round 13); the companion reads it, checks it, and 0 turns the seed off (alg. 2's rule)."""

from __future__ import annotations

from typing import Any

import pytest

from companion.app import build_decider
from companion.config import ConfigError, parse_config
from companion.middleware import Middleware


def _raw(**middleware: Any) -> dict[str, Any]:
    return {"drone": {"id": "d1"}, "mavlink": {"url": "udpin:127.0.0.1:14550"},
            "constraint": {"name": "constant", "params": {"limit_bytes_per_s": 20000.0}},
            "middleware": middleware}


def _decider(**middleware: Any) -> Middleware:
    decider = build_decider(parse_config(_raw(**middleware)))
    assert isinstance(decider, Middleware)
    return decider


def test_dp_seed_reaches_the_mcts_policy() -> None:
    assert _decider().config.dp_seed == 128  # the default
    assert _decider(dp_seed=32).config.dp_seed == 32
    assert _decider(dp_seed=0).config.dp_seed is None


def test_dp_seed_is_not_a_live_parameter() -> None:
    decider = _decider(dp_seed=32)
    result = decider.set_params({"dp_seed": 8}, 0.0)
    assert not result.ok and "dp_seed" in (result.error or "")
    assert decider.config.dp_seed == 32


@pytest.mark.parametrize("value", [-1, 2.5, True, "128", [128]])
def test_a_bad_dp_seed_is_a_config_error(value: Any) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(_raw(dp_seed=value), source="c.toml")
    assert str(caught.value) == (f"c.toml: middleware.dp_seed: expected an integer >= 0, "
                                 f"got {value!r}")
