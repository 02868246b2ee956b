"""The companion application: services in one TaskGroup around the information distribution layer.

Data flow (ARCHITECTURE.md, "Data flow on a drone")::

    MavlinkService -> TelemetryState --+--> TelemetryPublisher (position 1 Hz, battery, status)
    CameraService  -> score + encode --+--> CompanionApp.submit(message, payloads)
                                                |  decider.decide(message, now) in the
                                                |  decision executor, within the time budget
                                                v
                                       transport.send_message  -> ground station
    transport events: ReportReceived -> decider.on_report; CommandReceived -> scheduled at t_exec

Every service has ``async run()`` with its cleanup in ``finally`` and ``stop()``; all run in
exactly one ``asyncio.TaskGroup`` (:meth:`CompanionApp.run`). Blocking work (scoring, JPEG,
MCTS) runs in executors the app owns; the optimiser is only ever called from its one-thread
executor, so it needs no locks. Every decision and its reason goes to the mission log
(JSON Lines, ``utility_specs.log`` records plus ``decision``).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import secrets
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import IO, Any, Protocol

from companion.camera import CameraService, Frame, FrameSource, open_source
from companion.config import CompanionConfig, missing_keys
from companion.imaging import DEFAULT_SCALES, EncodedImage, image_message
from companion.linkhealth import LinkHealth
from companion.mavlink import MavlinkService, MavlinkSettings
from companion.protocol import (
    CommandReceived,
    Decoder,
    Encoder,
    LocalProtocolError,
    ReportReceived,
    Status,
)
from companion.scoring import Scorer, make_scorer
from companion.telemetry import (
    LinkStateSample,
    Sample,
    StatusTextSample,
    TelemetrySnapshot,
    TelemetryState,
)
from utility_specs.log import message_to_record, write_record
from utility_specs.message import Message, Version

__all__ = [
    "CompanionApp",
    "Decider",
    "DecisionLike",
    "Transport",
    "TransportFactory",
]

log = logging.getLogger(__name__)

Clock = Callable[[], float]

IDLE_STATUS_PERIOD_S = 1.0
"""Status period outside the mission window, when status is all a drone sends: often enough
that the ground station (``link_lost_s`` 3 s) does not take an ended mission for a lost link."""


class DecisionLike(Protocol):
    """What the app reads from a decision (``companion.middleware`` ``Decision``)."""

    @property
    def send(self) -> bool: ...

    @property
    def version(self) -> int | None: ...

    @property
    def reason(self) -> str: ...


class Decider(Protocol):
    """The information distribution layer as the app uses it (sans-I/O, ``now`` given)."""

    def decide(self, message: Message, now: float) -> DecisionLike: ...

    def on_report(self, event: Any, now: float) -> None: ...

    def set_params(self, params: Mapping[str, Any], now: float) -> None: ...

    def get_timer(self) -> float | None: ...

    def handle_timer(self, now: float) -> None: ...


class Transport(Protocol):
    """The UDP link to the ground station (``companion.transport``)."""

    async def run(self) -> None: ...

    def stop(self) -> None: ...

    def send_message(self, message: Message, payload: bytes, now: float) -> int: ...

    def send_status(self, status: Any, now: float) -> int: ...


TransportFactory = Callable[[Callable[[Any], None]], Transport]
"""Builds the transport given the callback that receives its decoder events."""


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class Submission:
    message: Message
    payloads: tuple[bytes, ...]


class MissionLogWriter:
    """Appends JSON Lines records; flushed by the app's housekeeping and at close.

    A full SD card must not stop the drone from streaming: write errors (OSError) are counted
    in ``errors`` and logged now and then, never raised. The file buffer keeps what it could
    not write and tries again at the next flush.
    """

    def __init__(self, path: str | Path | None) -> None:
        self._stream: IO[str] | None = None
        self.errors = 0
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._stream = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed in close()

    def write(self, record: Mapping[str, Any]) -> bool:
        """Append one record; False if it cannot be JSON (NaN, odd types) or written."""
        if self._stream is None:
            return True
        try:  # write_record serialises the whole line before writing any of it
            write_record(self._stream, record)
        except (ValueError, TypeError) as exc:
            log.warning("mission log: record skipped: %s", exc)
            return False
        except OSError as exc:
            self._failed(exc)
            return False
        return True

    def flush(self) -> None:
        if self._stream is not None:
            try:
                self._stream.flush()
            except OSError as exc:
                self._failed(exc)

    def close(self) -> None:
        if self._stream is not None:
            stream, self._stream = self._stream, None
            try:
                stream.close()
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        self.errors += 1
        if self.errors == 1 or self.errors % 100 == 0:
            log.error("mission log: write failed (%s), %d times so far; streaming goes on",
                      exc, self.errors)


FAILSAFE_STATES = (5, 6)
"""MAV_STATE_CRITICAL and MAV_STATE_EMERGENCY: the autopilot is in a failsafe."""


class TelemetryPublisher:
    """Turns the telemetry state into ``position``, ``battery`` and ``status`` messages.

    Position at ``position_rate_hz`` (1 Hz: eq. 4.11's position utility), battery every
    ``battery_period_s`` (data ``level`` in 0..1 for eq. 4.9), mission status every
    ``status_period_s`` and at once when mode, armed state, failsafe, link or mission state
    change. Each status carries ``since``, when its state began (the ``status_change``
    utility: a new state is worth sending at once); while no status of the current state
    has gone out (the constraint's window was full), it is offered again every
    ``STATE_RETRY_S``, not only every period; after ``STATE_RETRIES`` such retries the
    interval doubles up to the period (a dead link does not cost two decisions a second).
    """

    STATE_RETRY_S = 0.5
    STATE_RETRIES = 4

    def __init__(self, app: CompanionApp) -> None:
        self._app = app
        self._stopping = asyncio.Event()
        self._status_key: tuple[Any, ...] | None = None
        self._wake = asyncio.Event()
        self._statustexts: list[StatusTextSample] = []
        self._since: float | None = None
        """When the current status key began (fleet clock)."""
        self._announced: float | None = None
        """``since`` of the newest state a sent status reported."""
        self._last_position: float | None = None
        self._retries = 0

    def on_sample(self, sample: Sample) -> None:
        if isinstance(sample, StatusTextSample):  # autopilot messages ride on the status
            self._statustexts.append(sample)
            self._wake.set()
            return
        snap = self._app.telemetry.snapshot()
        if self._status_key is not None and self._status_key != self._key(snap):
            self._wake.set()

    def _key(self, snap: TelemetrySnapshot) -> tuple[Any, ...]:
        failsafe = snap.system_status in FAILSAFE_STATES
        return (snap.mode, snap.armed, failsafe, snap.connected, self._app.mission_state)

    async def run(self) -> None:
        cfg = self._app.config.telemetry
        loop = asyncio.get_running_loop()
        period_pos = 1.0 / cfg.position_rate_hz if cfg.position_rate_hz > 0 else math.inf
        t_pos = t_bat = t_status = loop.time()
        try:
            while not self._stopping.is_set():
                now_mono = loop.time()
                snap = self._app.telemetry.snapshot()
                if now_mono >= t_pos:
                    t_pos = now_mono + period_pos
                    if snap.position_problem is None and snap.t_position != self._last_position:
                        self._last_position = snap.t_position  # never the same fix twice
                        await self._app.submit_telemetry("position", self._position(snap))
                if now_mono >= t_bat:
                    t_bat = now_mono + cfg.battery_period_s
                    if snap.battery_remaining is not None and snap.battery_remaining > 0:
                        await self._app.submit_telemetry("battery", self._battery(snap))
                if now_mono >= t_status or self._wake.is_set():
                    self._wake.clear()
                    t_status = now_mono + (cfg.status_period_s
                                           if self._app.mission_state == "running"
                                           else min(cfg.status_period_s, IDLE_STATUS_PERIOD_S))
                    key = self._key(snap)
                    if key != self._status_key or self._since is None:
                        self._since = self._app.clock()
                        self._retries = 0
                    self._status_key = key
                    if await self._app.submit_telemetry("status", self._status(snap)):
                        self._announced = self._since
                    elif self._announced != self._since:  # a new state not told yet
                        backoff = 2.0 ** max(0, self._retries - self.STATE_RETRIES + 1)
                        self._retries += 1
                        t_status = min(t_status, now_mono + self.STATE_RETRY_S * backoff)
                wait = max(0.0, min(t_pos, t_bat, t_status) - loop.time())
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(wait):
                        await self._either(self._stopping, self._wake)
        finally:
            self._stopping.set()

    @staticmethod
    async def _either(a: asyncio.Event, b: asyncio.Event) -> None:
        waits = [asyncio.ensure_future(a.wait()), asyncio.ensure_future(b.wait())]
        try:
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()

    def stop(self) -> None:
        self._stopping.set()

    def _position(self, snap: TelemetrySnapshot) -> dict[str, Any]:
        return snap.geotag(at=self._app.clock())

    @staticmethod
    def _battery(snap: TelemetrySnapshot) -> dict[str, Any]:
        data: dict[str, Any] = {"level": snap.battery_remaining}
        if snap.battery_v is not None and math.isfinite(snap.battery_v):
            data["battery_v"] = snap.battery_v
        return data

    def _status(self, snap: TelemetrySnapshot) -> dict[str, Any]:
        """Mission status; field names are the ones the ground station's fleet view reads."""
        data: dict[str, Any] = {"mode": snap.mode, "armed": snap.armed,
                                "connected": snap.connected, "since": self._since,
                                "failsafe": snap.system_status in FAILSAFE_STATES,
                                "mission": self._app.mission_state, "autopilot": snap.autopilot}
        if snap.gps_fix_type is not None:
            data["fix_type"] = snap.gps_fix_type
        xi = self._app.constraint_limit()
        if xi is not None:
            data["xi_bytes_per_s"] = xi
        link = getattr(self._app.decider, "link_health", None)  # Δ and loss for the station
        if link is not None:
            data |= {k: v for k, v in link(self._app.clock()).items() if v is not None}
        fallback = self._app.fallback_share()
        if fallback is not None:
            data["fallback_share"] = fallback
        if self._statustexts:
            worst = min(self._statustexts, key=lambda s: s.severity)
            data["statustext"] = " | ".join(s.text for s in self._statustexts)[:200]
            data["severity"] = worst.severity
            self._statustexts.clear()
        return data


class CompanionApp:
    """One drone's companion: wiring, the decision pipeline and mission commands.

    Everything with I/O is injected so tests can swap it: ``decider`` (the middleware),
    ``transport_factory``, ``frame_source`` (default: from the camera config) and
    ``mavlink_connect`` (default: pymavlink).
    """

    def __init__(
        self,
        config: CompanionConfig,
        *,
        decider: Decider,
        transport_factory: TransportFactory,
        clock: Clock,
        frame_source: FrameSource | None = None,
        scorer: Scorer | None = None,
        mavlink_connect: Callable[[MavlinkSettings], Any] | None = None,
        mission_log: str | Path | None = None,
    ) -> None:
        self.config = config
        self.clock = clock
        self.decider = decider
        self.telemetry = TelemetryState()
        self.mission_state = "idle" if config.mission.wait_for_start else "running"
        self.counters: dict[str, int] = {
            "generated": 0, "sent": 0, "dropped": 0, "decide_timeouts": 0, "decide_errors": 0,
            "send_errors": 0, "reports": 0, "commands": 0, "frames_skipped": 0,
            "frame_errors": 0, "not_running": 0, "decided": 0, "fallback": 0,
        }
        self.sent_by_type: dict[str, int] = {}
        self._seq = 0
        self._decide_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decide")
        self._frame_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame")
        self._frame_busy = False
        self._log = MissionLogWriter(mission_log if mission_log is not None
                                     else config.mission.log)
        self._scorer = scorer or make_scorer(config.scoring.scorers,
                                             red=config.scoring.red_share,
                                             aruco=config.scoring.aruco,
                                             hog=config.scoring.hog_people)
        self._command_results: dict[int, Status | None] = {}
        """Command id -> its final status (None while it waits for ``t_exec``)."""
        self._command_tasks: set[asyncio.Task[None]] = set()
        self._timers: list[asyncio.TimerHandle] = []
        self._decider_timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping = asyncio.Event()
        self.transport = transport_factory(self._on_transport_event)
        self.mavlink = MavlinkService(config.mavlink, self.telemetry, clock=clock,
                                      connect=mavlink_connect)
        self.publisher = TelemetryPublisher(self)
        self.telemetry.add_listener(self.publisher.on_sample)
        self.telemetry.add_listener(self._on_link_state)
        self.camera: CameraService | None = None
        if config.camera.enabled:
            cam = config.camera
            source = frame_source or open_source(
                cam.source, width=cam.width, height=cam.height, rate_hz=cam.rate_hz,
                pose=self.telemetry.snapshot, options=dict(cam.options))
            self.camera = CameraService(source, self._on_frame, clock=clock,
                                        rate_hz=cam.rate_hz, width=cam.width,
                                        height=cam.height, pose=self.telemetry.snapshot)

    # -- life cycle -----------------------------------------------------------------------

    async def run(self) -> None:
        """Run every service until :meth:`stop` (or one of them fails)."""
        self._loop = asyncio.get_running_loop()
        log.info("companion %s starting", self.config.drone_id,
                 extra={"event": "start", "drone": self.config.drone_id})
        self._log.write({"mission": {"t_start": self.clock()}})
        try:
            async with asyncio.TaskGroup() as group:
                group.create_task(self.transport.run(), name="transport")
                wait_started = getattr(self.transport, "wait_started", None)
                if wait_started is not None:  # bind before anything tries to send
                    async with asyncio.timeout(10.0):
                        await wait_started()
                group.create_task(self.mavlink.run(), name="mavlink")
                await self._warm_up()  # before anything asks the optimiser
                group.create_task(self.publisher.run(), name="telemetry-publisher")
                if self.camera is not None:
                    group.create_task(self.camera.run(), name="camera")
                group.create_task(self._housekeeping(), name="housekeeping")
                await self._stopping.wait()
                self._stop_services()
        finally:
            for handle in self._timers:
                handle.cancel()
            if self._decider_timer is not None:
                self._decider_timer.cancel()
            self._decide_pool.shutdown(wait=False, cancel_futures=True)
            self._frame_pool.shutdown(wait=False, cancel_futures=True)
            self._log.write({"mission": {"t_end": self.clock()}})
            self._log.close()
            log.info("companion %s stopped", self.config.drone_id,
                     extra={"event": "stop", "counters": dict(self.counters)})

    async def _warm_up(self) -> None:
        """Run the decider's optional ``warm_up`` in its executor; a stop request wins."""
        warm_up = getattr(self.decider, "warm_up", None)
        if warm_up is None:
            return
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        work = loop.run_in_executor(self._decide_pool, warm_up)
        stopping = asyncio.ensure_future(self._stopping.wait())
        try:
            await asyncio.wait([work, stopping], timeout=120.0,
                               return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopping.cancel()
        if not work.done():
            log.warning("optimiser warm-up unfinished after %.1f s", loop.time() - t0)
            return
        exc = work.exception()
        if exc is not None:  # logged, not fatal: the real decisions will show the problem
            log.warning("optimiser warm-up failed: %r", exc)
        else:
            log.info("optimiser warmed up in %.2f s", loop.time() - t0,
                     extra={"event": "warm_up"})

    def _stop_services(self) -> None:
        self.transport.stop()
        self.mavlink.stop()
        self.publisher.stop()
        if self.camera is not None:
            self.camera.stop()

    def stop(self) -> None:
        """Ask every service to finish (safe to call from a signal handler)."""
        self._stopping.set()

    async def _housekeeping(self) -> None:
        try:
            while not self._stopping.is_set():
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(1.0):
                        await self._stopping.wait()
                self._log.flush()
        finally:
            self._log.flush()

    def constraint_limit(self) -> float | None:
        """ξ now (bytes/s) when the decider exposes its constraint, for status messages."""
        constraint = getattr(self.decider, "constraint", None)
        if constraint is None:
            return None
        value = float(constraint.limit_bytes_per_s(now=self.clock()))
        return value if math.isfinite(value) else None

    def fallback_share(self) -> float | None:
        """Share of decisions the optimiser did not make itself (greedy fallback or timeout);
        None before the first decision."""
        c = self.counters
        asked = c["decided"] + c["decide_timeouts"]
        return (c["fallback"] + c["decide_timeouts"]) / asked if asked else None

    def _on_link_state(self, sample: Sample) -> None:
        """Autopilot link changes go to the mission log as state records."""
        if isinstance(sample, LinkStateSample):
            self._log.write({"state": {"agent": self.config.drone_id, "t": sample.t,
                                       "autopilot_link": "up" if sample.connected else "lost",
                                       "reason": sample.reason}})

    # -- the decision pipeline --------------------------------------------------------------

    def next_seq(self) -> int:
        seq = self._seq
        self._seq += 1
        return seq

    async def submit_telemetry(self, type_name: str, data: Mapping[str, Any]) -> bool:
        """Telemetry travels in the first fragment's metadata alone: no payload to carry.

        Its size for the constraint and the model is that metadata's encoded size.
        """
        now = self.clock()
        message = Message(sender=self.config.drone_id, seq=self.next_seq(), type=type_name,
                          t_gen=now, size=len(_json_payload(data)), data=dict(data))
        return await self.submit(message, (b"",))

    async def submit(self, message: Message, payloads: Sequence[bytes]) -> bool:
        """Ask the decider about ``message``; send the chosen version. True if sent."""
        self.counters["generated"] += 1
        if self.mission_state != "running" and message.type != "status":
            self.counters["not_running"] += 1
            return False
        loop = asyncio.get_running_loop()
        now = self.clock()
        budget = self.config.budgets.time_budget_s
        try:
            async with asyncio.timeout(budget + max(0.25, budget)):  # + queueing slack
                decision = await loop.run_in_executor(self._decide_pool, self.decider.decide,
                                                      message, now)
        except TimeoutError:
            self.counters["decide_timeouts"] += 1
            self._record(message, sent=False, decision={"send": False,
                                                       "reason": "decision timeout"})
            return False
        self._arm_decider_timer()
        self.counters["decided"] += 1
        if decision.reason.startswith("fallback"):
            self.counters["fallback"] += 1
        info = _decision_record(decision)
        if self.mission_state != "running" and message.type != "status":
            # ended (or not started) while the optimiser decided: nothing goes out after end
            self.counters["not_running"] += 1
            self._record(message, sent=False, decision={**info, "send": False,
                                                       "reason": f"mission {self.mission_state}"})
            return False
        if not decision.send:
            self.counters["dropped"] += 1
            self._record(message, sent=False, decision=info)
            return False
        chosen = message
        version = decision.version
        if message.versions and version is not None:
            chosen = message.with_version(version)
        t_sent = self.clock()
        chosen = dataclasses.replace(chosen, t_sent=t_sent)
        payload = payloads[version if version is not None and version < len(payloads) else 0]
        try:
            self.transport.send_message(chosen, payload, t_sent)
        except (OSError, ValueError) as exc:
            self.counters["send_errors"] += 1
            log.warning("send %s/%d failed: %s", chosen.type, chosen.seq, exc)
            self._record(chosen, sent=False, decision={**info, "error": str(exc)})
            return False
        self.counters["sent"] += 1
        self.sent_by_type[chosen.type] = self.sent_by_type.get(chosen.type, 0) + 1
        self._record(chosen, sent=True, decision=info)
        return True

    def _record(self, message: Message, *, sent: bool, decision: Mapping[str, Any]) -> None:
        if not sent:
            message = dataclasses.replace(message, t_sent=None)
        self._log.write(message_to_record(message, decision=dict(decision)))

    # -- frames -----------------------------------------------------------------------------

    async def _on_frame(self, frame: Frame) -> None:
        """Score and encode off the loop, then submit; a busy pipeline skips the frame, and
        outside the mission window (before start, after end) no frame is scored at all."""
        if self.mission_state != "running":
            self.counters["not_running"] += 1
            return
        if self._frame_busy:
            self.counters["frames_skipped"] += 1
            return
        self._frame_busy = True
        try:
            loop = asyncio.get_running_loop()
            seq = self.next_seq()
            encoded = await loop.run_in_executor(self._frame_pool, self._encode, frame, seq)
        except (ValueError, RuntimeError) as exc:
            self.counters["frame_errors"] += 1
            log.warning("frame %d: %s", frame.index, exc)
            return
        finally:
            self._frame_busy = False
        await self.submit(encoded.message, encoded.payloads)

    def _encode(self, frame: Frame, seq: int) -> EncodedImage:
        features = self._scorer.score(frame.image)
        geotag = (frame.telemetry.geotag(at=frame.t_capture) if frame.telemetry is not None
                  else {"position": "none"})
        return image_message(frame.image, sender=self.config.drone_id, seq=seq,
                             t_gen=frame.t_capture, features=features, geotag=geotag,
                             jpeg_quality=self.config.camera.jpeg_quality,
                             scales=[(n, s) for n, s in DEFAULT_SCALES
                                     if n in self.config.camera.versions])

    # -- transport events, reports and commands ----------------------------------------------

    def _on_transport_event(self, event: Any) -> None:
        if isinstance(event, ReportReceived):
            self.counters["reports"] += 1
            loop = asyncio.get_running_loop()
            now = self.clock()
            future = loop.run_in_executor(self._decide_pool, self.decider.on_report, event, now)
            future.add_done_callback(self._after_decider_call)
        elif isinstance(event, CommandReceived):
            self._schedule_command(event.command)

    def _after_decider_call(self, future: asyncio.Future[Any]) -> None:
        if future.cancelled():
            return
        exc = future.exception()
        if exc is not None:
            self.counters["decide_errors"] += 1
            log.error("middleware call failed: %r", exc, exc_info=exc)
        self._arm_decider_timer()

    def _arm_decider_timer(self) -> None:
        """One ``call_later`` for the decider's next deadline (aioquic's transmit())."""
        loop = self._loop
        if loop is None or self._stopping.is_set():
            return
        if self._decider_timer is not None:
            self._decider_timer.cancel()
            self._decider_timer = None
        deadline = self.decider.get_timer()
        if deadline is None:
            return
        self._decider_timer = loop.call_later(max(0.0, deadline - self.clock()),
                                              self._fire_decider_timer)

    def _fire_decider_timer(self) -> None:
        self._decider_timer = None
        if self._loop is None or self._stopping.is_set():
            return
        future = self._loop.run_in_executor(self._decide_pool, self.decider.handle_timer,
                                            self.clock())
        future.add_done_callback(self._after_decider_call)

    def _schedule_command(self, command: Any) -> None:
        """Acknowledge at once, execute at ``t_exec`` (fleet clock); duplicates are ignored.

        A repeated command gets its final result again (``done``/``error``) once it has
        one, else another ack: the ground station resends until it sees a result, so a lost
        ``done`` datagram is recovered. The log line comes last and cannot stop the command.
        """
        if command.target is not None and command.target != self.config.drone_id:
            return
        if command.command_id in self._command_results:
            result = self._command_results[command.command_id]
            self.transport.send_status(
                result or Status(state="ack", command_id=command.command_id), self.clock())
            return
        self._command_results[command.command_id] = None
        self.counters["commands"] += 1
        self.transport.send_status(Status(state="ack", command_id=command.command_id),
                                   self.clock())
        loop = asyncio.get_running_loop()
        delay = max(0.0, command.t_exec - self.clock())
        handle = loop.call_later(delay, self._execute_command, command)
        self._timers.append(handle)
        _log_safely(logging.INFO, "command %s #%d at %.3f (in %.3f s)", command.name,
                    command.command_id, command.t_exec, delay,
                    extra={"event": "command", "command": command.name})

    def _execute_command(self, command: Any) -> None:
        """Run a due command; ``set_params`` waits until the optimiser has applied it."""
        if command.name == "set_params" and self._loop is not None:
            task = self._loop.create_task(self._apply_params(command))
            self._command_tasks.add(task)
            task.add_done_callback(self._command_tasks.discard)
            return
        now = self.clock()
        info: dict[str, Any] = {"name": command.name}
        try:
            if command.name == "start":
                self.mission_state = "running"
            elif command.name == "end":
                self.mission_state = "ended"
            elif command.name == "set_params":  # no loop yet (tests driving the app directly)
                self._set_params_now(dict(command.args), now)
                info["params"] = dict(command.args)
            elif command.name == "request_report":
                info["counters"] = dict(self.counters)
            else:
                raise ValueError(f"unknown command {command.name!r}")
        except (ValueError, TypeError) as exc:
            self._finish_command(command, info, error=str(exc))
            return
        self._finish_command(command, info)

    async def _apply_params(self, command: Any) -> None:
        params = dict(command.args)
        info: dict[str, Any] = {"name": command.name, "params": params}
        assert self._loop is not None
        try:
            await self._loop.run_in_executor(self._decide_pool, self._set_params_now, params,
                                             self.clock())
        except Exception as exc:  # any rejection is the error
            self._finish_command(command, info, error=str(exc) or repr(exc))
            return
        finally:
            self._arm_decider_timer()
        self._finish_command(command, info)

    def _finish_command(self, command: Any, info: dict[str, Any], *,
                        error: str | None = None) -> None:
        """Send and remember the result; then the status message, mission log and log line."""
        now = self.clock()
        if error is None:
            status = Status(state="done", command_id=command.command_id, info=info)
        else:
            status = Status(state="error", command_id=command.command_id,
                            info={**info, "error": error})
        self._command_results[command.command_id] = status
        if len(self._command_results) > 1000:  # bounded: forget the oldest
            del self._command_results[next(iter(self._command_results))]
        try:
            self.transport.send_status(status, now)
        except (OSError, ValueError, LocalProtocolError) as exc:  # resent on the retry
            self.counters["send_errors"] += 1
            _log_safely(logging.WARNING, "command %s #%d: result not sent: %s",
                        command.name, command.command_id, exc)
        if error is not None:
            _log_safely(logging.WARNING, "command %s #%d failed: %s", command.name,
                        command.command_id, error)
            return
        self.publisher.on_sample(Sample(t=now))
        self._log.write({"state": {"agent": self.config.drone_id, "t": now,
                                   "mission": self.mission_state, "command": command.name}})
        _log_safely(logging.INFO, "command %s #%d done", command.name, command.command_id,
                    extra={"event": "command_done", "command": command.name})

    def _set_params_now(self, params: Mapping[str, Any], now: float) -> None:
        """Live parameter change (alpha, mcts_iterations, time_budget_s...) without restart.

        Runs in the decision executor (the optimiser's one thread). The decider validates
        every key before it changes anything; the app's own copy follows only when it did.
        """
        budget = params.get("time_budget_s")
        if "time_budget_s" in params and (isinstance(budget, bool)
                                          or not isinstance(budget, int | float)
                                          or not budget > 0):
            raise ValueError(f"time_budget_s must be a number > 0, got {budget!r}")
        self.decider.set_params(params, now)
        if budget is not None:
            self.config = dataclasses.replace(
                self.config, budgets=dataclasses.replace(self.config.budgets,
                                                         time_budget_s=float(budget)))


def _log_safely(level: int, msg: str, *args: Any, extra: Mapping[str, Any] | None = None
                ) -> None:
    """Log, but never let a logging problem (a bad ``extra`` key, a broken handler) stop
    the code path that logs: a command must run whether or not its log line can be made."""
    try:
        log.log(level, msg, *args, extra=dict(extra) if extra else None)
    except Exception:  # logging must not break the caller
        with contextlib.suppress(Exception):
            log.log(level, msg, *args)


def _decision_record(decision: DecisionLike) -> dict[str, Any]:
    record: dict[str, Any] = {"send": bool(decision.send), "version": decision.version,
                              "reason": decision.reason}
    for name in ("score", "iterations", "elapsed_s", "budget_bytes"):
        value = getattr(decision, name, None)
        if isinstance(value, int | float) and math.isfinite(value):
            record[name] = value
    return record


def _json_payload(data: Mapping[str, Any]) -> bytes:
    return json.dumps(dict(data), separators=(",", ":"), sort_keys=True).encode()


class AppSetupError(Exception):
    """The app cannot be assembled from this configuration; the text says what is wrong."""


def load_mission_spec(config: CompanionConfig) -> Any:
    """The mission spec the configuration names (a file or ``builtin:NAME``)."""
    from utility_specs.errors import SpecError
    from utility_specs.files import builtin_spec, load_spec

    spec = config.mission.spec
    try:
        if spec.startswith("builtin:"):
            return builtin_spec(spec.removeprefix("builtin:"))
        return load_spec(spec)
    except SpecError as exc:
        raise AppSetupError(f"{config.source}: mission.spec: {exc}") from None


def build_constraint(config: CompanionConfig) -> Any:
    from companion.middleware.constraints import make_constraint

    try:
        return make_constraint(config.constraint.name, **dict(config.constraint.params))
    except (ValueError, TypeError) as exc:
        raise AppSetupError(f"{config.source}: constraint: {exc}") from None


def check_setup(config: CompanionConfig) -> list[str]:
    """Build everything that does not need the vehicle or the network; lines to print."""
    spec = load_mission_spec(config)
    lines = [f"mission spec: {spec.source}: types {', '.join(sorted(spec.types))}"]
    missing = [t for t in ("image", "position", "battery", "status") if t not in spec.types]
    if missing:
        lines.append(f"mission spec: no type for {', '.join(missing)}: those messages "
                     "will be dropped")
    constraint = build_constraint(config)
    lines.append(f"constraint: {config.constraint.name} "
                 f"(window {constraint.window_s:g} s)")
    try:
        make_scorer(config.scoring.scorers, red=config.scoring.red_share,
                    aruco=config.scoring.aruco, hog=config.scoring.hog_people)
    except (ValueError, RuntimeError) as exc:
        raise AppSetupError(f"{config.source}: scoring.scorers: {exc}") from None
    lines.append(f"scoring: {', '.join(config.scoring.scorers) or 'none'}")
    gs = config.ground_station
    lines.append(f"ground station: {gs.host}:{gs.port} fleet {gs.fleet_id}")
    problem = missing_keys(config)  # check refuses what run would refuse
    if problem is not None:
        raise AppSetupError(problem)
    lines.append("keys: fleet key and the ground station's command key loaded")
    return lines


def create_app(config: CompanionConfig, *, clock: Clock,
               frame_source: FrameSource | None = None,
               mavlink_connect: Callable[[MavlinkSettings], Any] | None = None) -> CompanionApp:
    """The production wiring: the real middleware and UDP transport (app factory)."""
    check_setup(config)
    decider: Decider = build_decider(config)
    factory = build_transport_factory(config, clock=clock)
    return CompanionApp(config, decider=decider, transport_factory=factory, clock=clock,
                        frame_source=frame_source, mavlink_connect=mavlink_connect)


MIDDLEWARE_KEYS = (
    "c", "horizon_s", "tail_s", "default_latency_s", "max_items", "chunk_iterations",
    "search_inflight",
)
"""``[middleware]`` keys passed to ``MiddlewareConfig``; ``alpha`` and ``seed`` are ours."""


class MiddlewareDecider:
    """``companion.middleware.Middleware`` as the app's :class:`Decider`.

    Adds what belongs to the shell: the wall-time budget (``deadline`` on ``budget_clock``,
    a monotonic clock) besides the iteration budget, receiver reports turned into link samples
    and round trips for the (adaptive) constraint, and live parameter changes.
    """

    def __init__(self, middleware: Any, *, agent: str, time_budget_s: float,
                 budget_clock: Clock) -> None:
        self.middleware = middleware
        self.constraint = middleware.constraint
        self.agent = agent
        self.time_budget_s = time_budget_s
        self._budget_clock = budget_clock
        self.counters: dict[str, int] = {"link_samples": 0, "round_trips": 0,
                                         "bad_round_trips": 0}
        self.health = LinkHealth()

    def warm_up(self) -> None:
        """One decision on a throwaway optimiser, so JIT compilation (numba) happens before
        the first real message instead of costing it a decision timeout."""
        from companion.middleware.constraint import ConstantConstraint

        scratch = type(self.middleware)(self.middleware.config,
                                         constraint=ConstantConstraint(limit_bytes_per_s=1e5))
        spec_types = self.middleware.config.spec.types
        type_name = "image" if "image" in spec_types else next(iter(spec_types))
        versions = (Version(name="full", size=20_000, quality=1.0),
                    Version(name="half", size=5_000, quality=0.5))
        for seq in range(3):
            scratch.decide(Message(sender=self.agent, seq=seq, type=type_name, t_gen=seq * 0.2,
                                   size=20_000, data={"red": 0.1, "object": False,
                                                      "level": 0.9},
                                   versions=versions, version=0), seq * 0.2)

    def decide(self, message: Message, now: float) -> DecisionLike:
        deadline = self._budget_clock() + self.time_budget_s
        decision: DecisionLike = self.middleware.decide(message, now, deadline=deadline)
        if message.type == "status" and not decision.send:
            # the heartbeat: a status always goes, so the station's silence means loss; its
            # bytes count in the window like any send
            self.middleware.knowledge.on_sent(message, now=now)
            self.constraint.on_sent(message.size, now=now)
            decision = dataclasses.replace(decision, send=True, version=None,  # type: ignore[type-var]
                                           reason="status-heartbeat")
        if decision.send:
            self.health.on_sent(message.seq, now)
        return decision

    def link_health(self, now: float) -> dict[str, float | None]:
        """Δ (s) and loss of this drone's link, for its status messages."""
        return {"delta_s": self.health.delta_s(self.constraint), "loss": self.health.loss(now)}

    def on_report(self, event: Any, now: float) -> None:
        """Deliveries for the optimiser; our own ones as link samples for the constraint."""
        from companion.middleware.constraint import LinkSample
        from companion.middleware.linkstats import RoundTrip

        report = event.report
        self.middleware.on_report(report, now)
        for echo in report.echoes:
            if echo.sender != self.agent:
                continue
            try:
                trip = RoundTrip(t_sent=echo.t_sent, t_remote_rcv=echo.t_rcv,
                                 t_remote_sent=event.t_sent, t_rcv=event.t_rcv)
            except ValueError:
                self.counters["bad_round_trips"] += 1
                continue
            self.constraint.on_round_trip(trip, now=now)
            self.counters["round_trips"] += 1
        samples = [LinkSample(t_sent=e.t_sent, t_rcv=e.t_rcv, size=e.size, sender=e.sender,
                              seq=e.seq)
                   for e in report.entries if e.sender == self.agent and e.t_sent is not None]
        for sample in samples:
            self.health.on_delivered(sample.seq)
        if not samples:
            return
        self.constraint.on_samples(samples, now=now)
        self.counters["link_samples"] += len(samples)

    def set_params(self, params: Mapping[str, Any], now: float) -> None:
        """``mcts_iterations``, ``time_budget_s``, ``alpha`` (eq. 7.1/7.2), the optimiser's
        own keys and ``constraint.NAME`` (a number of the goodput constraint, e.g.
        ``constraint.limit_bytes_per_s`` or ``constraint.alpha_bytes_per_s``), effective from
        the next decision. All or nothing: every key is checked before any is applied, and a
        rejected key raises ValueError naming it and why."""
        from companion.middleware.middleware import MiddlewareError

        changes: dict[str, Any] = {}
        constraint_changes: dict[str, float] = {}
        time_budget: float | None = None
        for key, value in params.items():
            if key in ("mcts_iterations", *MIDDLEWARE_KEYS) and (
                    isinstance(value, bool) or not isinstance(value, int | float)
                    or not math.isfinite(value)):
                raise ValueError(f"{key} must be a number, got {value!r}")
            if key in ("mcts_iterations", "max_items", "chunk_iterations") and (
                    not isinstance(value, int) or value < 0):
                raise ValueError(f"{key} must be a whole number >= 0, got {value!r}")
            if key == "mcts_iterations":
                changes["max_iterations"] = value
            elif key == "time_budget_s":
                if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0:
                    raise ValueError(f"time_budget_s must be a number > 0, got {value!r}")
                time_budget = float(value)
            elif key == "alpha":
                self._check_alpha(value)
            elif key in MIDDLEWARE_KEYS:
                changes[key] = value
            elif key.startswith("constraint."):
                name = key.removeprefix("constraint.")
                constraint_changes[self._constraint_attr(name)] = self._constraint_value(
                    key, value)
            else:
                raise ValueError(f"unknown parameter {key!r} (known: mcts_iterations, "
                                 f"time_budget_s, alpha, {', '.join(MIDDLEWARE_KEYS)}, "
                                 f"constraint.{', constraint.'.join(self.constraint_keys())})")
        if changes:
            try:
                dataclasses.replace(self.middleware.config, **changes)
            except (MiddlewareError, TypeError) as exc:
                raise ValueError(str(exc)) from None
        if constraint_changes:
            self._check_constraint(constraint_changes)
        # everything checked: apply (alpha first, the only step that builds something)
        if "alpha" in params:
            self._set_alpha(params["alpha"])
        if changes:
            self.middleware.config = dataclasses.replace(self.middleware.config, **changes)
        if time_budget is not None:
            self.time_budget_s = time_budget
        for attr, number in constraint_changes.items():
            setattr(self.constraint, attr, number)

    def constraint_keys(self) -> list[str]:
        """The constraint's numbers ``set_params`` may change (``constraint.NAME``)."""
        names = [k for k, v in vars(self.constraint).items()
                 if not k.startswith("_") and k not in ("window_s", "n_updates")
                 and isinstance(v, int | float) and not isinstance(v, bool)]
        if hasattr(self.constraint, "_limit"):  # ConstantConstraint's ξ
            names.append("limit_bytes_per_s")
        return sorted(names)

    def _constraint_attr(self, name: str) -> str:
        if name not in self.constraint_keys():
            raise ValueError(f"unknown parameter 'constraint.{name}' for the "
                             f"{type(self.constraint).__name__} (known: "
                             f"{', '.join(self.constraint_keys()) or 'none'})")
        return "_limit" if name == "limit_bytes_per_s" else name

    def _check_constraint(self, changes: Mapping[str, float]) -> None:
        """Build a throwaway constraint of the same kind with the new numbers: its own
        checks (e.g. ranges) reject what the running one must not get."""
        import inspect

        kind = type(self.constraint)
        current = {name: getattr(self.constraint, "_limit" if name == "limit_bytes_per_s"
                                 else name, None)
                   for name in inspect.signature(kind).parameters}
        kwargs = {k: v for k, v in current.items()
                  if isinstance(v, int | float) and not isinstance(v, bool)}
        kwargs.update({"limit_bytes_per_s" if k == "_limit" else k: v
                       for k, v in changes.items()})
        try:
            kind(**kwargs)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"constraint: {exc}") from None

    @staticmethod
    def _constraint_value(key: str, value: Any) -> float:
        if (isinstance(value, bool) or not isinstance(value, int | float)
                or not math.isfinite(value) or value < 0):
            raise ValueError(f"{key} must be a number >= 0, got {value!r}")
        return float(value)

    def _check_alpha(self, alpha: Any) -> None:
        if isinstance(alpha, bool) or not isinstance(alpha, int | float) or alpha < 0:
            raise ValueError(f"alpha must be a number >= 0, got {alpha!r}")
        if not any("alpha" in info.utility.params()
                   for info in self.middleware.config.spec.types.values()):
            raise ValueError("alpha: no information type of the mission uses alpha")

    def _set_alpha(self, alpha: Any) -> None:
        from utility_specs.errors import SpecError
        from utility_specs.functions import make_function

        if isinstance(alpha, bool) or not isinstance(alpha, int | float) or alpha < 0:
            raise ValueError(f"alpha must be a number >= 0, got {alpha!r}")
        spec = self.middleware.config.spec
        types = dict(spec.types)
        changed = False
        for name, info in spec.types.items():
            utility = info.utility
            if "alpha" in utility.params():
                try:
                    fn = make_function(utility.name, {**utility.params(), "alpha": float(alpha)})
                except SpecError as exc:
                    raise ValueError(str(exc)) from None
                types[name] = dataclasses.replace(info, utility=fn)
                changed = True
        if not changed:
            raise ValueError("alpha: no information type of the mission uses alpha")
        new_spec = dataclasses.replace(spec, types=types)
        self.middleware.config = dataclasses.replace(self.middleware.config, spec=new_spec)
        self.middleware.knowledge.spec = new_spec

    def get_timer(self) -> float | None:
        timer: float | None = self.middleware.get_timer()
        return timer

    def handle_timer(self, now: float) -> None:
        self.middleware.handle_timer(now)


def build_decider(config: CompanionConfig, *, budget_clock: Clock | None = None
                  ) -> MiddlewareDecider:
    """The information distribution layer (``companion.middleware``) for this drone."""
    import time

    import numpy as np

    from companion.middleware.middleware import Middleware, MiddlewareConfig, MiddlewareError

    spec = load_mission_spec(config)
    constraint = build_constraint(config)
    extra = dict(config.middleware)
    alpha = extra.pop("alpha", None)
    seed = extra.pop("seed", None)
    unknown = sorted(set(extra) - set(MIDDLEWARE_KEYS))
    if unknown:
        raise AppSetupError(f"{config.source}: middleware.{unknown[0]}: expected one of "
                            f"alpha, seed, {', '.join(MIDDLEWARE_KEYS)}")
    try:
        mw_config = MiddlewareConfig(spec=spec, agent=config.drone_id,
                                     max_iterations=config.budgets.mcts_iterations, **extra)
    except (MiddlewareError, TypeError) as exc:
        raise AppSetupError(f"{config.source}: middleware: {exc}") from None
    rng = np.random.default_rng(seed if isinstance(seed, int) else None)
    clock = budget_clock or time.perf_counter
    middleware = Middleware(mw_config, rng=rng, constraint=constraint, budget_clock=clock)
    decider = MiddlewareDecider(middleware, agent=config.drone_id,
                                time_budget_s=config.budgets.time_budget_s, budget_clock=clock)
    if alpha is not None:
        try:
            decider.set_params({"alpha": alpha}, 0.0)
        except ValueError as exc:
            raise AppSetupError(f"{config.source}: middleware.alpha: {exc}") from None
    return decider


def build_transport_factory(config: CompanionConfig, *, clock: Clock) -> TransportFactory:
    """The UDP transport to the ground station (``companion.transport.UdpTransport``)."""
    from companion.transport import UdpTransport

    gs = config.ground_station
    problem = missing_keys(config)
    if problem is not None or gs.fleet_key is None:
        raise AppSetupError(problem or "no fleet key")
    key = gs.fleet_key
    try:
        Encoder(gs.fleet_id, config.drone_id, key)
    except LocalProtocolError as exc:
        raise AppSetupError(f"{config.source}: drone.id / ground_station: {exc}") from None
    # A fresh epoch per start: commands captured during an earlier boot carry the old one.
    epoch = secrets.randbits(63) + 1

    def factory(on_event: Callable[[Any], None]) -> Transport:
        return UdpTransport(
            encoder=Encoder(gs.fleet_id, config.drone_id, key),
            decoder=Decoder(gs.fleet_id, key, local_id=config.drone_id,
                            command_key=gs.command_public_key, epoch=epoch),
            remote_addr=(gs.host, gs.port),
            local_addr=(gs.listen_host, gs.listen_port),
            clock=clock,
            on_event=on_event,
            epoch=epoch,
        )

    return factory
