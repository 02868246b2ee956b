"""first_number: the one reader of numbers in message data (peer table, dashboard, mirror)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from utility_specs.data_fields import first_number, is_number


def test_first_finite_number_among_the_spellings() -> None:
    data = {"lat": 47.5, "lat_deg": float("nan"), "alt": True, "alt_m": "12", "fix": 3}
    assert first_number(data, "lat_deg", "lat") == 47.5
    assert first_number(data, "alt", "alt_m") is None  # a bool and a string are not numbers
    assert first_number(data, "fix") == 3.0 and isinstance(first_number(data, "fix"), float)
    assert first_number(data) is None
    assert first_number({}, "lat") is None


values = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=3))


@given(st.dictionaries(st.sampled_from("abcd"), values), st.lists(st.sampled_from("abcde")))
def test_it_is_the_first_key_whose_value_is_a_finite_number(data: dict[str, object],
                                                             keys: list[str]) -> None:
    numbers = [data[k] for k in keys if k in data and is_number(data[k])]
    got = first_number(data, *keys)
    if not numbers:
        assert got is None
    else:
        assert got == float(numbers[0]) and math.isfinite(got)
        assert not isinstance(numbers[0], bool)
