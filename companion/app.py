"""The companion application: small services wired together, run in one TaskGroup.

Data flow (ARCHITECTURE.md, "Data flow on a drone"; docs/architecture.md)::

    MavlinkService -> TelemetryState -> TelemetryPublisher (publisher.py) --+
    CameraService (camera.py) -> CameraPipeline (pipeline.py): score, encode -+
                                                                             v
        Dispatcher.submit (dispatch.py): decide in the decider's executor within the time
        budget -> MissionLogWriter (mission_log.py) -> transport.send_message -> ground station
    transport events: ReportReceived -> Dispatcher.on_report (a ReceiverReport);
                      CommandReceived -> CommandExecutor (commands.py), run at t_exec

Every service has ``async run()`` with its cleanup in ``finally`` and ``stop()`` (or
``close()``); all run in exactly one ``asyncio.TaskGroup`` (:meth:`CompanionApp.run`).
Blocking work (scoring, JPEG, MCTS) runs in the services' executors; the optimiser is only
ever called from the dispatcher's one-thread executor, so it needs no locks.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from companion.camera import CameraError, FrameSource, open_source
from companion.camera_service import CameraService
from companion.clock_check import ClockCheck
from companion.commands import CommandExecutor
from companion.config import CompanionConfig, missing_keys
from companion.dispatch import COUNTERS, Dispatcher
from companion.mavlink import MavlinkService, MavlinkSettings
from companion.mavlink_commands import wildcard_mavlink_warning
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter, log_problem
from companion.peers import PeerServices, peer_types_of, peers_setup_problem
from companion.pipeline import CameraPipeline
from companion.protocol import (
    CommandReceived,
    Decoder,
    Encoder,
    LocalProtocolError,
    ReportReceived,
)
from companion.publisher import TelemetryPublisher
from companion.scoring import Scorer, make_scorer
from companion.telemetry import LinkStateSample, Sample, StatusTextSample, TelemetryState
from utility_specs.message import Message

if TYPE_CHECKING:  # the middleware (numba, numpy) is imported when a decider is built
    from companion.middleware.constraints.base import GoodputConstraint
    from companion.middleware.decider import Decider

__all__ = [
    "CompanionApp",
    "Transport",
    "TransportFactory",
]

log = logging.getLogger(__name__)

STALL_LATE_S = 1.0
"""The housekeeping tick this late means the process did not run (:meth:`CompanionApp._stalled`)."""
CAMERA_REOPEN_S = 2.0
"""A live camera that cannot be opened, or stops giving frames, is opened again this often;
the companion runs on without it (telemetry first)."""

Clock = Callable[[], float]


class Transport(Protocol):
    """The UDP link to the ground station (``companion.transport``)."""

    async def run(self) -> None: ...

    def stop(self) -> None: ...

    def send_message(self, message: Message, payload: bytes, now: float, *,
                     shared: bool = False) -> int: ...

    def send_status(self, status: Any, now: float) -> int: ...

    def pace(self, rate_bytes_per_s: float) -> None: ...


TransportFactory = Callable[[Callable[[Any], None]], Transport]
"""Builds the transport given the callback that receives its decoder events."""


class CompanionApp:
    """One drone's companion: the services below, wired together and run in one TaskGroup.

    Everything with I/O is injected so tests can swap it: ``decider`` (the middleware),
    ``transport_factory``, ``frame_source`` (default: from the camera config), ``scorer``
    (default: the configured scorers) and ``mavlink_connect`` (default: pymavlink).
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
        self.clock = clock
        self.telemetry = TelemetryState()
        cam = config.camera
        if cam.enabled and frame_source is None:  # first: a camera that cannot open stops here
            frame_source = open_source(cam.source, width=cam.width, height=cam.height,
                                       rate_hz=cam.rate_hz, pose=self.telemetry.snapshot,
                                       options=dict(cam.options), reopen_s=CAMERA_REOPEN_S)
        self.mission = MissionWindow("idle" if config.mission.wait_for_start else "running")
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.mission_log = MissionLogWriter(mission_log if mission_log is not None
                                            else config.mission.log)
        self._stopping = asyncio.Event()
        self.transport = transport_factory(self._on_transport_event)
        self.dispatcher = Dispatcher(config, decider=decider, clock=clock,
                                     send_message=self._send_message,
                                     mission_log=self.mission_log, mission=self.mission,
                                     counters=self.counters)
        link_rate = config.ground_station.link_rate_bytes_per_s
        if link_rate > 0:  # no message's datagrams leave faster than the radio carries them
            self.transport.pace(link_rate)
        self.mavlink = MavlinkService(config.mavlink, self.telemetry, clock=clock,
                                      connect=mavlink_connect)
        self.publisher = TelemetryPublisher(config.telemetry, telemetry=self.telemetry,
                                            dispatcher=self.dispatcher, mission=self.mission,
                                            clock=clock)
        spec_peer_types = peer_types_of(load_mission_spec(config))
        self.peers_problem = peers_setup_problem(config.peers, spec_peer_types)
        self.peers = PeerServices(  # peer table, /peers endpoint, ADSB_VEHICLE (docs/peers.md)
            config.peers, own_id=config.drone_id, clock=clock,
            peer_types=spec_peer_types if config.peers.medium else frozenset(),
            send_mavlink=self.mavlink.send_message,
            send_report=(getattr(self.transport, "send_report_shared", None)
                         if config.peers.medium else None),
            learn=self._learn_heard)
        self.peers.count_reports_in(decider)  # reports on the medium use the budget's air time
        self.publisher.status_extra = self.peers.status_fields
        self.telemetry.add_listener(self.publisher.on_sample)
        self.telemetry.add_listener(self._on_link_state)
        self.telemetry.add_listener(ClockCheck(time.monotonic).on_sample)
        self.commands = CommandExecutor(
            drone_id=config.drone_id, clock=clock, send_status=self.transport.send_status,
            dispatcher=self.dispatcher, mission=self.mission, mission_log=self.mission_log,
            on_done=lambda now: self.publisher.on_sample(Sample(t=now)))
        self.pipeline: CameraPipeline | None = None
        self.camera: CameraService | None = None
        if frame_source is not None and cam.enabled:
            self.pipeline = CameraPipeline(
                cam, drone_id=config.drone_id, dispatcher=self.dispatcher, mission=self.mission,
                scorer=scorer or make_scorer(config.scoring.scorers, config.scoring.settings))
            self.camera = CameraService(frame_source, self.pipeline.on_frame, clock=clock,
                                        rate_hz=cam.rate_hz, width=cam.width,
                                        height=cam.height, pose=self.telemetry.snapshot,
                                        on_problem=self._camera_problem)

    def _camera_problem(self, severity: int, text: str) -> None:
        """A camera outage rides on the status as an autopilot text does: the dashboard's
        alerts and a GCS fed by the station's MAVLink mirror show it."""
        self.publisher.on_sample(StatusTextSample(t=self.clock(), severity=severity,
                                                  text=text))

    @property
    def config(self) -> CompanionConfig:
        """The configuration in force (live parameters such as ``time_budget_s`` included)."""
        return self.dispatcher.config

    @property
    def mission_state(self) -> str:
        return self.mission.state

    @property
    def sent_by_type(self) -> dict[str, int]:
        return self.dispatcher.sent_by_type

    def fallback_share(self) -> float | None:
        return self.dispatcher.fallback_share()

    # -- life cycle -----------------------------------------------------------------------

    async def run(self) -> None:
        """Run every service until :meth:`stop` (or one of them fails)."""
        drone = self.config.drone_id
        log.info("companion %s starting", drone, extra={"event": "start", "drone": drone})
        exposed = wildcard_mavlink_warning(self.config.mavlink.url)
        if exposed is not None:
            log.warning(exposed)
        if self.peers_problem is not None:
            log.warning(self.peers_problem)
        self.mission_log.write({"mission": {"t_start": self.clock()}})
        self.dispatcher.bind(self._stopping)
        try:
            async with asyncio.TaskGroup() as group:
                group.create_task(self.transport.run(), name="transport")
                wait_started = getattr(self.transport, "wait_started", None)
                if wait_started is not None:  # bind before anything tries to send
                    async with asyncio.timeout(10.0):
                        await wait_started()
                group.create_task(self.mavlink.run(), name="mavlink")
                # statuses flow while the optimiser warms up (the dispatcher sends them without
                # it), so a cold numba cache never looks like a lost link at the station
                group.create_task(self.publisher.run(), name="telemetry-publisher")
                await self.dispatcher.warm_up()  # before anything else asks the optimiser
                if self.camera is not None:
                    group.create_task(self.camera.run(), name="camera")
                group.create_task(self._housekeeping(), name="housekeeping")
                group.create_task(self.peers.run(), name="peers")
                await self._stopping.wait()
                self._stop_services()
        finally:
            self.commands.close()
            self.dispatcher.close()
            if self.pipeline is not None:
                self.pipeline.close()
            self.mission_log.write({"mission": {"t_end": self.clock()}})
            self.mission_log.close()
            log.info("companion %s stopped", drone,
                     extra={"event": "stop", "counters": dict(self.counters)})

    def _stop_services(self) -> None:
        self.transport.stop()
        self.mavlink.stop()
        self.publisher.stop()
        self.peers.stop()
        if self.camera is not None:
            self.camera.stop()

    def stop(self) -> None:
        """Ask every service to finish (safe to call from a signal handler)."""
        self._stopping.set()

    async def _housekeeping(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            while not self._stopping.is_set():
                t_before, ran_at = loop.time(), self.clock()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(1.0):
                        await self._stopping.wait()
                self._check_ran(loop.time() - t_before - 1.0, since=ran_at)
                t_before, ran_at = loop.time(), self.clock()
                self.mission_log.flush()
                self._check_ran(loop.time() - t_before, since=ran_at)  # a slow SD card's write
        finally:
            self.mission_log.flush()

    def _check_ran(self, late_s: float, *, since: float) -> None:
        if late_s > STALL_LATE_S and not self._stopping.is_set():
            self._stalled(late_s, since=since)

    def _stalled(self, late_s: float, *, since: float) -> None:
        """The loop did not run for ``late_s`` (SIGSTOP, swap, an SD card's write, a paused
        VM): what the pacer held was stamped before and left after, so the adaptive
        constraint must not read those messages' latency as the link's queue."""
        pacer = getattr(self.transport, "pacer", None)
        held_s = pacer.max_delay_s if pacer is not None else 0.0
        log.warning("companion: the process did not run for %.1f s (this computer was busy "
                    "or suspended): the link statistics skip what it delayed", late_s,
                    extra={"event": "stall", "late_s": round(late_s, 2)})
        self.dispatcher.on_stall(since - held_s, self.clock())

    # -- routing ----------------------------------------------------------------------------

    def _on_transport_event(self, event: Any) -> None:
        self.peers.on_event(event)  # peers' telemetry heard on the shared medium
        if isinstance(event, ReportReceived):  # the ground's, or a peer's on the medium
            self.dispatcher.on_report(event, receiver=event.reporter
                                      if self.peers.is_peer(event.reporter) else "ground")
        elif isinstance(event, CommandReceived):
            self.commands.schedule(event.command)

    def _learn_heard(self, report: Any, now: float) -> None:
        """What this drone heard from peers is delivered here too: its optimiser learns it."""
        from companion.middleware.reports import ReceiverReport

        self.dispatcher.on_report(ReceiverReport(entries=report.entries,
                                                 receiver=self.config.drone_id))

    def _send_message(self, message: Message, payload: bytes, now: float) -> int:
        """Types the spec shares with peers go on the shared medium (docs/peers.md)."""
        if self.peers.shared(message.type):
            return self.transport.send_message(message, payload, now, shared=True)
        return self.transport.send_message(message, payload, now)

    def _on_link_state(self, sample: Sample) -> None:
        """Autopilot link changes go to the mission log as state records."""
        if isinstance(sample, LinkStateSample):
            self.mission_log.write_state(
                self.config.drone_id, sample.t,
                autopilot_link="up" if sample.connected else "lost", reason=sample.reason)


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


def build_constraint(config: CompanionConfig) -> GoodputConstraint:
    from companion.middleware.constraints import make_constraint
    from companion.middleware.errors import MiddlewareError

    try:
        return make_constraint(config.constraint.name, **dict(config.constraint.params))
    except MiddlewareError as exc:
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
        make_scorer(config.scoring.scorers, config.scoring.settings)
    except (ValueError, RuntimeError) as exc:
        raise AppSetupError(f"{config.source}: scoring.scorers: {exc}") from None
    lines.append(f"scoring: {', '.join(config.scoring.scorers) or 'none'}")
    gs = config.ground_station
    lines.append(f"ground station: {gs.host}:{gs.port} fleet {gs.fleet_id}")
    unshared = peers_setup_problem(config.peers, peer_types_of(spec))
    if unshared is not None:
        lines.append(f"peers: {unshared}")
    problem = missing_keys(config)  # check refuses what run would refuse
    if problem is not None:
        raise AppSetupError(problem)
    lines.append("keys: fleet key and the ground station's command key loaded")
    if config.mission.log is not None:
        if (unwritable := log_problem(config.mission.log)) is not None:
            raise AppSetupError(f"{config.source}: mission.log: {unwritable}")
        lines.append(f"mission log: {config.mission.log}")
    return lines


def create_app(config: CompanionConfig, *, clock: Clock,
               frame_source: FrameSource | None = None,
               mavlink_connect: Callable[[MavlinkSettings], Any] | None = None) -> CompanionApp:
    """The production wiring: the real middleware and UDP transport (app factory)."""
    check_setup(config)
    decider: Decider = build_decider(config)
    factory = build_transport_factory(config, clock=clock)
    try:
        return CompanionApp(config, decider=decider, transport_factory=factory, clock=clock,
                            frame_source=frame_source, mavlink_connect=mavlink_connect)
    except CameraError as exc:  # a bad camera.source is a setup error, not a traceback
        raise AppSetupError(f"{config.source}: camera.source: {exc}") from None


def build_decider(config: CompanionConfig, *, budget_clock: Clock | None = None) -> Decider:
    """The decision policy ``[middleware] policy`` (default ``mcts``) for this drone."""
    import time

    import numpy as np

    from companion.middleware.decider import DeciderSetup
    from companion.middleware.errors import MiddlewareError, UnknownParamError
    from companion.middleware.policies import make_decider

    params = dict(config.middleware)
    policy = params.pop("policy", "mcts")
    seed = params.pop("seed", None)
    setup = DeciderSetup(spec=load_mission_spec(config), agent=config.drone_id,
                         constraint=build_constraint(config),
                         rng=np.random.default_rng(seed if isinstance(seed, int) else None),
                         max_iterations=config.budgets.mcts_iterations,
                         time_budget_s=config.budgets.time_budget_s,
                         budget_clock=budget_clock or time.perf_counter)
    try:
        return make_decider(policy, setup, **params)
    except UnknownParamError as exc:
        raise AppSetupError(f"{config.source}: middleware.{exc.key}: expected one of "
                            f"policy, seed, {', '.join(exc.known)}") from None
    except MiddlewareError as exc:
        raise AppSetupError(f"{config.source}: middleware: {exc}") from None


def build_transport_factory(config: CompanionConfig, *, clock: Clock) -> TransportFactory:
    """The UDP transport to the ground station (``companion.transport.UdpTransport``)."""
    from companion.transport import UdpTransport, parse_medium

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
            remote_name="ground_station.host",
            local_addr=(gs.listen_host, gs.listen_port),
            clock=clock,
            on_event=on_event,
            epoch=epoch,
            medium=parse_medium(config.peers.medium) if config.peers.medium else None,
        )

    return factory
