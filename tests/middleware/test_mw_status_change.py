"""A change of vehicle state is worth sending under the shipped spec, with images saturating
the link (issue 17: under ``status``/``last`` a newer status was never worth its bytes)."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from utility_specs.message import Message, Version
from utility_specs.spec import parse_spec

SPEC = parse_spec(tomllib.loads((Path(__file__).resolve().parents[2] / "utility_specs"
                                 / "missions" / "image_streaming.toml").read_text()))
VERSIONS = (Version(name="full", size=20_000, quality=1.0),
            Version(name="half", size=5_000, quality=0.5),
            Version(name="quarter", size=1_300, quality=0.25))
T0 = 1_700_000_000.0


def _run(budget_bytes_per_s: float, change_at: int) -> tuple[list[tuple[float, str, bool]],
                                                            Middleware]:
    """Images at 5 Hz, a status each second, reports each second with 0.3 s latency."""
    mw = Middleware(MiddlewareConfig(spec=SPEC, agent="d1", max_iterations=300),
                    constraint=ConstantConstraint(limit_bytes_per_s=budget_bytes_per_s,
                                                  window_s=1.0))
    mode, since, seq = "STABILIZE", T0, 0
    pending: list[Message] = []
    statuses = []
    for k in range(400):
        t = T0 + 0.05 * k
        if k % 20 == 0:
            mw.on_delivered([p for p in pending if p.t_rcv is not None and p.t_rcv <= t], t)
            pending = [p for p in pending if p.t_rcv is not None and p.t_rcv > t]
        if k % 4 == 0:
            m = Message(sender="d1", seq=seq, type="image", t_gen=t, size=20_000,
                        data={"red": 0.05}, versions=VERSIONS, version=0)
        elif k % 20 == 1 or k == change_at:
            if k == change_at:
                mode, since = "GUIDED", t
            m = Message(sender="d1", seq=seq, type="status", t_gen=t, size=150,
                        data={"mode": mode, "armed": mode == "GUIDED", "since": since})
        else:
            continue
        seq += 1
        d = mw.decide(m, t)
        if d.send:
            sent = m.with_version(d.version) if m.versions and d.version is not None else m
            pending.append(dataclasses.replace(sent, t_sent=t, t_rcv=t + 0.3, receiver="g"))
        if m.type == "status":
            statuses.append((round(t - T0, 2), mode, d.send))
    return statuses, mw


def test_the_first_status_of_a_new_state_goes_out_on_a_saturated_link() -> None:
    for change_at in (203, 307):  # between two periodic statuses
        statuses, mw = _run(3_000.0, change_at)
        assert mw.counters["sent"] < mw.counters["decisions"]  # images are dropped: saturated
        first_new = next(s for s in statuses if s[1] == "GUIDED")
        assert first_new == (round(0.05 * change_at, 2), "GUIDED", True), statuses


def test_the_optimiser_values_a_change_far_above_a_repeat() -> None:
    """The gain of the decided status (tree level 0, sent in full) with and without a change."""
    _, mw = _run(1e9, change_at=10_000)
    t = T0 + 20.01
    repeat = Message(sender="d1", seq=10_000, type="status", t_gen=t, size=150,
                     data={"mode": "STABILIZE", "armed": False, "since": T0})
    mw.decide(repeat, t)
    problem = mw.last_problem
    assert problem is not None
    gain_repeat = float(problem.gain[problem.decided_level, 1, 0])
    change = Message(sender="d1", seq=10_001, type="status", t_gen=t + 0.01, size=150,
                     data={"mode": "GUIDED", "armed": True, "since": t + 0.01})
    mw.decide(change, t + 0.01)
    problem = mw.last_problem
    assert problem is not None
    gain_change = float(problem.gain[problem.decided_level, 1, 0])
    assert gain_change > 10 * gain_repeat > 0, (gain_change, gain_repeat)
