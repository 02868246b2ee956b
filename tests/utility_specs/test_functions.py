"""Each utility function against values computed by hand from the thesis formulas."""

from __future__ import annotations

import math

import pytest

from tests.utility_specs.helpers import msg
from utility_specs.errors import MessageError, SpecError
from utility_specs.functions import (
    Battery,
    External,
    Linear,
    Localization,
    ObjectImage,
    Objective,
    Position,
    RedImage,
    Status,
    StatusPoisson,
    Video,
    VideoVersions,
    make_function,
    video_coefficients,
)
from utility_specs.message import Message, Version


def test_battery_eq_4_9() -> None:
    fn = Battery(depletion_rate=0.01)
    m = msg(10.0, 11.0, level=0.5)
    # 1 - 0.01 * 5 / 0.5 = 0.9
    assert fn.value(m, 15.0) == pytest.approx(0.9)
    assert fn.expiry(m) == pytest.approx(60.0)  # 0.5 / 0.01 s after generation
    assert fn.value(m, 70.0) == 0.0
    # ∫_11^21 (1 - 0.02 (t - 10)) dt = 10 - 0.01 (11² - 1²) = 8.8
    assert fn.integral(m, 11.0, 21.0) == pytest.approx(8.8)
    # whole support from reception: ∫_1^50 (1 - 0.02 x) dx = 49 - 0.01 (2500 - 1) = 24.01
    assert fn.integral(m, 11.0, 1000.0) == pytest.approx(24.01)


def test_battery_rate_can_come_with_the_message() -> None:
    fn = Battery(depletion_rate=0.01)
    m = msg(0.0, 0.0, level=1.0, depletion_rate=0.1)
    assert fn.value(m, 5.0) == pytest.approx(0.5)


def test_position_eq_4_12() -> None:
    fn = Position(v_max=2.0, area=100.0)
    m = msg(0.0, 0.5)
    c = math.pi * 4 / 100
    assert fn.value(m, 2.0) == pytest.approx(1 - c * 4)
    assert fn.expiry(m) == pytest.approx(1 / math.sqrt(c))
    assert fn.integral(m, 1.0, 2.0) == pytest.approx(1.0 - c * (8 - 1) / 3)


def test_status_eq_4_14_is_one_after_reception() -> None:
    fn = Status()
    m = msg(1.0, 2.0)
    assert fn.value(m, 2.0) == 0.0
    assert fn.value(m, 2.0001) == 1.0
    assert fn.integral(m, 2.0, 5.0) == 3.0


def test_status_poisson_eq_4_16() -> None:
    fn = StatusPoisson(rate=0.5)
    m = msg(1.0, 1.0)
    assert fn.value(m, 3.0) == pytest.approx(math.exp(-1.0))
    assert fn.integral(m, 1.0, 3.0) == pytest.approx((1 - math.exp(-1.0)) / 0.5)


def test_objective_eq_4_18_reads_the_state() -> None:
    fn = Objective()
    m = msg(0.0, 0.0, objective="o2")
    assert fn.value(m, 1.0, {"objectives": ["o1", "o2"]}) == 1.0
    assert fn.value(m, 1.0, {"objectives": ["o1"]}) == 0.0
    assert fn.value(m, 1.0, {}) == 0.0


def test_localization_eq_4_20_removes_what_was_known() -> None:
    fn = Localization()
    first = msg(0.0, 1.0, seq=0, cells=[[0, 0], [1, 0], [2, 0]])
    second = msg(0.0, 2.0, seq=1, cells=[[2, 0], [3, 0]])
    prepared = fn.prepare([second, first])
    assert prepared is not None
    by_seq = {m.seq: m for m in prepared}
    state = {"observed_cells": [[1, 0], [2, 0], [3, 0], [4, 0]]}
    assert fn.value(by_seq[0], 5.0, state) == pytest.approx(2 / 4)  # cells 1, 2
    assert fn.value(by_seq[1], 5.0, state) == pytest.approx(1 / 4)  # cell 3 only: 2 was known


def test_localization_with_polygons() -> None:
    fn = Localization()
    first = msg(0.0, 1.0, seq=0, area=[[0, 0], [2, 0], [2, 2], [0, 2]])
    second = msg(0.0, 2.0, seq=1, area=[[1, 0], [3, 0], [3, 2], [1, 2]])
    prepared = fn.prepare([first, second])
    assert prepared is not None
    observed = {"observed_area": [[0, 0], [4, 0], [4, 1], [0, 1]]}  # area 4
    assert fn.value(prepared[0], 3.0, observed) == pytest.approx(2 / 4)
    assert fn.value(prepared[1], 3.0, observed) == pytest.approx(1 / 4)  # new part [2,3]x[0,1]


def test_video_coefficients_eq_4_31_4_32() -> None:
    k, l = video_coefficients(0.1, 24.0, 12.0)  # noqa: E741
    assert k == pytest.approx(0.1 / (1 - 12 / (48 * math.log(2))))
    assert l == pytest.approx(1 + math.log2(1 / 24) * k)
    with pytest.raises(SpecError, match="f_1"):
        video_coefficients(0.1, 24.0, 40.0)


def test_video_eq_4_28_is_capped_to_0_1() -> None:
    fn = Video(S=0.1, f_max=24.0, f_1=12.0)
    m = msg(0.0, 0.0)
    assert fn.value(m, 0.0) == 1.0
    assert fn.value(m, 1 / 24) == pytest.approx(1.0)
    assert fn.value(m, 0.5) == pytest.approx(fn.l - fn.k * math.log2(0.5))
    assert fn.value(m, fn.x_zero + 1) == 0.0
    # ∫_0^x0 of the capped log = 1/24 + ∫_{1/24}^{x0} (l - k log2 x) dx
    x0, x1 = 1 / 24, fn.x_zero
    antiderivative = lambda x: fn.l * x - fn.k * (x * math.log(x) - x) / math.log(2)  # noqa: E731
    expected = x0 + antiderivative(x1) - antiderivative(x0)
    assert fn.integral(m, 0.0, 100.0) == pytest.approx(expected)


def test_video_versions_eq_4_33_scales_by_diagonal() -> None:
    fn = VideoVersions(S=0.1, f_max=24.0, f_1=12.0)
    m = msg(0.0, 0.0, diagonal=400.0, full_diagonal=800.0)
    assert fn.value(m, 1.0) == pytest.approx(0.5 * Video().shape(1.0))
    versions = (
        Version(name="full", size=100, quality=1.0),
        Version(name="q", size=10, quality=0.25),
    )
    v = Message(sender="a", seq=0, type="x", t_gen=0.0, t_rcv=0.0, versions=versions, version=1)
    assert fn.value(v, 1.0) == pytest.approx(0.25 * Video().shape(1.0))


def test_red_image_eq_7_1_and_object_image_eq_7_2() -> None:
    red = RedImage(alpha=10.0)
    base = Video()
    m = msg(0.0, 0.1, red=0.3)
    assert red.value(m, 1.0) == pytest.approx(base.value(m, 1.0) * 4.0)
    obj = ObjectImage(alpha=10.0)
    assert obj.value(msg(0.0, 0.1, object=True), 1.0) == pytest.approx(11 * base.value(m, 1.0))
    assert obj.value(msg(0.0, 0.1, object=False), 1.0) == pytest.approx(base.value(m, 1.0))
    with pytest.raises(MessageError, match="red"):
        red.value(msg(0.0, 0.1, red=1.5), 1.0)


def test_external_eq_4_34_is_an_impulse() -> None:
    fn = External()
    assert fn.impulse
    assert fn.impulse_value(msg(0.0, 1.0, value=3.5)) == 3.5
    assert fn.aggregations == {"sum"}


def test_linear_from_the_study_of_ch_5_4() -> None:
    fn = Linear(initial=2.0, slope=0.5)
    m = msg(1.0, 1.0)
    assert fn.value(m, 3.0) == pytest.approx(1.0)
    assert fn.expiry(m) == pytest.approx(5.0)
    assert fn.integral(m, 1.0, 10.0) == pytest.approx(4.0)  # triangle 2 * 4 / 2


def test_make_function_names_bad_params() -> None:
    with pytest.raises(SpecError, match="unknown utility 'nope'"):
        make_function("nope", {})
    with pytest.raises(SpecError, match="depletion_rate"):
        make_function("battery", {"depletion_rate": -1})
    with pytest.raises(SpecError, match="bad params"):
        make_function("battery", {"rate": 1})


def test_missing_data_field_is_a_clear_error() -> None:
    with pytest.raises(MessageError, match="level"):
        Battery(depletion_rate=0.01).value(msg(0.0, 0.0), 1.0)
