"""Mission commands on a drone (docs/ground_station.md, "What a command does to a drone").

start/end/set_params/request_report end in ``done`` or ``error`` with the reason, whatever
the logging configuration; set_params is ``done`` only once the optimiser has applied it.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import re
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from companion_fake_vehicle import FakeVehicle
from test_companion_app import FakeDecider, _config, _make, _until

import companion.commands as commands_module
from companion.app import build_decider
from companion.config import parse_config
from companion.middleware import ParamsResult
from companion.protocol import Command, CommandReceived


def _send(transport: Any, command: Command) -> None:
    transport.on_event(CommandReceived(command=command, sender="gs", t_sent=time.time(),
                                       t_rcv=time.time(), addr=("127.0.0.1", 1)))


def _result(transport: Any, command_id: int) -> Any:
    finals = [s for s in transport.statuses
              if s.command_id == command_id and s.state in ("done", "error")]
    return finals[-1] if finals else None


@pytest.fixture
def debug_logging(caplog: pytest.LogCaptureFixture) -> pytest.LogCaptureFixture:
    """Every logger at DEBUG, as a user's ``--log-level debug`` (INFO is the default)."""
    caplog.set_level(logging.DEBUG)
    return caplog


async def test_commands_are_done_with_debug_logging_on(
        vehicle: FakeVehicle, tmp_path: Path, debug_logging: pytest.LogCaptureFixture) -> None:
    decider = FakeDecider()
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        transport = transports[0]
        _send(transport, Command(command_id=1, name="end", t_exec=time.time()))
        _send(transport, Command(command_id=2, name="start", t_exec=time.time() + 0.2))
        _send(transport, Command(command_id=3, name="set_params", t_exec=time.time(),
                                 args={"threshold": 0.5}))
        _send(transport, Command(command_id=4, name="request_report", t_exec=time.time()))
        await _until(lambda: all(_result(transport, i) for i in (1, 2, 3, 4)))
        assert [_result(transport, i).state for i in (1, 2, 3, 4)] == ["done"] * 4
        assert app.mission_state == "running"
        assert decider.threshold == 0.5
        counters = _result(transport, 4).info["counters"]
        assert counters["commands"] == 4
        assert any("command start #2" in r.getMessage() for r in debug_logging.records)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


async def test_a_failing_log_call_does_not_stop_a_command(
        vehicle: FakeVehicle, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: Any, **kwargs: Any) -> None:
        raise KeyError("Attempt to overwrite 'name' in LogRecord")

    monkeypatch.setattr(commands_module.log, "log", broken)  # every log line of the command path
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), FakeDecider())
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        _send(transports[0], Command(command_id=9, name="end", t_exec=time.time()))
        await _until(lambda: _result(transports[0], 9) is not None)
        assert _result(transports[0], 9).state == "done"
        assert app.mission_state == "ended"
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


class SlowParams(FakeDecider):
    """Applies parameters slowly, in the decision thread, like a busy optimiser."""

    def __init__(self) -> None:
        super().__init__()
        self.applied = threading.Event()

    def set_params(self, params: Mapping[str, Any], now: float) -> ParamsResult:
        time.sleep(0.3)
        result = super().set_params(params, now)
        self.applied.set()
        return result


async def test_set_params_is_done_only_after_it_was_applied(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = SlowParams()
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        _send(transports[0], Command(command_id=5, name="set_params", t_exec=time.time(),
                                     args={"threshold": 0.7}))
        await asyncio.sleep(0.1)
        assert _result(transports[0], 5) is None  # still being applied
        await _until(lambda: _result(transports[0], 5) is not None)
        assert decider.applied.is_set() and decider.threshold == 0.7
        # the ground station resends until it sees a result: a lost "done" comes again
        _send(transports[0], Command(command_id=5, name="set_params", t_exec=time.time(),
                                     args={"threshold": 0.7}))
        assert transports[0].statuses[-1].state == "done"
        assert decider.params == [{"threshold": 0.7}]  # executed once
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


def _real_decider(tmp_path: Path, constraint: str = "constant") -> Any:
    params = {"limit_bytes_per_s": 20_000.0} if constraint == "constant" else {}
    config = parse_config({"drone": {"id": "d1"},
                           "constraint": {"name": constraint, "params": params},
                           "budgets": {"mcts_iterations": 300}})
    return build_decider(config)


def test_set_params_reaches_the_optimiser_and_the_constraint(tmp_path: Path) -> None:
    decider = _real_decider(tmp_path)
    result = decider.set_params({"mcts_iterations": 40, "time_budget_s": 0.2, "alpha": 3,
                                 "constraint.limit_bytes_per_s": 5000}, 0.0)
    assert result.ok and dict(result.applied) == {
        "mcts_iterations": 40, "time_budget_s": 0.2, "alpha": 3.0,
        "constraint.limit_bytes_per_s": 5000.0}
    assert decider.config.max_iterations == 40
    assert decider.config.time_budget_s == 0.2
    assert decider.constraint.limit_bytes_per_s(now=0.0) == 5000.0
    image = decider.config.spec.types["image"].utility.params()
    assert image["alpha"] == 3.0


@pytest.mark.parametrize(("params", "reason"), [
    ({"mcts_iterations": 50, "warp_speed": 9}, "unknown parameter 'warp_speed'"),
    ({"mcts_iterations": 50, "time_budget_s": -1}, "time_budget_s must be a number > 0"),
    ({"mcts_iterations": 50, "constraint.limit_bytes_per_s": "fast"},
     "constraint.limit_bytes_per_s must be a number"),
    ({"mcts_iterations": 50, "constraint.window": 1}, "unknown parameter 'constraint.window'"),
    ({"mcts_iterations": 50, "alpha": -2}, "alpha must be a number >= 0"),
    ({"mcts_iterations": "abc"}, "mcts_iterations must be a number, got 'abc'"),
    ({"mcts_iterations": 2.5}, "mcts_iterations must be a whole number >= 1, got 2.5"),
    ({"mcts_iterations": 0}, "mcts_iterations must be a whole number >= 1, got 0"),
    ({"c": "wide"}, "c must be a number, got 'wide'"),
])
def test_a_rejected_key_changes_nothing_and_says_why(
        tmp_path: Path, params: dict[str, Any], reason: str) -> None:
    decider = _real_decider(tmp_path)
    before = decider.config
    result = decider.set_params(params, 0.0)
    assert not result.ok and re.search(reason, str(result.error)) and not result.applied
    assert decider.config == before
    assert decider.config.time_budget_s == 0.05
    assert decider.constraint.limit_bytes_per_s(now=0.0) == 20_000.0


async def test_a_rejected_set_params_is_an_error_with_the_reason(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = _real_decider(tmp_path, constraint="adaptive")
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        _send(transports[0], Command(command_id=6, name="set_params", t_exec=time.time(),
                                     args={"mcts_iterations": 10, "bogus": 1}))
        await _until(lambda: _result(transports[0], 6) is not None, 30)
        error = _result(transports[0], 6)
        assert error.state == "error" and "unknown parameter 'bogus'" in error.info["error"]
        assert decider.config.max_iterations == 300
        _send(transports[0], Command(command_id=7, name="set_params", t_exec=time.time(),
                                     args={"constraint.alpha_bytes_per_s": 1000}))
        await _until(lambda: _result(transports[0], 7) is not None, 30)
        assert _result(transports[0], 7).state == "done"
        assert decider.constraint.alpha_bytes_per_s == 1000.0
        # the constraint's own range checks apply: min above max is refused, nothing changes
        _send(transports[0], Command(command_id=8, name="set_params", t_exec=time.time(),
                                     args={"constraint.min_bytes_per_s": 1e9}))
        await _until(lambda: _result(transports[0], 8) is not None, 30)
        error = _result(transports[0], 8)
        assert error.state == "error" and "min_bytes_per_s" in error.info["error"]
        assert decider.constraint.min_bytes_per_s == 1250.0
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


class SlowDecisions(FakeDecider):
    """Every decision takes a while and says "send": an end arrives while one is running."""

    def __init__(self) -> None:
        super().__init__()
        self.threshold = 0.0
        self.deciding = threading.Event()

    def decide(self, message: Any, now: float) -> Any:
        if message.type == "image":
            self.deciding.set()
            time.sleep(0.15)
        return super().decide(message, now)


async def test_nothing_is_sent_after_end(vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = SlowDecisions()
    app, transports = _make(_config(vehicle, tmp_path, rate_hz=20.0), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: app.sent_by_type.get("image", 0) >= 2, 15)
        decider.deciding.clear()
        await asyncio.to_thread(decider.deciding.wait, 5)  # a decision is under way
        _send(transports[0], Command(command_id=11, name="end", t_exec=time.time()))
        await _until(lambda: _result(transports[0], 11) is not None)
        n_sent = len(transports[0].sent)
        t_end = time.time()
        await asyncio.sleep(0.6)
        late = [m for m, _ in transports[0].sent[n_sent:] if m.type != "status"]
        assert late == []
        assert not [m for m, _ in transports[0].sent
                    if m.type == "image" and m.t_sent is not None and m.t_sent > t_end]
        # nor is a frame scored or offered to the optimiser after the end
        assert not [m for m in decider.decided if m.type == "image" and m.t_gen > t_end]
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


async def test_after_end_status_keeps_the_link_visibly_alive(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    """Only status goes out after end; it comes every second (not every status_period_s =
    5 s), so the station's link-loss alarm (3 s) stays quiet."""
    config = _config(vehicle, tmp_path, enabled=False)
    config = dataclasses.replace(config, telemetry=dataclasses.replace(
        config.telemetry, status_period_s=5.0))
    app, transports = _make(config, FakeDecider())
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        _send(transports[0], Command(command_id=12, name="end", t_exec=time.time()))
        await _until(lambda: _result(transports[0], 12) is not None)
        t_end = time.time()
        await asyncio.sleep(3.3)
        after = [m for m, _ in transports[0].sent if m.t_gen > t_end]
        assert {m.type for m in after} == {"status"}
        gaps = np.diff([t_end] + [m.t_gen for m in after] + [time.time()])
        assert len(after) >= 3 and max(gaps) < 1.3, gaps
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
