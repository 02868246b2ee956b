"""Middleware.decide end to end in explicit time; baselines; the netsim channel; the study."""

from __future__ import annotations

import ast
import csv
import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from companion.middleware import (
    ConstantConstraint,
    Decision,
    Greedy,
    KnapsackGreedy,
    Middleware,
    MiddlewareConfig,
    MiddlewareError,
    RandomDrop,
    SendAll,
)
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from tests.middleware.conftest import T0, msg, small_spec
from utility_specs.message import Message

SPEC = small_spec()
ROOT = Path(__file__).resolve().parents[2]


def _mw(budget_bytes_per_s: float = 1e12, **kw: object) -> Middleware:
    config = MiddlewareConfig(spec=SPEC, agent="a", max_iterations=300, **kw)  # type: ignore[arg-type]
    return Middleware(config, rng=np.random.default_rng(1),
                      constraint=ConstantConstraint(limit_bytes_per_s=budget_bytes_per_s,
                                                    window_s=1.0))


def test_decision_validation() -> None:
    with pytest.raises(MiddlewareError):
        Decision(send=False, version=1)


def test_unconstrained_sends_everything_best_version() -> None:
    mw = _mw()
    for k in range(6):
        d = mw.decide(msg("a", k, "image", T0 + 0.2 * k), T0 + 0.2 * k)
        assert d.send and d.version == 0, d


def test_budget_is_respected_and_counted() -> None:
    mw = _mw(budget_bytes_per_s=250.0)  # one 250-byte quarter image per 1 s window
    sent = []
    for k in range(10):
        now = T0 + 0.25 * k
        d = mw.decide(msg("a", k, "image", now), now)
        if d.send:
            assert d.version == 2
            sent.append(now)
    assert sent
    assert all(b - a > 1.0 for a, b in itertools.pairwise(sent))
    assert mw.counters["decisions"] == 10


def test_unknown_type_and_foreign_sender() -> None:
    mw = _mw()
    d = mw.decide(msg("a", 0, "nope", T0), T0)
    assert not d.send and d.reason == "unknown-type" and mw.counters["unknown_type"] == 1
    with pytest.raises(MiddlewareError):
        mw.decide(msg("b", 0, "battery", T0), T0)


def test_wall_clock_budget_uses_injected_clock() -> None:
    ticks = iter(range(1000))
    config = MiddlewareConfig(spec=SPEC, agent="a", max_iterations=100_000, chunk_iterations=10)
    mw = Middleware(config, rng=np.random.default_rng(0),
                    constraint=ConstantConstraint(limit_bytes_per_s=1e9),
                    budget_clock=lambda: float(next(ticks)))
    d = mw.decide(msg("a", 0, "battery", T0), T0, deadline=3.0)
    assert d.iterations <= 30


def test_deliveries_feed_knowledge_and_latency() -> None:
    mw = _mw()
    m = msg("b", 0, "battery", T0)
    delivered = m.delivered(receiver="ground", t_rcv=T0 + 0.2)
    mw.on_delivered([delivered, delivered], T0 + 0.2)
    assert mw.counters["delivered"] == 1
    assert mw.knowledge.latency.mean_s == pytest.approx(0.2)


def test_baselines() -> None:
    assert SendAll().decide(msg("a", 0, "image", T0), T0).version == 0
    rd = RandomDrop(0.5, rng=np.random.default_rng(3))
    share = np.mean([rd.decide(msg("a", k, "battery", T0), T0).send for k in range(400)])
    assert 0.4 < share < 0.6
    greedy = Greedy(SPEC, agent="a", constraint=ConstantConstraint(limit_bytes_per_s=1000,
                                                                   window_s=1.0))
    versions = [greedy.decide(msg("a", k, "image", T0 + 0.1 * k), T0 + 0.1 * k).version
                for k in range(3)]
    assert versions == [1, None, None] or versions[0] == 1
    knap = KnapsackGreedy(SPEC, agent="a", constraint=ConstantConstraint(limit_bytes_per_s=1e9))
    assert knap.decide(msg("a", 0, "battery", T0), T0).send


def test_channel_is_fifo_with_capacity_and_overhead() -> None:
    channel = ChannelConfig(capacity_bytes_per_s=1000.0, overhead_bytes=100, propagation_s=0.01)
    agents = [SimAgent(name=n, policy=SendAll(),
                       streams=[StreamConfig(type="linear", period_s=1.0, size=400)])
              for n in ("a", "b")]
    result = simulate(agents, channel=channel, t_end=2.5, rng=np.random.default_rng(0))
    rcv = sorted(m.t_rcv for m in result.delivered if m.t_rcv is not None)
    # both generate at 0, 1, 2: each packet takes 0.5 s, the second waits for the first
    assert rcv == pytest.approx([0.51, 1.01, 1.51, 2.01])  # the pair of t = 2 lands after 2.5
    assert result.drop_share == pytest.approx(2 / 6)


def test_channel_loss_is_seeded() -> None:
    channel = ChannelConfig(loss=0.5)
    agents = [SimAgent(name="a", policy=SendAll(),
                       streams=[StreamConfig(type="linear", period_s=0.1, size=10)])]
    a = simulate(agents, channel=channel, t_end=10, rng=np.random.default_rng(5))
    b = simulate(agents, channel=channel, t_end=10, rng=np.random.default_rng(5))
    assert a.lost == b.lost and 20 < a.lost < 80


def test_middleware_modules_are_io_free() -> None:
    banned = {"asyncio", "socket", "threading", "time", "cv2", "sqlite3", "random"}
    for name in ("middleware", "mcts", "_kernel", "incremental", "forecast", "knowledge",
                 "baselines"):
        tree = ast.parse((ROOT / "companion" / "middleware" / f"{name}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                assert not {a.name.split(".")[0] for a in node.names} & banned, name
            if isinstance(node, ast.ImportFrom) and node.module:
                assert node.module.split(".")[0] not in banned, name


def test_study_quick(tmp_path: Path) -> None:
    from sitl.study.drop_rate import main

    assert main(["--out", str(tmp_path), "--quick"]) == 0
    rows = list(csv.DictReader((tmp_path / "drop_rate.csv").open()))
    assert {r["scenario"] for r in rows} == {"mostly-low", "uniform", "mostly-high"}
    assert (tmp_path / "drop_rate.png").stat().st_size > 10_000
    by = {(r["scenario"], r["policy"], float(r["param"])): r for r in rows}
    # with the tightest budget, MCTS keeps more utility than dropping 80 % at random
    low = by[("mostly-low", "mcts300", 2.5)]
    rnd = by[("mostly-low", "random", 0.8)]
    assert float(low["drop_share"]) >= float(rnd["drop_share"]) - 0.1
    assert float(low["utility_pct"]) > float(rnd["utility_pct"])
    opt = list(csv.DictReader((tmp_path / "optimum.csv").open()))
    assert all(float(r["mcts_pct"]) <= float(r["optimum_pct"]) + 1.0 for r in opt)


def test_report_entries_keep_the_carried_quality() -> None:
    from companion.middleware import ReceiverReport
    from companion.protocol.records import ReportEntry

    mw = _mw()
    entry = ReportEntry(sender="b", seq=3, type="image", t_gen=T0, t_sent=T0, t_rcv=T0 + 0.1,
                        size=250, version=2, quality=0.25, data={})
    mw.on_report(ReceiverReport(entries=(entry,)), T0 + 0.1)
    base = mw.knowledge.base_message(msg("b", 4, "image", T0 + 1))
    assert base is not None and base[0].quality == 0.25 and base[1] == T0 + 0.1
    assert mw.counters["delivered"] == 1


def test_a_report_entry_received_before_its_drone_clock_generated_it_counts() -> None:
    """Ground and drone clocks disagree by a little: t_rcv < t_gen is clamped, not dropped."""
    from companion.middleware import ReceiverReport
    from companion.protocol.records import ReportEntry

    mw = _mw()
    entry = ReportEntry(sender="b", seq=3, type="image", t_gen=T0, t_sent=T0, t_rcv=T0 - 0.02,
                        size=250, data={})
    mw.on_report(ReceiverReport(entries=(entry,)), T0 + 0.1)
    assert mw.counters["delivered"] == 1 and mw.counters["bad_report_entry"] == 0


def test_bad_data_is_counted_and_does_not_poison_the_forecast() -> None:
    mw = _mw()
    bad = Message(sender="a", seq=0, type="battery", t_gen=T0, size=10, data={})  # no level
    d = mw.decide(bad, T0)
    assert not d.send and d.reason.startswith("bad-message")
    assert mw.counters["bad_message"] == 1
    mw.on_delivered([Message(sender="b", seq=0, type="battery", t_gen=T0, t_rcv=T0 + 0.1,
                             receiver="ground", data={"level": "x"})], T0 + 0.1)
    assert mw.counters["delivered"] == 0
    for k in range(1, 4):  # good messages afterwards are decided normally
        assert mw.decide(msg("a", k, "battery", T0 + k), T0 + k).reason == "mcts"


def _full_window_then_own(mw: Middleware) -> list[Decision]:
    """b's delivered status reports (10 Hz) keep the 1 s window full; then a's battery
    messages, worth far more per byte, come."""
    for j in range(11):
        t = T0 - 1.0 + 0.1 * j
        other = dataclasses.replace(msg("b", j, "status", t, size=200), receiver="ground",
                                    t_sent=t, t_rcv=t + 0.05)
        mw.on_delivered([other], t + 0.05)
    return [mw.decide(msg("a", 100 + k, "battery", T0 + 0.1 + 0.2 * k), T0 + 0.1 + 0.2 * k)
            for k in range(3)]


def test_an_invisible_stream_announces_itself_once() -> None:
    """Other agents plan only for streams they have heard of: a stream that never got a
    message out is sent once over a full window (counted), then plans as usual."""
    decisions = _full_window_then_own(_mw(budget_bytes_per_s=250.0))
    assert [d.send for d in decisions] == [True, False, False]
    assert decisions[0].reason == "mcts-announce"
    off = _mw(budget_bytes_per_s=250.0, announce_after_s=None)
    assert [d.send for d in _full_window_then_own(off)] == [False, False, False]
    assert off.counters["announce"] == 0
