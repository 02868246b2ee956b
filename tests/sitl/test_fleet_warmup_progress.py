"""The launcher's wait for warm optimisers (:mod:`sitl.fleet.warmup`), without processes: a
scripted ``/api/fleet`` and a fake clock. The product test is
``tests/integration/test_fleet_warmup.py``."""

from __future__ import annotations

import io
from collections.abc import Iterator, Mapping
from typing import Any

import pytest

from sitl.fleet.processes import FleetError, Stop
from sitl.fleet.warmup import wait_for_warm_up, warm_drones


def _fleet(**ready: bool | None) -> dict[str, Any]:
    return {"drones": [{"drone": d, "optimiser_ready": r} for d, r in ready.items()]}


class Script:
    """``/api/fleet`` answers in turn (the last one repeats); poll k happens at k s."""

    def __init__(self, *answers: Mapping[str, Any] | None) -> None:
        self.answers: Iterator[Mapping[str, Any] | None] = iter(answers)
        self.last: Mapping[str, Any] | None = None
        self.t = 0.0
        self.polls = 0

    def __call__(self) -> Mapping[str, Any] | None:
        self.t = float(self.polls)
        self.polls += 1
        self.last = next(self.answers, self.last)
        return self.last

    def clock(self) -> float:
        return self.t


def test_only_a_true_optimiser_ready_counts() -> None:
    assert warm_drones(_fleet(d1=True, d2=False, d3=None)) == {"d1"}
    assert warm_drones({"drones": [{"drone": "d1", "optimiser_ready": "yes"}, "junk"]}) == set()
    assert warm_drones(None) == set() and warm_drones({}) == set()


def test_waits_until_every_drone_is_warm_and_shows_progress() -> None:
    api = Script(None, _fleet(d1=False, d2=False), _fleet(d1=True, d2=False),
                 _fleet(d1=True, d2=False), _fleet(d1=True, d2=True, d9=False))
    out = io.StringIO()
    cold = wait_for_warm_up(api, ["d1", "d2"], stop=Stop(), timeout_s=60.0, out=out,
                            poll_s=0.0, clock=api.clock)
    assert cold == [] and api.polls == 5
    assert out.getvalue().splitlines() == [
        "waiting for 2 companions to warm up (optimiser compiling) 0/2... 0 s",
        "waiting for 2 companions to warm up (optimiser compiling) 1/2... 2 s",
        "companions warm: 2/2 after 4.0 s",
    ]


def test_warm_at_the_first_look_says_so_once() -> None:
    api = Script(_fleet(d1=True))
    out = io.StringIO()
    assert wait_for_warm_up(api, ["d1"], stop=Stop(), timeout_s=60.0, out=out, poll_s=0.0,
                            clock=api.clock) == []
    assert out.getvalue() == "companions warm: 1/1 (optimiser ready)\n"


def test_a_timeout_returns_the_cold_drones_and_repeats_progress_every_10_s() -> None:
    api = Script(_fleet(d1=True, d2=False, d3=None))
    out = io.StringIO()
    cold = wait_for_warm_up(api, ["d1", "d2", "d3"], stop=Stop(), timeout_s=25.0, out=out,
                            poll_s=0.0, clock=api.clock)
    assert cold == ["d2", "d3"]
    assert [line.rsplit("... ", 1)[1] for line in out.getvalue().splitlines()] == [
        "0 s", "10 s", "20 s"]


def test_a_stop_request_ends_the_wait() -> None:
    stop = Stop()
    stop.reason = "SIGINT"
    api = Script(_fleet(d1=False))
    with pytest.raises(FleetError, match=r"stopped \(SIGINT\) while waiting for the "
                                         r"companions to warm up"):
        wait_for_warm_up(api, ["d1"], stop=stop, timeout_s=60.0, out=io.StringIO(),
                         poll_s=0.0, clock=api.clock)
