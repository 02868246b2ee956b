"""The package's one root finder, and the thesis code's message sequence replayed (issue 18)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.baselines import SendAll
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from utility_specs._envelope import falsi_point
from utility_specs.curves import ShapeCurve
from utility_specs.files import builtin_spec

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "benchmarks" / "data"
VIDEO = builtin_spec("image_streaming").types["image"].utility


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 2.0), st.floats(0.3, 1.0), st.floats(0.0, 2.0), st.floats(0.05, 0.3))
def test_a_crossing_is_bracketed_to_a_microsecond(g1: float, s1: float, dg: float,
                                                  s2: float) -> None:
    # an older large frame against a newer small one: the small one rises above it once
    shape = VIDEO._shape  # type: ignore[attr-defined]
    old, new = ShapeCurve(g1, s1, shape), ShapeCurve(g1 + dg, s2, shape)
    lo, hi = g1 + dg, g1 + dg + 60.0
    t = old.first_above(new, lo, hi)
    if t is None:  # never above: the new one is at or below the old one at the end too
        assert new.value(hi) <= old.value(hi) + 1e-12
        return
    assert new.value(t) > old.value(t) or t == lo
    if t > lo:
        assert new.value(t - 1e-6) <= old.value(t - 1e-6) + 1e-12 * (1 + old.value(t))


def test_the_root_finder_stops_at_a_microsecond_bracket() -> None:
    assert np.isnan(falsi_point(1.0, 1.0 + 5e-7, -1.0, 1.0))
    assert falsi_point(0.0, 1.0, -1.0, 3.0) == 0.25  # the secant's zero


def test_the_reference_sequence_file_is_its_recipe() -> None:
    sys.path.insert(0, str(DATA))
    try:
        from make_infdist_preset0 import generate  # type: ignore[import-not-found]
    finally:
        sys.path.remove(str(DATA))
    with (DATA / "infdist_preset0_seed0.csv").open(newline="") as f:
        stored = list(csv.DictReader(f))
    fresh = generate()
    assert len(stored) == len(fresh) == 990  # the count for preset 0
    for a, b in zip(stored, fresh, strict=True):
        assert int(a["sender"]) == b["sender"] and int(a["k"]) == b["k"]
        assert abs(float(a["t_gen"]) - b["t_gen"]) < 1e-8
        assert abs(float(a["depletion_rate"]) - b["depletion_rate"]) < 1e-8


def test_a_recorded_sequence_is_replayed_as_recorded() -> None:
    times = (0.5, 0.05, 2.0, 9.9, 10.5)  # out of order, one after the end
    agent = SimAgent(name="a", policy=SendAll(), streams=[StreamConfig(
        type="battery_0", period_s=1.0, size=100, times=times,
        data=lambda k, g: {"level": 1.0, "depletion_rate": 0.1 * (k + 1)})])
    result = simulate([agent], channel=ChannelConfig(capacity_bytes_per_s=1e6), t_end=10.0,
                      rng=np.random.default_rng(0))
    got = sorted((m.t_gen, m.data["depletion_rate"]) for m in result.generated)
    assert got == [(0.05, 0.2), (0.5, 0.1), (2.0, 0.30000000000000004), (9.9, 0.4)]
