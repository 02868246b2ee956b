"""Every registered constraint can drive the fleet, scaled to the relay's rate."""

from __future__ import annotations

import pytest

from companion.middleware.constraints.registry import CONSTRAINTS, make_constraint
from sitl.fleet.cli import parse_args
from sitl.fleet.link import relay_constraint_params


@pytest.mark.parametrize("name", ["adaptive", "adaptive-smooth", "adaptive-thesis", "aimd"])
def test_each_learning_constraint_is_built_from_the_relay_parameters(name: str) -> None:
    rate = 50_000.0
    constraint = make_constraint(name, **relay_constraint_params(name, rate))
    assert constraint.window_s == 0.5
    assert 0.05 * rate <= constraint.limit_bytes_per_s(now=0.0) <= rate


def test_the_fleet_offers_every_registered_constraint() -> None:
    for name in CONSTRAINTS:
        assert parse_args(["--constraint", name]).constraint == name


def test_peers_alone_selects_a_spec_that_shares_with_peers() -> None:
    """`uav-sitl fleet --peers` with the image-streaming spec shared nothing (no type has
    peers among its receivers): every drone's peer list stayed empty."""
    assert parse_args(["--peers"]).spec == "peer_sharing"
    assert parse_args([]).spec == "image_streaming"
    assert parse_args(["--peers", "--spec", "sync_swarm"]).spec == "sync_swarm"
