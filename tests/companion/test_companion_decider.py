"""The decider the app builds from its config: budgets, reports, live parameters, policies."""

from __future__ import annotations

import pytest

from companion.app import AppSetupError, build_decider
from companion.config import ConfigError, parse_config
from companion.middleware import Middleware, RandomDrop, ReceiverReport, SendAll
from companion.protocol import ClockEcho, Report, ReportEntry, ReportReceived
from utility_specs.message import Message, Version

T0 = 1_700_000_000.0


def _config(**tables: object) -> object:
    return parse_config({"drone": {"id": "d1"}, "budgets": {"mcts_iterations": 50},
                         "constraint": {"name": "adaptive", "params": {"window_s": 0.5}},
                         **tables})


def _image(seq: int, t: float, red: float) -> Message:
    versions = (Version(name="full", size=30_000, quality=1.0),
                Version(name="half", size=8_000, quality=0.5))
    return Message(sender="d1", seq=seq, type="image", t_gen=t, size=30_000,
                   data={"red": red, "object": False}, versions=versions, version=0)


def test_decides_with_the_iteration_budget() -> None:
    decider = build_decider(_config())
    decision = decider.decide(_image(0, T0, 0.2), T0)
    assert decision.reason.startswith(("mcts", "fallback"))
    assert 0 < decision.iterations <= 50  # type: ignore[attr-defined]
    unknown = decider.decide(Message(sender="d1", seq=1, type="thermal", t_gen=T0), T0)
    assert (unknown.send, unknown.reason) == (False, "unknown-type")


def test_live_parameters_change_the_optimiser() -> None:
    mw = build_decider(_config())
    assert isinstance(mw, Middleware)
    result = mw.set_params({"mcts_iterations": 20, "alpha": 3.0, "time_budget_s": 0.2}, T0)
    assert result.ok and dict(result.applied) == {"mcts_iterations": 20, "alpha": 3.0,
                                                  "time_budget_s": 0.2}
    assert mw.config.max_iterations == 20 and mw.config.time_budget_s == 0.2
    assert mw.config.spec["image"].utility.params()["alpha"] == 3.0
    assert mw.knowledge.spec is mw.config.spec
    before = mw.config
    rejected = mw.set_params({"warp": 9}, T0)
    assert not rejected.ok and "unknown parameter 'warp'" in str(rejected.error)
    assert dict(rejected.applied) == {} and mw.config is before
    rejected = mw.set_params({"alpha": -1}, T0)
    assert "alpha must be a number >= 0" in str(rejected.error) and mw.config is before


def test_alpha_and_unknown_keys_from_the_config() -> None:
    mw = build_decider(_config(middleware={"alpha": 4.0, "seed": 3, "c": 0.5}))
    assert isinstance(mw, Middleware)
    assert mw.config.spec["image"].utility.params()["alpha"] == 4.0
    assert mw.config.c == 0.5
    with pytest.raises(AppSetupError, match=r"middleware.gamma: expected one of policy, seed, "
                                            r"alpha, c, horizon_s, tail_s, default_latency_s"):
        build_decider(_config(middleware={"gamma": 1}))
    with pytest.raises(AppSetupError, match=r"middleware: alpha must be a number >= 0"):
        build_decider(_config(middleware={"alpha": -4.0}))


def test_the_policy_is_a_config_value() -> None:
    """``[middleware] policy`` picks any registered policy, with its own keys."""
    assert isinstance(build_decider(_config(middleware={"policy": "send_all"})), SendAll)
    drop = build_decider(_config(middleware={"policy": "random_drop", "seed": 4,
                                             "drop_probability": 0.25, "any_version": True}))
    assert isinstance(drop, RandomDrop) and (drop.p, drop.any_version) == (0.25, True)
    with pytest.raises(ConfigError, match=r"middleware.policy: expected one of greedy, "
                                          r"knapsack_greedy, mcts, random_drop, send_all, "
                                          r"got 'best'"):
        _config(middleware={"policy": "best"})
    with pytest.raises(AppSetupError, match=r"middleware.c: expected one of policy, seed, "
                                            r"drop_probability, any_version, always_send$"):
        build_decider(_config(middleware={"policy": "random_drop", "c": 0.5}))
    with pytest.raises(AppSetupError, match=r"drop probability must be in \[0, 1\], got 2"):
        build_decider(_config(middleware={"policy": "random_drop", "drop_probability": 2}))


def test_reports_feed_deliveries_link_samples_and_round_trips() -> None:
    decider = build_decider(_config())
    sent = _image(0, T0, 0.3)
    decider.decide(sent, T0)
    mine = ReportEntry(sender="d1", seq=0, type="image", t_gen=T0, t_sent=T0 + 0.01,
                       t_rcv=T0 + 0.08, size=8_000, version=1, quality=0.5,
                       data={"red": 0.3, "object": False})
    theirs = ReportEntry(sender="d2", seq=5, type="image", t_gen=T0, t_sent=T0,
                         t_rcv=T0 + 0.05, size=9_000, data={"red": 0.0, "object": False})
    report = Report(entries=(mine, theirs),
                    echoes=(ClockEcho(sender="d1", t_sent=T0 + 0.01, t_rcv=T0 + 0.08),
                            ClockEcho(sender="d2", t_sent=T0, t_rcv=T0 + 0.05)))
    event = ReportReceived(report=report, reporter="gs", report_number=1, part_index=0,
                           part_count=1, t_sent=T0 + 0.1, t_rcv=T0 + 0.15,
                           addr=("127.0.0.1", 1))
    learned = decider.on_report(ReceiverReport.from_event(event), T0 + 0.15)
    assert (learned.delivered, learned.bad_entries) == (2, 0)
    assert (learned.link.link_samples, learned.link.round_trips,
            learned.link.bad_round_trips) == (1, 1, 0)
    assert isinstance(decider, Middleware)
    assert {k: decider.counters[k] for k in ("link_samples", "round_trips", "bad_round_trips",
                                              "delivered")} == {
        "link_samples": 1, "round_trips": 1, "bad_round_trips": 0, "delivered": 2}
    stats = decider.constraint.stats  # type: ignore[attr-defined]
    assert stats.counters["samples"] == 1
    assert stats.clock.get().n_samples == 1  # the round trip reached the clock estimator


def test_warm_up_leaves_the_real_optimiser_untouched() -> None:
    decider = build_decider(_config())
    assert isinstance(decider, Middleware)
    decider.warm_up()
    assert decider.counters["decisions"] == 0
