"""`uav-sitl fleet --fleet-share`: the companions' ``[middleware] fleet_size`` (issue 18,
round 7), read back by the companion's own parser and policy builder."""

from __future__ import annotations

from pathlib import Path

from tests.sitl.fleet_written import middleware_values


def _fleet_sizes(tmp_path: Path, *argv: str) -> list[int | None]:
    return middleware_values(tmp_path, "fleet_size", "--goodput", "20000", *argv)


def test_the_fleet_declares_its_number_of_drones_by_default(tmp_path: Path) -> None:
    """Measured on the demo fleet, the share keeps the start's full frames from overflowing
    the relay (docs/middleware.md, round 7), so it is the fleet's default."""
    assert _fleet_sizes(tmp_path / "a", "--drones", "3") == [3, 3, 3]
    assert _fleet_sizes(tmp_path / "b", "--drones", "10", "--fleet-share") == [10] * 10


def test_no_fleet_share_and_other_policies_write_no_fleet_size(tmp_path: Path) -> None:
    assert _fleet_sizes(tmp_path / "a", "--drones", "2", "--no-fleet-share") == [None, None]
    # the random and send-all baselines have no mission-start share: never written
    for policy in ("random", "send_all"):
        assert _fleet_sizes(tmp_path / policy, "--drones", "2", "--policy", policy) == [None,
                                                                                        None]
