"""Mission length without the machine's noise: a young and an old mission, interleaved.

Whether decide() gets dearer as a mission goes on cannot be read from one run's early and
late decisions: on a shared machine the CPU time of the same work changes by x1.5 from one
10 s stretch to the next (another process on the sibling hyperthread, the caches), and a
scenario's load pattern moves along the mission. So two missions of the same periodic
scenario (:data:`~sitl.study.scaling.workloads.CYCLE_S`) run in two threads that take turns
decision by decision: the *old* one from 0 to ``t_end``, the *young* one ``offset_s`` (a
whole number of cycles) behind it. The young mission's first cycles and the old one's last
cycles then run interleaved, at the same phase of the scenario and under the same machine
conditions, and differ only in how long their mission has run.

Only one mission runs at a time (a baton): the one whose aligned time (its simulated time,
minus ``offset_s`` for the old one) is behind. Each decision's CPU and wall time is taken
here around the inner ``decide`` (after the hand-over), so waiting for the baton never
counts.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Baton", "Timed", "TimedDecisions", "run_interleaved"]

OLD, YOUNG = 0, 1


class Baton:
    """Cooperative turns between two missions by aligned simulated time."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._at = [-math.inf, -math.inf]
        self._done = [False, False]
        self._running: int | None = None

    def enter(self, me: int) -> None:
        with self._cond:
            self._cond.wait_for(lambda: self._running in (None, me))
            self._running = me

    def step(self, me: int, aligned_t: float) -> None:
        """Before ``me`` decides at ``aligned_t``: let the other mission catch up first."""
        other = 1 - me
        with self._cond:
            self._at[me] = aligned_t
            if not self._done[other] and self._at[other] < aligned_t:
                self._running = other
                self._cond.notify_all()
                self._cond.wait_for(lambda: self._running == me)

    def leave(self, me: int) -> None:
        other = 1 - me
        with self._cond:
            self._done[me], self._at[me] = True, math.inf
            self._running = None if self._done[other] else other
            self._cond.notify_all()


@dataclass(slots=True)
class TimedDecisions:
    """One mission's decisions as timed here: simulated time, wall and CPU seconds."""

    t: list[float] = field(default_factory=list)
    wall_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)

    def cpu_ms(self) -> np.ndarray:
        return np.asarray(self.cpu_s) * 1e3


class Timed:
    """Wraps one agent's policy: waits for the baton, then times the inner ``decide``."""

    def __init__(self, policy: Any, baton: Baton, me: int, offset_s: float,
                 record: TimedDecisions) -> None:
        self.policy, self.baton, self.me = policy, baton, me
        self.offset_s, self.record = offset_s, record

    def decide(self, message: Any, now: float) -> Any:
        self.baton.step(self.me, now - self.offset_s)
        t0, c0 = time.perf_counter(), time.thread_time()
        decision = self.policy.decide(message, now)
        self.record.wall_s.append(time.perf_counter() - t0)
        self.record.cpu_s.append(time.thread_time() - c0)
        self.record.t.append(now)
        return decision

    def on_delivered(self, messages: Any, now: float) -> None:
        self.policy.on_delivered(messages, now)

    def __getattr__(self, name: str) -> Any:  # the constraint, report hooks, counters
        return getattr(self.policy, name)


Run = Callable[[float, Callable[[Any], Any]], tuple[Any, Any, list[Any]]]
"""``run(t_end, wrap)``: one mission whose every policy is ``wrap(policy)``."""


def run_interleaved(run: Run, *, t_end: float, offset_s: float) -> tuple[
        tuple[Any, Any, list[Any]], TimedDecisions, TimedDecisions]:
    """The old mission (0..``t_end``) and the young one (0..``t_end - offset_s``) in turns;
    returns the old mission's ``run`` result and both missions' timed decisions."""
    baton = Baton()
    records = (TimedDecisions(), TimedDecisions())

    def mission(me: int, length: float, offset: float) -> tuple[Any, Any, list[Any]]:
        baton.enter(me)
        try:
            return run(length, lambda p: Timed(p, baton, me, offset, records[me]))
        finally:
            baton.leave(me)

    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="lockstep") as pool:
        old = pool.submit(mission, OLD, t_end, offset_s)
        young = pool.submit(mission, YOUNG, t_end - offset_s, 0.0)
        result = old.result()
        young.result()
    return result, records[OLD], records[YOUNG]
