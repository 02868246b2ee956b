"""The one seam: the policy registry, typed reports, live parameters, the layer's errors."""

from __future__ import annotations

import importlib
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.app import AppSetupError, build_decider
from companion.config import ConfigError, parse_config
from companion.middleware import (
    DECIDERS,
    ConstantConstraint,
    DeciderSetup,
    Greedy,
    Middleware,
    MiddlewareConfig,
    MiddlewareError,
    ReceiverReport,
    SendAll,
    make_constraint,
    make_decider,
    register_decider,
)
from companion.middleware.constraints import AdaptiveConstraint, RoundTrip
from companion.middleware.errors import (
    ConstraintError,
    LinkStatsError,
    UnknownParamError,
    UnknownPolicyError,
)
from companion.middleware.reports import feed_link
from companion.protocol.records import ClockEcho, ReportEntry
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version

T0 = 1_700_000_000.0
DOC = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"
SPEC = builtin_spec("image_streaming")


def _setup(constraint: object | None = None, **kw: object) -> DeciderSetup:
    return DeciderSetup(spec=SPEC, agent="d1",
                        constraint=constraint or ConstantConstraint(limit_bytes_per_s=20_000.0),
                        rng=np.random.default_rng(0), max_iterations=50, **kw)  # type: ignore[arg-type]


def _image(seq: int, red: float, sender: str = "d1") -> Message:
    versions = (Version(name="full", size=20_000, quality=1.0),
                Version(name="half", size=5_000, quality=0.5))
    return Message(sender=sender, seq=seq, type="image", t_gen=T0 + seq, size=20_000,
                   data={"red": red, "object": False}, versions=versions, version=0)


def _doc_blocks(heading: str) -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    section = text.split(heading, 1)[1].split("\n### ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_docs_example_policy_is_one_module_and_one_registry_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    module_code, registry_line = _doc_blocks("### Adding a policy")
    (tmp_path / "red_only.py").write_text(module_code, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("red_only")
    entries = eval("{" + registry_line.strip() + "}", {"RedOnly": module.RedOnly})
    for name, factory in entries.items():
        monkeypatch.setitem(DECIDERS, name, factory)
    config = parse_config({"drone": {"id": "d1"},
                           "middleware": {"policy": "red_only", "threshold": 0.5}})
    decider = build_decider(config)
    assert isinstance(decider, module.RedOnly) and decider.threshold == 0.5
    assert decider.decide(_image(0, 0.6), T0).send
    dropped = decider.decide(_image(1, 0.2), T0 + 1)
    assert (dropped.send, dropped.reason) == (False, "not-red")
    status = Message(sender="d1", seq=2, type="status", t_gen=T0, size=40, data={})
    assert decider.decide(status, T0).send
    assert not decider.set_params({"threshold": 0.1}, T0).ok  # no live parameters
    with pytest.raises(AppSetupError, match=r"middleware.gamma: expected one of policy, seed, "
                                            r"threshold$"):
        build_decider(parse_config({"drone": {"id": "d1"},
                                    "middleware": {"policy": "red_only", "gamma": 1}}))


def test_registry_names_and_errors() -> None:
    assert sorted(DECIDERS) == ["greedy", "knapsack_greedy", "mcts", "random_drop", "send_all"]
    assert isinstance(make_decider("mcts", _setup()), Middleware)
    assert isinstance(make_decider("greedy", _setup()), Greedy)
    with pytest.raises(UnknownPolicyError, match=r"unknown policy 'best'; expected one of "
                                                 r"greedy, knapsack_greedy, mcts"):
        make_decider("best", _setup())
    with pytest.raises(UnknownParamError, match=r"unknown parameter 'p' for the random_drop "
                                                r"policy \(known: drop_probability, "
                                                r"any_version, always_send\)"):
        make_decider("random_drop", _setup(), p=0.5)
    with pytest.raises(MiddlewareError, match="already registered"):
        register_decider("mcts", SendAll.from_setup)
    with pytest.raises(ConfigError, match=r"middleware.policy: expected one of .*got 3"):
        parse_config({"drone": {"id": "d1"}, "middleware": {"policy": 3}})


def test_a_registered_policy_is_accepted_by_the_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(DECIDERS, "plain", raising=False)
    register_decider("plain", SendAll.from_setup)
    try:
        config = parse_config({"drone": {"id": "d1"}, "middleware": {"policy": "plain"}})
        assert isinstance(build_decider(config), SendAll)
    finally:
        del DECIDERS["plain"]


def test_the_layer_raises_its_own_errors() -> None:
    with pytest.raises(ConstraintError, match="unknown goodput constraint 'sgd'"):
        make_constraint("sgd")
    with pytest.raises(ConstraintError, match="bad parameters for goodput constraint"):
        make_constraint("constant", limit_bytes_per_s="fast")
    with pytest.raises(LinkStatsError, match=r"t_rcv .* is before t_sent"):
        RoundTrip(t_sent=2.0, t_remote_rcv=1.0, t_remote_sent=1.5, t_rcv=1.0)
    with pytest.raises(MiddlewareError, match="agent must not be empty"):
        MiddlewareConfig(spec=SPEC, agent="")
    for error in (ConstraintError, LinkStatsError, UnknownPolicyError):
        assert issubclass(error, MiddlewareError) and issubclass(error, ValueError)


def test_a_report_feeds_knowledge_and_link_statistics_and_hides_no_bug() -> None:
    mw = make_decider("mcts", _setup(AdaptiveConstraint(window_s=0.5)))
    assert isinstance(mw, Middleware)
    mw.decide(_image(0, 0.3), T0)
    mine = ReportEntry(sender="d1", seq=0, type="image", t_gen=T0, t_sent=T0 + 0.01,
                       t_rcv=T0 + 0.08, size=5_000, version=1, quality=0.5,
                       data={"red": 0.3, "object": False})
    unreadable = ReportEntry(sender="d2", seq=1, type="battery", t_gen=T0, t_sent=T0,
                             t_rcv=T0 + 0.05, size=10, data={"level": "x"})
    report = ReceiverReport(entries=(mine, unreadable),
                            echoes=(ClockEcho(sender="d1", t_sent=T0 + 0.5, t_rcv=T0 + 0.3),),
                            t_sent=T0 + 0.2, t_rcv=T0 + 0.6)
    learned = mw.on_report(report, T0 + 0.6)
    # the battery level cannot be read: not learned (only d1's image is delivered); the
    # echo's t_rcv is later than the report's own send: an impossible round trip, skipped
    assert (learned.delivered, learned.bad_entries, learned.link.link_samples,
            learned.link.round_trips, learned.link.bad_round_trips) == (1, 0, 1, 0, 1)
    assert mw.counters["delivered"] == 1 and mw.counters["link_samples"] == 1
    assert mw.counters["bad_round_trips"] == 1
    with pytest.raises(AttributeError):  # a wrong object is a bug, not a bad entry
        mw.on_report(ReceiverReport(entries=("not an entry",)), T0 + 1)  # type: ignore[arg-type]


def test_feed_link_is_the_link_half_alone() -> None:
    """What the link emulator and the adaptive study call: same samples, same round trips."""
    constraint = AdaptiveConstraint(window_s=0.5)
    entries = tuple(ReportEntry(sender="probe", seq=k, type="probe", t_gen=T0 + 0.1 * k,
                                t_sent=T0 + 0.1 * k, t_rcv=T0 + 0.1 * k + 0.02, size=1000)
                    for k in range(10))
    report = ReceiverReport(entries=entries, echoes=(ClockEcho(sender="probe",
                                                               t_sent=T0 + 0.9,
                                                               t_rcv=T0 + 0.92),),
                            t_sent=T0 + 1.0, t_rcv=T0 + 1.03)
    fed = feed_link(constraint, report, agent="probe", now=T0 + 1.03)
    assert (fed.link_samples, fed.round_trips, fed.bad_round_trips) == (10, 1, 0)
    assert constraint.stats.counters["samples"] == 10
    offset = constraint.stats.clock.get()
    assert offset is not None and offset.offset_s == pytest.approx(
        ((0.92 - 0.9) + (1.0 - 1.03)) / 2)
    assert feed_link(constraint, ReceiverReport(entries=entries), agent="other",
                     now=T0 + 2).link_samples == 0


def test_baselines_take_constraint_parameters_only() -> None:
    greedy = make_decider("greedy", _setup())
    result = greedy.set_params({"constraint.limit_bytes_per_s": 5000}, T0)
    assert result.ok and dict(result.applied) == {"constraint.limit_bytes_per_s": 5000.0}
    assert greedy.constraint.limit_bytes_per_s(now=T0) == 5000.0  # type: ignore[attr-defined]
    refused = greedy.set_params({"constraint.limit_bytes_per_s": 1, "alpha": 2}, T0)
    assert not refused.ok and "no live parameters but constraint.NAME" in str(refused.error)
    assert greedy.constraint.limit_bytes_per_s(now=T0) == 5000.0  # type: ignore[attr-defined]
    assert not make_decider("send_all", _setup()).set_params({"x": 1}, T0).ok


KEYS = st.sampled_from(["mcts_iterations", "time_budget_s", "alpha", "c", "max_items",
                        "constraint.alpha_bytes_per_s", "constraint.min_bytes_per_s",
                        "constraint.learning_rate", "constraint.window_s", "warp"])
VALUES = st.one_of(st.integers(-5, 10**7), st.floats(-10.0, 1e8), st.just(math.nan),
                   st.booleans(), st.text(max_size=3), st.none())


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(KEYS, VALUES, max_size=4))
def test_set_params_applies_all_or_nothing(params: dict[str, object]) -> None:
    """Whatever comes in: either every key is applied as reported, or nothing changes."""
    constraint = AdaptiveConstraint(window_s=0.5)
    mw = make_decider("mcts", _setup(constraint))
    assert isinstance(mw, Middleware)
    config, numbers = mw.config, dict(vars(constraint))
    result = mw.set_params(params, T0)  # type: ignore[arg-type]
    if not result.ok:
        assert result.error and not result.applied
        assert mw.config is config and mw.knowledge.spec is config.spec
        assert {k: v for k, v in vars(constraint).items() if isinstance(v, float)} == {
            k: v for k, v in numbers.items() if isinstance(v, float)}
        return
    assert set(result.applied) == set(params)
    for key, value in result.applied.items():
        if key.startswith("constraint."):
            assert getattr(constraint, key.removeprefix("constraint.")) == value
        elif key == "mcts_iterations":
            assert mw.config.max_iterations == value
        elif key == "alpha":
            assert mw.config.spec["image"].utility.params()["alpha"] == value
            assert mw.knowledge.spec is mw.config.spec
        else:
            assert getattr(mw.config, key) == value
        assert isinstance(value, int | float) and math.isfinite(value)
