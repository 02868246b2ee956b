"""The decision path of one drone: ask the decider about a message, log why, send the choice.

The :class:`Dispatcher` owns the optimiser's one-thread executor and makes every call into the
decider there (``decide``, reports, timers, live parameters, warm-up), so the decider needs no
locks. A message goes one way through :meth:`Dispatcher.submit`: decide (within the time
budget) -> mission log -> transport; nothing calls back up into the app.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import math
from collections.abc import Callable, Mapping, MutableMapping
from typing import TYPE_CHECKING, Any

from companion.config import CompanionConfig
from companion.decider_thread import DeciderThread
from companion.linkhealth import LinkHealth
from companion.middleware.decider import COMPANION_ALWAYS_SEND
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from utility_specs.message import Message

if TYPE_CHECKING:  # the decider seam (companion.middleware's Decider protocol)
    from companion.middleware.decider import Decider, Decision

__all__ = ["COUNTERS", "Dispatcher"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SendMessage = Callable[[Message, bytes, float], int]

HEARTBEAT_TYPES = frozenset(COMPANION_ALWAYS_SEND)
"""The status heartbeat: the registry's policies send it whatever they decide, and the
dispatcher sends it without asking while the optimiser warms up."""

COUNTERS = ("generated", "sent", "dropped", "decide_timeouts", "decide_errors", "send_errors",
            "reports", "commands", "frames_skipped", "frame_errors", "not_running", "decided",
            "fallback", "warming_up", "stalls")
"""The app's counters (shared by its services; ``request_report`` returns them)."""


class Dispatcher:
    """Decides and sends messages; runs the decider's reports, timers and parameter changes."""

    def __init__(self, config: CompanionConfig, *, decider: Decider, clock: Clock,
                 send_message: SendMessage, mission_log: MissionLogWriter,
                 mission: MissionWindow, counters: MutableMapping[str, int]) -> None:
        self.config = config
        """The configuration in force: live parameters (``time_budget_s``) replace it."""
        self.decider = decider
        self.clock = clock
        self.counters = counters
        self.sent_by_type: dict[str, int] = {}
        self._send_message = send_message
        self._log = mission_log
        self._mission = mission
        self._seq = 0
        self._pool = DeciderThread("decide")  # a daemon: a stop never waits for a compile
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self.health = LinkHealth()
        """Δ and loss of this drone's own link, for its status messages."""
        self._warming = False
        """The optimiser's warm-up (numba compilation: up to seconds on a cold cache) runs:
        only the status heartbeat goes out, so the station does not see the drone vanish."""
        self.after_warm_up: Callable[[], None] | None = None
        """Run in the decider's thread once its warm-up succeeded (the console script's:
        :func:`companion.cli.freeze_startup_heap`)."""
        self.optimiser_ready = False
        """The warm-up is over (or the decider has none): the statuses say so, and the fleet
        launcher starts the mission only once every drone's optimiser is ready."""

    # -- life cycle -------------------------------------------------------------------------

    def bind(self, stopping: asyncio.Event) -> None:
        """From now on decider calls go to the executor of the running loop, until
        ``stopping`` is set."""
        self._loop = asyncio.get_running_loop()
        self._stopping = stopping

    def close(self) -> None:
        if self._stopping is not None:
            self._stopping.set()
        if self._timer is not None:
            self._timer.cancel()
        self._pool.shutdown(wait=False, cancel_futures=True)

    @property
    def started(self) -> bool:
        """Bound to the event loop: decider calls go to its executor from now on."""
        return self._loop is not None

    @property
    def running(self) -> bool:
        """Started and not stopping: decider calls may be scheduled."""
        return self._stopping is not None and not self._stopping.is_set()

    async def warm_up(self) -> None:
        """Run the decider's optional ``warm_up`` in its executor; a stop request wins.
        Afterwards :attr:`optimiser_ready` is true, however the warm-up ended."""
        try:
            await self._warm_up()
        finally:
            self.optimiser_ready = True

    async def _warm_up(self) -> None:
        warm_up = getattr(self.decider, "warm_up", None)
        stopping = self._stopping
        if warm_up is None or stopping is None:
            return
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        after = self.after_warm_up

        def job() -> None:
            warm_up()
            if after is not None:
                after()

        work: asyncio.Future[Any] = loop.run_in_executor(self._pool, job)
        stop_wait = asyncio.ensure_future(stopping.wait())
        self._warming = True
        try:
            await asyncio.wait([work, stop_wait], timeout=120.0,
                               return_when=asyncio.FIRST_COMPLETED)
        finally:
            self._warming = False
            stop_wait.cancel()
        if not work.done():
            log.warning("optimiser warm-up unfinished after %.1f s", loop.time() - t0)
            return
        exc = work.exception()
        if exc is not None:  # logged, not fatal: the real decisions will show the problem
            log.warning("optimiser warm-up failed: %r", exc)
        else:
            log.info("optimiser warmed up in %.2f s", loop.time() - t0,
                     extra={"event": "warm_up"})

    # -- messages ---------------------------------------------------------------------------

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
        return await self.submit(message)

    async def submit(self, message: Message) -> bool:
        """Ask the decider about ``message``; send the chosen version (its bytes travel in
        the message's versions). True if sent."""
        self.counters["generated"] += 1
        if not self._mission.running and message.type != "status":
            self.counters["not_running"] += 1
            return False
        if self._warming:  # the optimiser's thread is busy compiling: no decision to ask for
            if message.type not in HEARTBEAT_TYPES:
                self.counters["warming_up"] += 1
                self._log.write_message(message, sent=False, decision={
                    "send": False, "reason": "optimiser warming up"})
                return False
            return self._send(message, None, {"send": True, "version": None,
                                              "reason": "status-heartbeat (warming up)"})
        loop = asyncio.get_running_loop()
        now = self.clock()
        budget = self.config.budgets.time_budget_s
        try:
            async with asyncio.timeout(budget + max(0.25, budget)):  # + queueing slack
                decision = await loop.run_in_executor(self._pool, self.decider.decide,
                                                      message, now)
        except TimeoutError:
            self.counters["decide_timeouts"] += 1
            if message.type in HEARTBEAT_TYPES:  # it always goes: the station's silence is loss
                return self._send(message, None, {"send": True, "version": None,
                                                  "reason": "status-heartbeat (decision timeout)"})
            self._log.write_message(message, sent=False, decision={
                "send": False, "reason": "decision timeout"})
            return False
        self._arm_timer()
        self.counters["decided"] += 1
        if decision.reason.startswith("fallback"):
            self.counters["fallback"] += 1
        info = decision_record(decision)
        if not self._mission.running and message.type != "status":
            # ended (or not started) while the optimiser decided: nothing goes out after end
            self.counters["not_running"] += 1
            self._log.write_message(message, sent=False, decision={
                **info, "send": False, "reason": f"mission {self._mission.state}"})
            return False
        if not decision.send:
            self.counters["dropped"] += 1
            self._log.write_message(message, sent=False, decision=info)
            return False
        return self._send(message, decision.version, info)

    def _send(self, message: Message, version: int | None, info: dict[str, Any]) -> bool:
        """Send the decided version of ``message``, count and log it. True if sent."""
        chosen = message
        if message.versions and version is not None:
            chosen = message.with_version(version)
        t_sent = self.clock()
        chosen = dataclasses.replace(chosen, t_sent=t_sent)
        try:
            datagrams = self._send_message(chosen, chosen.payload, t_sent)
        except (OSError, ValueError) as exc:
            self.counters["send_errors"] += 1
            log.warning("send %s/%d failed: %s", chosen.type, chosen.seq, exc)
            self._log.write_message(chosen, sent=False, decision={**info, "error": str(exc)})
            return False
        if datagrams == 0:  # refused whole: the pacer's backlog (the link is busy), a full
            self.counters["send_errors"] += 1  # write buffer, or no socket yet
            self._log.write_message(chosen, sent=False, decision={
                **info, "error": "the transport refused it (link queue full)"})
            return False
        self.counters["sent"] += 1
        self.health.on_sent(chosen.seq, t_sent)
        self.sent_by_type[chosen.type] = self.sent_by_type.get(chosen.type, 0) + 1
        self._log.write_message(chosen, sent=True, decision=info)
        return True

    # -- reports, timers, live parameters ----------------------------------------------------

    def on_report(self, event: Any, *, receiver: str = "ground") -> None:
        """A receiver report (a protocol event, or a ``ReceiverReport`` built here) for the
        decider, handled in its executor; ``receiver``: who sent the event's report."""
        self.counters["reports"] += 1
        loop = asyncio.get_running_loop()
        from companion.middleware.reports import ReceiverReport

        report = event if isinstance(event, ReceiverReport) \
            else ReceiverReport.from_event(event, receiver=receiver)
        if report.receiver == "ground":  # the link health is the link to the station
            for entry in report.entries:
                if entry.sender == self.config.drone_id:
                    self.health.on_delivered(entry.seq)
        future = loop.run_in_executor(self._pool, self.decider.on_report, report, self.clock())
        future.add_done_callback(self._after_call)

    def on_stall(self, t_from: float, t_to: float) -> None:
        """The process did not run in [t_from, t_to] (fleet clock): a decider that learns the
        link from reports is told, in its executor, so the delay is not read as queueing."""
        self.counters["stalls"] += 1
        hook = getattr(self.decider, "on_stall", None)
        if hook is None or self._loop is None:
            return
        future = self._loop.run_in_executor(self._pool, hook, t_from, t_to, self.clock())
        future.add_done_callback(self._after_call)

    def mission_started(self) -> None:
        """The ground station started the mission: tell a decider that plans the mission's
        start (the middleware's fleet share), in its executor like every decider call."""
        hook = getattr(self.decider, "mission_started", None)
        if hook is None:
            return
        if self._loop is None:  # not bound to a loop yet (tests driving the app directly)
            hook(self.clock())
            return
        future = self._loop.run_in_executor(self._pool, hook, self.clock())
        future.add_done_callback(self._after_call)

    async def set_params(self, params: Mapping[str, Any]) -> None:
        """Apply live parameters in the decider's executor; raises what rejected them."""
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(self._pool, self.set_params_now, params, self.clock())
        finally:
            self._arm_timer()

    def set_params_now(self, params: Mapping[str, Any], now: float) -> None:
        """Live parameter change (alpha, mcts_iterations, time_budget_s...) without restart.

        Runs in the decision executor (the optimiser's one thread). The decider validates
        every key before it changes anything; the app's own copy follows only when it did.
        """
        budget = params.get("time_budget_s")
        if "time_budget_s" in params and (isinstance(budget, bool)
                                          or not isinstance(budget, int | float)
                                          or not budget > 0):
            raise ValueError(f"time_budget_s must be a number > 0, got {budget!r}")
        result = self.decider.set_params(params, now)
        if result.error is not None:
            raise ValueError(result.error)
        if budget is not None:
            self.config = dataclasses.replace(
                self.config, budgets=dataclasses.replace(self.config.budgets,
                                                         time_budget_s=float(budget)))

    def _after_call(self, future: asyncio.Future[Any]) -> None:
        if future.cancelled():
            return
        exc = future.exception()
        if exc is not None:
            self.counters["decide_errors"] += 1
            log.error("middleware call failed: %r", exc, exc_info=exc)
        self._arm_timer()

    def _arm_timer(self) -> None:
        """One ``call_later`` for the decider's next deadline (aioquic's transmit())."""
        loop = self._loop
        if loop is None or not self.running:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadline = self.decider.get_timer()
        if deadline is None:
            return
        self._timer = loop.call_later(max(0.0, deadline - self.clock()), self._fire_timer)

    def _fire_timer(self) -> None:
        self._timer = None
        if self._loop is None or not self.running:
            return
        future = self._loop.run_in_executor(self._pool, self.decider.handle_timer,
                                            self.clock())
        future.add_done_callback(self._after_call)

    # -- figures for status messages ---------------------------------------------------------

    def constraint_limit(self) -> float | None:
        """ξ now (bytes/s) when the decider exposes its constraint, for status messages."""
        constraint = getattr(self.decider, "constraint", None)
        if constraint is None:
            return None
        value = float(constraint.limit_bytes_per_s(now=self.clock()))
        return value if math.isfinite(value) else None

    def link_health(self) -> dict[str, float]:
        """Δ (s) and loss of this drone's link, for status messages (what is known)."""
        values = {"delta_s": self.health.delta_s(getattr(self.decider, "constraint", None)),
                  "loss": self.health.loss(self.clock())}
        return {k: v for k, v in values.items() if v is not None}

    def fallback_share(self) -> float | None:
        """Share of decisions the optimiser did not make itself (greedy fallback or timeout);
        None before the first decision."""
        c = self.counters
        asked = c["decided"] + c["decide_timeouts"]
        return (c["fallback"] + c["decide_timeouts"]) / asked if asked else None


def decision_record(decision: Decision) -> dict[str, Any]:
    """The ``decision`` field of a mission log record: what was chosen, why, at what cost."""
    record: dict[str, Any] = {"send": bool(decision.send), "version": decision.version,
                              "reason": decision.reason}
    for name in ("score", "iterations", "elapsed_s", "budget_bytes"):
        value = getattr(decision, name, None)
        if isinstance(value, int | float) and math.isfinite(value):
            record[name] = value
    return record


def _json_payload(data: Mapping[str, Any]) -> bytes:
    return json.dumps(dict(data), separators=(",", ":"), sort_keys=True).encode()
