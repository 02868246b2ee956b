"""The study's workloads: fleets of simulated drones on :mod:`sitl.netsim` and the receiver
reports the ground station would send for them."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

FLEET_SIZES = (10, 25, 50, 100)
IMAGE_CAPACITY_BYTES_PER_S = 125_000.0
"""1 Mbit/s shared link (the near-capacity link of bench_mcts's companion-default row)."""
BATTERY_BUDGET_PER_10 = 9.25
"""Messages per 2.5 s window per 10 agents (the reference setup's budget 9.25)."""
OPTIMUM_AGENTS = (2, 4)
"""The exact offline optimum (DP over levels) is for small fleets only: at 10 agents it holds
more than 500 000 states on one level 2.3 s into the mission (measured), so the optimum cells
use 2 and 4 agents whatever ``--agents`` says."""
OPTIMUM_BUDGET_PER_AGENT = 0.75
"""Messages per window per agent in the optimum cells (bench_mcts: 3 for 4 agents)."""
REPORT_INTERVAL_S = 0.25
"""The ground station's report period (``ReportScheduler`` default in the product)."""
WARMUP = {"images": 3.0, "battery": 5.0, "long": 5.0}
"""Decisions before this simulated time are left out: the fleet is not known yet."""
CYCLE_S = 10.0
"""The ``long`` cell's scenario repeats every 10 s: each agent's period is rounded to
10 s / k (k = 8..12 for the reference's rates around 1 Hz), so the fleet's arrivals line up
the same way in every cycle and early and late decisions can be compared at like phases
(with free periods the alignment drifts over minutes and decide time follows it)."""


def image_agents(n: int, make_policy: Callable[[str, int], Any]) -> list[Any]:
    """``n`` drones: 5 frames/s in 3 versions, 1 Hz position, 0.2 Hz battery (phases spread
    over each period so the fleet's frames do not all arrive at one instant)."""
    from sitl.netsim import SimAgent, StreamConfig
    from utility_specs.message import Version

    versions = (Version(name="full", size=40_000, quality=1.0),
                Version(name="half", size=10_000, quality=0.5),
                Version(name="quarter", size=2_500, quality=0.25))
    agents = []
    for i in range(n):
        def red(k: int, g: np.random.Generator, i: int = i) -> dict[str, Any]:
            return {"red": float(min(1.0, abs(g.normal(0.002 * i, 0.05))))}

        phase = (i / n)
        agents.append(SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}", i), streams=[
            StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=0.2 * phase,
                         versions=versions, data=red),
            StreamConfig(type="position", period_s=1.0, size=64, phase_s=phase),
            StreamConfig(type="battery", period_s=5.0, size=32, phase_s=5.0 * phase,
                         data=lambda k, g: {"level": max(0.1, 1.0 - 0.001 * k)}),
        ]))
    return agents


def _image_run(n: int, t_end: float, seed: int) -> tuple[Any, Any, list[Any]]:
    from companion.middleware.adaptive import AdaptiveConstraint
    from companion.middleware.middleware import Middleware, MiddlewareConfig
    from sitl.netsim import ChannelConfig, simulate
    from utility_specs.files import builtin_spec

    spec = builtin_spec("image_streaming")
    middlewares: list[Middleware] = []

    def policy(name: str, i: int) -> Middleware:
        # build_decider's defaults: 300 iterations, horizon 3 s, adaptive constraint
        config = MiddlewareConfig(spec=spec, agent=name, max_iterations=300, horizon_s=3.0)
        mw = Middleware(config, rng=np.random.default_rng([seed, i]),
                        constraint=AdaptiveConstraint())
        middlewares.append(mw)
        return mw

    agents = image_agents(n, policy)
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=IMAGE_CAPACITY_BYTES_PER_S,
                                                    report_interval_s=REPORT_INTERVAL_S),
                      t_end=t_end, rng=np.random.default_rng([seed, 5]))
    return spec, result, middlewares


def fleet_spec(scenario: str, n: int) -> Any:
    """The scenario's spec for ``n`` agents: agent i's stream ``battery_i`` has the weight
    of ``battery_{i % 10}`` (the fleet is copies of the thesis' 10-agent fleet; its weights
    3^(i+1) would otherwise reach 3^100)."""
    import tomllib
    from importlib import resources

    from sitl.study.drop_rate import SCENARIOS
    from utility_specs.spec import parse_spec

    name = SCENARIOS[scenario]
    raw = tomllib.loads((resources.files("utility_specs") / "missions" / f"{name}.toml")
                        .read_text(encoding="utf-8"))
    base = raw["types"]
    raw["types"] = {f"battery_{i}": dict(base[f"battery_{i % len(base)}"]) for i in range(n)}
    return parse_spec(raw, source=f"{name} x {n} agents")


def _battery_run(n: int, t_end: float, seed: int, *, cycle_s: float | None = None,
                 wrap: Callable[[Any], Any] | None = None) -> tuple[Any, Any, list[Any]]:
    """The reference scenario (mostly-low, 1500 iterations) with ``n`` agents; with
    ``cycle_s`` every period divides it (a periodic scenario, see :data:`CYCLE_S`); ``wrap``
    wraps each agent's policy (the ``long`` cell's turns and planted cost)."""
    from sitl.netsim import SimAgent, simulate
    from sitl.study.drop_rate import CHANNEL, _scenario_streams, policy_factory

    seed = seed % 2**31
    spec = fleet_spec("mostly-low", n)
    make = policy_factory("mcts1500", BATTERY_BUDGET_PER_10 * n / 10, seed=seed)
    streams = _scenario_streams("mostly-low", n, np.random.default_rng([seed, 7]))
    if cycle_s is not None:
        streams = [replace(s, period_s=cycle_s / max(1, round(cycle_s / s.period_s)))
                   for s in streams]
    policies = [make(f"agent{i}", spec) for i in range(n)]
    deciders = [wrap(p) for p in policies] if wrap is not None else policies
    agents = [SimAgent(name=f"agent{i}", policy=deciders[i], streams=[streams[i]])
              for i in range(n)]
    result = simulate(agents, channel=replace(CHANNEL, report_interval_s=REPORT_INTERVAL_S),
                      t_end=t_end, rng=np.random.default_rng([seed, 3]))
    return spec, result, policies


class GrowingCost:
    """A policy with a planted O(elapsed) cost, to prove the ``long`` check trips: every
    decide also spends ``us_per_s`` microseconds of CPU per simulated second since the
    start (what a history scanned on every decision would cost). CPU time of this thread,
    the quantity the check measures, so the planted cost does not depend on the load."""

    def __init__(self, policy: Any, us_per_s: float) -> None:
        self.policy, self.us_per_s = policy, us_per_s

    def decide(self, message: Any, now: float) -> Any:
        decision = self.policy.decide(message, now)
        until = time.thread_time() + self.us_per_s * now * 1e-6
        while time.thread_time() < until:
            pass
        return decision

    def on_delivered(self, messages: Any, now: float) -> None:
        self.policy.on_delivered(messages, now)

    def __getattr__(self, name: str) -> Any:  # the constraint, report hooks, counters
        return getattr(self.policy, name)


RUNS: dict[str, Callable[[int, float, int], tuple[Any, Any, list[Any]]]] = {
    "images": _image_run,
    "battery": _battery_run,
}


@dataclass(frozen=True, slots=True)
class ReportSizes:
    mean_bytes: float
    max_bytes: int
    mean_datagrams: float
    downlink_bytes_per_s: float
    """Every report goes to every drone (unicast copies), as ``ground_station.receiver`` does."""


def report_sizes(delivered: Sequence[Any], *, senders: int, t_end: float,
                 interval_s: float = REPORT_INTERVAL_S) -> ReportSizes:
    """The receiver reports the ground station would send for these deliveries, encoded as
    the product encodes them (entries repeated in 2 reports, clock echoes rotating)."""
    from companion.protocol.encoder import Encoder
    from ground_station.reports import ReportScheduler

    key = hashlib.sha256(b"uav-infodist scaling study: sizes only").digest()
    encoder = Encoder(1, "gs", key)  # the ground station's default station_id
    scheduler = ReportScheduler(interval_s=interval_s, now=0.0)
    sizes: list[int] = []
    datagrams: list[int] = []

    def flush(until: float) -> None:
        while scheduler.get_timer() <= until:
            now = scheduler.get_timer()
            report = scheduler.due(now=now)
            if report is None:  # pragma: no cover - due at its own timer always reports
                break
            encoded = encoder.encode_report(report, now)
            sizes.append(sum(len(d) for d in encoded))
            datagrams.append(len(encoded))

    for m in sorted(delivered, key=lambda m: m.t_rcv):
        flush(m.t_rcv)
        scheduler.on_datagram(m.sender, t_sent=m.t_sent, t_rcv=m.t_rcv)
        scheduler.on_message(m, t_rcv=m.t_rcv)
    flush(t_end)
    if not sizes:
        return ReportSizes(0.0, 0, 0.0, 0.0)
    return ReportSizes(mean_bytes=float(np.mean(sizes)), max_bytes=max(sizes),
                       mean_datagrams=float(np.mean(datagrams)),
                       downlink_bytes_per_s=sum(sizes) * senders / t_end)
