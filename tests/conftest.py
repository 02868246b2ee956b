"""Project-wide test settings."""

from __future__ import annotations

import logging
import os
from collections.abc import Generator
from pathlib import Path

import pytest

# pymavlink picks its wire version from the environment at import time (STYLE.md): decide once.
os.environ.setdefault("MAVLINK20", "1")


def _load_stress_profile() -> None:
    """Opt-in stress run (``HYPOTHESIS_PROFILE=stress``) to find fragile properties before CI does.

    The default run is unchanged. ``stress`` asks for 500 examples where a test sets none, no
    deadline, no database (every run explores fresh), and ``pytest_collection_modifyitems`` below
    multiplies an explicit ``@settings(max_examples=N)`` by ``HYPOTHESIS_STRESS_FACTOR`` (10),
    since an explicit setting overrides a profile. Combine with ``--hypothesis-seed=N`` and
    ``-m hypothesis``. Known: at factor 10 (600 examples) test_compiled_and_curve_sweeps_agree
    can spend minutes inside hypothesis's own generation after the other properties ran (hits
    pytest's 300 s timeout); ``HYPOTHESIS_STRESS_FACTOR=1`` (500 examples) runs it in seconds.
    """
    from hypothesis import settings

    settings.register_profile("stress", max_examples=500, deadline=None, database=None)
    settings.load_profile("stress")


_STRESS = os.environ.get("HYPOTHESIS_PROFILE") == "stress"
if _STRESS:
    _load_stress_profile()


def pytest_collection_modifyitems(items: list) -> None:  # type: ignore[type-arg]
    if not _STRESS:
        return
    from hypothesis import settings

    factor = int(os.environ.get("HYPOTHESIS_STRESS_FACTOR", "10"))
    for item in items:
        test = getattr(item, "obj", None)
        # hypothesis reads this attribute when the test runs (an internal name: stress mode only).
        current = getattr(test, "_hypothesis_internal_use_settings", None)
        if current is None or not hasattr(test, "hypothesis"):
            continue
        if current.max_examples == settings.default.max_examples:
            continue  # no explicit max_examples: the profile's 500 already apply
        examples = max(current.max_examples * factor, settings.default.max_examples)
        test._hypothesis_internal_use_settings = settings(  # type: ignore[union-attr]
            current, max_examples=examples, deadline=None, database=None)


# Records are built only for enabled levels, so a logging call that raises does so only with
# its level on (issue 11: INFO was off in the tests). These files run with every logger at
# DEBUG, as ``--log-level debug`` would in the field: the whole pipeline and the command path
# (companion app and MAVLink), the station and its UDP receiver. The rest runs at the defaults.
DEBUG_LOGGED = (
    "tests/companion/test_companion_app.py",
    "tests/companion/test_companion_mavlink.py",
    "tests/ground_station/test_gs_app.py",
    "tests/integration/test_ground_station_udp.py",
    "tests/test_logging_extra.py",  # checks that the hook below is in force
)
_ROOT = Path(__file__).resolve().parents[1]
_DEBUG_LOGGED_PATHS = frozenset(_ROOT / name for name in DEBUG_LOGGED)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None
                            ) -> Generator[None, object, object]:
    if Path(item.path) not in _DEBUG_LOGGED_PATHS:
        return (yield)
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.DEBUG)  # what pytest's ``-o log_level=DEBUG`` does, for this file
    try:
        return (yield)
    finally:
        root.setLevel(level)
