"""The app with fake decider and transport: pipeline, decision log, commands, live params."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import io
import itertools
import json
import os
import subprocess
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from companion_fake_vehicle import FakeVehicle

from companion.app import CompanionApp
from companion.config import BudgetConfig, parse_config
from companion.middleware import ParamsResult, ReceiverReport
from companion.protocol import Command, CommandReceived, Status
from utility_specs.files import read_log
from utility_specs.message import Message


@dataclass(frozen=True)
class FakeDecision:
    send: bool
    version: int | None
    reason: str
    score: float = 0.0


class FakeDecider:
    """Sends images with red >= threshold in their half version, all telemetry."""

    def __init__(self, *, delay_s: float = 0.0) -> None:
        self.threshold = 0.2
        self.delay_s = delay_s
        self.decided: list[Message] = []
        self.reports: list[Any] = []
        self.params: list[Mapping[str, Any]] = []

    def decide(self, message: Message, now: float) -> FakeDecision:
        time.sleep(self.delay_s)
        self.decided.append(message)
        if message.type != "image":
            return FakeDecision(True, None, "telemetry", 1.0)
        if message.data["red"] >= self.threshold:
            return FakeDecision(True, 1, "red enough", 2.0)
        return FakeDecision(False, None, "not red", 0.0)

    def on_report(self, report: ReceiverReport, now: float) -> None:
        self.reports.append(report)

    def set_params(self, params: Mapping[str, Any], now: float) -> ParamsResult:
        self.params.append(dict(params))
        if "threshold" in params:
            self.threshold = float(params["threshold"])
        return ParamsResult(applied=dict(params))

    def get_timer(self) -> float | None:
        return None

    def handle_timer(self, now: float) -> None:
        pass


class FakeTransport:
    def __init__(self, on_event: Any) -> None:
        self.on_event = on_event
        self.sent: list[tuple[Message, bytes]] = []
        self.statuses: list[Status] = []
        self._stop = asyncio.Event()

    async def run(self) -> None:
        await self._stop.wait()

    def stop(self) -> None:
        self._stop.set()

    def send_message(self, message: Message, payload: bytes, now: float) -> int:
        self.sent.append((message, payload))
        return 1

    def send_status(self, status: Status, now: float) -> int:
        self.statuses.append(status)
        return 1


class RedThenPlain:
    """Frames alternate: a quarter red, plain grey."""

    description = "alternating"

    def __init__(self) -> None:
        self.i = 0

    def read(self, *, timeout_s: float) -> np.ndarray:
        self.i += 1
        image = np.full((120, 160, 3), 128, np.uint8)
        if self.i % 2:
            image[0:60, 0:80] = (0, 0, 255)
        return image

    def close(self) -> None:
        pass


def _config(vehicle: FakeVehicle, tmp_path: Path, **camera: Any) -> Any:
    return parse_config({
        "drone": {"id": "d1"},
        "mavlink": {"url": f"udpout:127.0.0.1:{vehicle.port}", "heartbeat_timeout_s": 2.0},
        "camera": {"source": "unused", "width": 160, "height": 120, "rate_hz": 20.0,
                   **camera},
        "scoring": {"red_share": {"scale": 1.0}},
        "mission": {"log": str(tmp_path / "mission.jsonl")},
        "telemetry": {"position_rate_hz": 5.0, "battery_period_s": 0.2,
                      "status_period_s": 0.5},
    })


def _make(config: Any, decider: FakeDecider, **kw: Any) -> tuple[CompanionApp, list[Any]]:
    transports: list[FakeTransport] = []

    def factory(on_event: Any) -> FakeTransport:
        transports.append(FakeTransport(on_event))
        return transports[-1]

    app = CompanionApp(config, decider=decider, transport_factory=factory, clock=time.time,
                       frame_source=RedThenPlain(), **kw)
    return app, transports


async def _until(predicate: Any, timeout_s: float = 5.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not predicate():
            await asyncio.sleep(0.02)


async def test_pipeline_sends_what_the_decider_chooses_and_logs_why(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = FakeDecider()
    app, transports = _make(_config(vehicle, tmp_path), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: {"image", "position", "battery", "status"} <= set(app.sent_by_type))
        await _until(lambda: app.counters["dropped"] >= 2)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    sent = transports[0].sent
    images = [(m, p) for m, p in sent if m.type == "image"]
    assert images and all(m.version == 1 and m.data["red"] == 0.25 for m, _ in images)
    assert all(m.size == m.versions[1].size == len(p) for m, p in images)
    assert all(m.t_sent is not None and m.t_sent >= m.t_gen for m, _ in sent)
    position = next(m for m, _ in sent if m.type == "position")
    assert position.data["lat_deg"] == pytest.approx(50.0615, abs=1e-3)
    battery = next(m for m, p in sent if m.type == "battery")
    assert battery.data["level"] == 0.87
    # telemetry rides in the metadata only; its size is that metadata's encoded size
    telemetry = [(m, p) for m, p in sent if m.type != "image"]
    assert telemetry and all(p == b"" for _, p in telemetry)
    assert all(
        m.size == len(json.dumps(dict(m.data), separators=(",", ":"), sort_keys=True).encode())
        for m, _ in telemetry
    )
    seqs = [m.seq for m in decider.decided]
    assert len(set(seqs)) == len(seqs)  # one sequence space per drone

    lines = [json.loads(x) for x in (tmp_path / "mission.jsonl").read_text().splitlines()]
    decisions = [r for r in lines if "decision" in r]
    assert {r["decision"]["reason"] for r in decisions} >= {"red enough", "not red", "telemetry"}
    dropped = [r for r in decisions if not r["decision"]["send"]]
    assert all(r["t_sent"] is None and r["t_rcv"] is None for r in dropped)
    log = read_log(tmp_path / "mission.jsonl")  # the model's reader accepts it
    assert len(log.messages) == len(decisions)


async def test_commands_run_at_their_instant_once(vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = FakeDecider()
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        transport = transports[0]
        t_exec = time.time() + 0.3
        end = Command(command_id=5, name="end", t_exec=t_exec)
        event = CommandReceived(command=end, sender="gs", t_sent=time.time(),
                                t_rcv=time.time(), addr=("127.0.0.1", 1))
        transport.on_event(event)
        transport.on_event(event)  # the ground station retries until acknowledged
        assert [s.state for s in transport.statuses] == ["ack", "ack"]
        assert app.mission_state == "running"
        await _until(lambda: app.mission_state == "ended")
        assert time.time() >= t_exec
        await _until(lambda: any(s.state == "done" for s in transport.statuses))
        assert app.counters["commands"] == 1

        params = Command(command_id=6, name="set_params", t_exec=0.0,
                         args={"threshold": 0.9, "time_budget_s": 0.2})
        transport.on_event(CommandReceived(command=params, sender="gs", t_sent=0.0, t_rcv=0.0,
                                           addr=("127.0.0.1", 1)))
        await _until(lambda: decider.params == [{"threshold": 0.9, "time_budget_s": 0.2}])
        assert app.config.budgets.time_budget_s == 0.2

        other = Command(command_id=7, name="end", t_exec=0.0, target="d2")
        transport.on_event(CommandReceived(command=other, sender="gs", t_sent=0.0, t_rcv=0.0,
                                           addr=("127.0.0.1", 1)))
        bad = Command(command_id=8, name="self_destruct", t_exec=0.0)
        transport.on_event(CommandReceived(command=bad, sender="gs", t_sent=0.0, t_rcv=0.0,
                                           addr=("127.0.0.1", 1)))
        await _until(lambda: any(s.state == "error" for s in transport.statuses))
        error = next(s for s in transport.statuses if s.state == "error")
        assert error.command_id == 8 and "unknown command" in error.info["error"]
        assert all(s.command_id != 7 for s in transport.statuses)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


async def test_waiting_for_start_sends_only_status_until_start(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    decider = FakeDecider()
    config = _config(vehicle, tmp_path)
    config = dataclasses.replace(config, mission=dataclasses.replace(config.mission,
                                                                     wait_for_start=True))
    app, transports = _make(config, decider)
    assert app.mission_state == "idle"
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: app.counters["not_running"] >= 3 and "status" in app.sent_by_type)
        assert {m.type for m, _ in transports[0].sent} == {"status"}
        assert transports[0].sent[-1][0].data["mission"] == "idle"
        start = Command(command_id=1, name="start", t_exec=time.time())
        transports[0].on_event(CommandReceived(command=start, sender="gs", t_sent=0.0,
                                               t_rcv=0.0, addr=("127.0.0.1", 1)))
        await _until(lambda: "image" in app.sent_by_type)
        await _until(lambda: any(m.type == "status" and m.data["mission"] == "running"
                                 for m, _ in transports[0].sent))
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


async def test_slow_decisions_are_bounded_and_counted(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    config = _config(vehicle, tmp_path, enabled=False)
    config = dataclasses.replace(config, budgets=BudgetConfig(time_budget_s=0.05))
    decider = FakeDecider(delay_s=0.5)
    app, _ = _make(config, decider)
    task = asyncio.create_task(app.run())
    log = tmp_path / "mission.jsonl"

    def reasons() -> set[str]:  # the log is flushed every second; a torn last line waits
        found = set()
        for line in log.read_text().splitlines() if log.exists() else []:
            with contextlib.suppress(ValueError):
                found.add(json.loads(line).get("decision", {}).get("reason"))
        return found

    try:
        # the first timeout may be a status's (a loaded run): wait for both kinds
        await _until(lambda: {"decision timeout", "status-heartbeat (decision timeout)"}
                     <= reasons(), 12)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    records = [json.loads(x) for x in log.read_text().splitlines()]
    assert app.counters["decide_timeouts"] >= 1
    assert any(r.get("decision", {}).get("reason") == "decision timeout" for r in records)
    # the status heartbeat still goes out when its decision times out (make demo, a host
    # stall of over 300 ms: three drones timed out on one decision at once, two on a status)
    status = [r for r in records if r.get("type") == "status"]
    assert status and all(r["t_sent"] is not None for r in status)
    assert any(r["decision"]["reason"] == "status-heartbeat (decision timeout)" for r in status)


async def test_reports_go_to_the_decider(vehicle: FakeVehicle, tmp_path: Path) -> None:
    from companion.protocol import Report, ReportReceived

    decider = FakeDecider()
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        event = ReportReceived(report=Report(), reporter="gs", report_number=1, part_index=0,
                               part_count=1, t_sent=time.time(), t_rcv=time.time(),
                               addr=("127.0.0.1", 1))
        transports[0].on_event(event)
        # the decider gets the report with the times of its own trip (for round trips)
        await _until(lambda: decider.reports == [ReceiverReport.from_event(event)])
        assert (decider.reports[0].t_sent, decider.reports[0].t_rcv) == (event.t_sent,
                                                                         event.t_rcv)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)


def test_mission_log_skips_records_json_cannot_carry(tmp_path: Path) -> None:
    from companion.mission_log import MissionLogWriter

    writer = MissionLogWriter(tmp_path / "m.jsonl")
    assert writer.write({"state": {"agent": "d1", "t": 1.0}}) is True
    assert writer.write({"state": {"agent": "d1", "t": float("nan")}}) is False
    writer.close()
    assert (tmp_path / "m.jsonl").read_text() == '{"state":{"agent":"d1","t":1.0}}\n'


class _FullDisk(io.StringIO):
    def write(self, text: str) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def flush(self) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self) -> None:  # a file's close flushes first
        super().close()
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_mission_log_write_errors_are_counted_not_raised(tmp_path: Path) -> None:
    from companion.mission_log import MissionLogWriter

    writer = MissionLogWriter(tmp_path / "m.jsonl")
    writer._stream.close()  # type: ignore[union-attr]
    writer._stream = _FullDisk()
    assert writer.write({"state": {"agent": "d1", "t": 1.0}}) is False
    writer.flush()
    writer.close()
    assert writer.errors == 3


@pytest.fixture
def full_disk(tmp_path: Path) -> Any:
    """A 256 kB tmpfs, filled up (root only; elsewhere the test skips and says why)."""
    mount_point = tmp_path / "full"
    mount_point.mkdir()
    if os.geteuid() != 0:
        pytest.skip("a real full disk needs a tmpfs mount: run the tests as root to enable")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount_point)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed ({done.stderr.strip()}): needs CAP_SYS_ADMIN")
    try:
        with contextlib.suppress(OSError), open(mount_point / "filler", "wb") as filler:
            while True:
                filler.write(b"\0" * 65536)
                filler.flush()
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


async def test_a_full_sd_card_does_not_stop_streaming(
        vehicle: FakeVehicle, tmp_path: Path, full_disk: Path) -> None:
    """The mission log's disk is full: the app keeps deciding and sending, counts the errors,
    and its log catches up once space is freed."""
    decider = FakeDecider()
    log_path = full_disk / "mission.jsonl"
    app, transports = _make(_config(vehicle, tmp_path), decider, mission_log=log_path)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: app.mission_log.errors > 0, timeout_s=10.0)
        sent = len(transports[0].sent)
        await _until(lambda: len(transports[0].sent) > sent + 5, timeout_s=10.0)
        assert not task.done()
        (full_disk / "filler").unlink()
        await asyncio.sleep(1.5)  # housekeeping flushes once a second
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    log = read_log(log_path)
    assert log.messages, "the log resumed once there was space"


async def test_status_carries_statustext_fix_and_constraint(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    from companion.middleware.constraint import ConstantConstraint
    from companion.telemetry import StatusTextSample

    decider = FakeDecider()
    decider.constraint = ConstantConstraint(limit_bytes_per_s=1234.0)  # type: ignore[attr-defined]
    app, transports = _make(_config(vehicle, tmp_path, enabled=False), decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: app.telemetry.snapshot().gps_fix_type is not None)
        app.telemetry.apply(StatusTextSample(t=time.time(), severity=2, text="PreArm: GPS"))
        await _until(lambda: any("statustext" in m.data for m, _ in transports[0].sent))
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    status = next(m for m, _ in transports[0].sent if "statustext" in m.data)
    assert (status.data["statustext"], status.data["severity"]) == ("PreArm: GPS", 2)
    assert status.data["xi_bytes_per_s"] == 1234.0 and status.data["fix_type"] == 3


class DropStatusesOf(FakeDecider):
    """Drops the first ``n`` statuses reporting ``mode`` (a full window), sends the rest."""

    def __init__(self, mode: str, n: int) -> None:
        super().__init__()
        self.mode, self.left = mode, n

    def decide(self, message: Message, now: float) -> FakeDecision:
        self.decided.append(message)
        if message.type == "status" and message.data["mode"] == self.mode and self.left > 0:
            self.left -= 1
            return FakeDecision(False, None, "window full", 0.0)
        return FakeDecision(True, None, "ok", 1.0)


def _status_config(vehicle: FakeVehicle, tmp_path: Path, *, period_s: float) -> Any:
    """The camera off and a periodic status every ``period_s``: what a status test watches."""
    config = _config(vehicle, tmp_path, enabled=False)
    return dataclasses.replace(
        config, telemetry=dataclasses.replace(config.telemetry, status_period_s=period_s))


async def test_a_new_state_carries_since_and_is_offered_again_until_sent(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    """Issue 17: a dropped status of a new state is retried every 0.5 s, not only each
    period (5 s here), and every status of one state carries the same ``since``."""
    decider = DropStatusesOf("GUIDED", 2)
    config = _status_config(vehicle, tmp_path, period_s=5.0)
    app, transports = _make(config, decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: any(m.type == "status" for m, _ in transports[0].sent))
        await _until(lambda: app.telemetry.snapshot().gps_fix_type == 3)  # not a new state later
        first = next(m for m, _ in transports[0].sent if m.type == "status")
        # the vehicle switches to GUIDED, arms and enters a failsafe (MAV_STATE_CRITICAL)
        vehicle.custom_mode, vehicle.armed, vehicle.system_status = 4, True, 5
        vehicle.send(vehicle.heartbeat())
        await _until(lambda: app.telemetry.snapshot().mode == "GUIDED")
        t_change = time.time()
        await _until(lambda: any(m.type == "status" and m.data["mode"] == "GUIDED"
                                 for m, _ in transports[0].sent), timeout_s=4.0)
        t_told = time.time()
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    guided = [m for m in decider.decided if m.type == "status" and m.data["mode"] == "GUIDED"]
    assert len(guided) == 3  # dropped twice, sent the third time
    assert 0.7 < t_told - t_change < 2.5  # two 0.5 s retries, not the 5 s period
    assert len({m.data["since"] for m in guided}) == 1
    since = guided[0].data["since"]
    assert first.data["since"] < since <= guided[0].t_gen
    assert all(m.data["failsafe"] is True and m.data["armed"] is True for m in guided)
    assert first.data["failsafe"] is False


async def test_retries_of_an_untold_state_back_off_when_the_link_stays_full(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    """Four retries 0.5 s apart, then 1 s, 2 s...: a dead link costs few decisions."""
    decider = DropStatusesOf("GUIDED", 1000)
    config = _status_config(vehicle, tmp_path, period_s=30.0)
    app, transports = _make(config, decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: any(m.type == "status" for m, _ in transports[0].sent))
        # the fix first: heard after the mode change (a loaded run), it is a new state of
        # its own and goes at once, which reads here as a retry 1 ms after the first
        await _until(lambda: app.telemetry.snapshot().gps_fix_type == 3)
        vehicle.custom_mode = 4
        vehicle.send(vehicle.heartbeat())
        await _until(lambda: any(m.type == "status" and m.data["mode"] == "GUIDED"
                                 for m in decider.decided))
        await asyncio.sleep(5.5)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    times = [m.t_gen for m in decider.decided if m.type == "status"
             and m.data["mode"] == "GUIDED"]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert len(gaps) >= 5, gaps
    assert gaps[:5] == pytest.approx([0.5, 0.5, 0.5, 0.5, 1.0], abs=0.15), gaps
    assert all(g > 1.8 for g in gaps[5:]), gaps  # 2 s, then 4 s


async def test_a_new_fix_is_told_at_once_not_at_the_next_period(
        vehicle: FakeVehicle, tmp_path: Path) -> None:
    """Whether the autopilot has a 3-D fix is part of the state: after a (re)connection the
    status went out with the fix unknown or none, and the dashboard showed "no fix" beside
    fresh positions until the next periodic status (30 s here; 5 s by default)."""
    vehicle.fix_after_s = 2.0  # ArduPilot after boot: the fix comes a little later
    decider = FakeDecider()
    config = _status_config(vehicle, tmp_path, period_s=30.0)
    app, transports = _make(config, decider)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: any(m.type == "status" for m, _ in transports[0].sent))
        assert next(m for m, _ in transports[0].sent if m.type == "status"
                    ).data["fix_type"] != 3
        await _until(lambda: app.telemetry.snapshot().gps_fix_type == 3, timeout_s=10.0)
        t_fix = time.time()
        await _until(lambda: any(m.type == "status" and m.data["fix_type"] == 3
                                 for m, _ in transports[0].sent), timeout_s=4.0)
        t_told = time.time()
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    assert t_told - t_fix < 1.5


class StallRecorder(FakeDecider):
    def __init__(self) -> None:
        super().__init__()
        self.stalls: list[tuple[float, float, float]] = []

    def on_stall(self, t_from: float, t_to: float, now: float) -> None:
        self.stalls.append((t_from, t_to, now))


@pytest.mark.parametrize("where", ["a task", "the mission log's flush"])
async def test_a_blocked_loop_is_told_to_the_decider_as_a_stall(
        vehicle: FakeVehicle, tmp_path: Path, caplog: pytest.LogCaptureFixture,
        where: str) -> None:
    """The process does not run for 2.5 s (here: the loop blocked, by a task or by a write
    to a slow SD card; SIGSTOP in the product test): the decider hears of the interval, so
    the adaptive constraint does not read what it delayed as the link's queue
    (tests/adaptive/test_adaptive_stall.py)."""
    decider = StallRecorder()
    app, _ = _make(_status_config(vehicle, tmp_path, period_s=5.0), decider)
    task = asyncio.create_task(app.run())
    blocked: list[float] = []
    try:
        await _until(lambda: app.telemetry.snapshot().connected)
        await asyncio.sleep(1.2)
        if where == "a task":
            t_block = time.time()
            time.sleep(2.5)  # blocks the loop: what a stop does to every task
            t_resume = time.time()
        else:
            flush = app.mission_log.flush

            def slow_flush() -> None:
                if not blocked:
                    blocked.append(time.time())
                    time.sleep(2.5)
                    blocked.append(time.time())
                flush()

            app.mission_log.flush = slow_flush  # type: ignore[method-assign]
            await _until(lambda: len(blocked) == 2, timeout_s=5.0)
            t_block, t_resume = blocked
        await _until(lambda: decider.stalls, timeout_s=3.0)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    ((t_from, t_to, _),) = decider.stalls
    # from the housekeeping's last tick before it (no pacer here to hold older sends)
    assert t_block - 1.1 <= t_from <= t_block and t_resume <= t_to <= t_resume + 0.5
    assert app.counters["stalls"] == 1
    assert any("the process did not run for" in r.getMessage() for r in caplog.records)
