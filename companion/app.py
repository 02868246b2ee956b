"""The companion application: small services wired together, run in one TaskGroup.

Data flow (ARCHITECTURE.md, "Data flow on a drone"; docs/architecture.md)::

    MavlinkService -> TelemetryState -> TelemetryPublisher (publisher.py) --+
    CameraService (camera.py) -> CameraPipeline (pipeline.py): score, encode -+
                                                                             v
        Dispatcher.submit (dispatch.py): decide in the decider's executor within the time
        budget -> MissionLogWriter (mission_log.py) -> transport.send_message -> ground station
    transport events: ReportReceived -> Dispatcher.on_report;
                      CommandReceived -> CommandExecutor (commands.py), run at t_exec

Every service has ``async run()`` with its cleanup in ``finally`` and ``stop()`` (or
``close()``); all run in exactly one ``asyncio.TaskGroup`` (:meth:`CompanionApp.run`).
Blocking work (scoring, JPEG, MCTS) runs in the services' executors; the optimiser is only
ever called from the dispatcher's one-thread executor, so it needs no locks.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import secrets
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

from companion.camera import CameraError, CameraService, FrameSource, open_source
from companion.commands import CommandExecutor
from companion.config import CompanionConfig, missing_keys
from companion.dispatch import COUNTERS, Dispatcher
from companion.mavlink import MavlinkService, MavlinkSettings
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
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
from companion.telemetry import LinkStateSample, Sample, TelemetryState
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
                                       options=dict(cam.options))
        self.mission = MissionWindow("idle" if config.mission.wait_for_start else "running")
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.mission_log = MissionLogWriter(mission_log if mission_log is not None
                                            else config.mission.log)
        self._stopping = asyncio.Event()
        self.transport = transport_factory(self._on_transport_event)
        self.dispatcher = Dispatcher(config, decider=decider, clock=clock,
                                     send_message=self.transport.send_message,
                                     mission_log=self.mission_log, mission=self.mission,
                                     counters=self.counters)
        self.mavlink = MavlinkService(config.mavlink, self.telemetry, clock=clock,
                                      connect=mavlink_connect)
        self.publisher = TelemetryPublisher(config.telemetry, telemetry=self.telemetry,
                                            dispatcher=self.dispatcher, mission=self.mission,
                                            clock=clock)
        self.telemetry.add_listener(self.publisher.on_sample)
        self.telemetry.add_listener(self._on_link_state)
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
                                        height=cam.height, pose=self.telemetry.snapshot)

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
                await self.dispatcher.warm_up()  # before anything asks the optimiser
                group.create_task(self.publisher.run(), name="telemetry-publisher")
                if self.camera is not None:
                    group.create_task(self.camera.run(), name="camera")
                group.create_task(self._housekeeping(), name="housekeeping")
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
                self.mission_log.flush()
        finally:
            self.mission_log.flush()

    # -- routing ----------------------------------------------------------------------------

    def _on_transport_event(self, event: Any) -> None:
        if isinstance(event, ReportReceived):
            self.dispatcher.on_report(event)
        elif isinstance(event, CommandReceived):
            self.commands.schedule(event.command)

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
        make_scorer(config.scoring.scorers, config.scoring.settings)
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
    try:
        return CompanionApp(config, decider=decider, transport_factory=factory, clock=clock,
                            frame_source=frame_source, mavlink_connect=mavlink_connect)
    except CameraError as exc:  # a bad camera.source is a setup error, not a traceback
        raise AppSetupError(f"{config.source}: camera.source: {exc}") from None


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
        return decision

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
