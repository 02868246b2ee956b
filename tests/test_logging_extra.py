"""Logging cannot break a code path: no ``extra=`` key anywhere clashes with a LogRecord field.

``logging.Logger.makeRecord`` raises ``KeyError: "Attempt to overwrite 'name' in LogRecord"``
for such a key, but only when the level is enabled, so a suite that runs with INFO off never
sees it (issue 11: mission commands were acknowledged and never executed). This scans the
source of every package instead of hoping a test happens to log at the right level.
"""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("companion", "ground_station", "sitl", "utility_specs")
RESERVED = set(vars(logging.LogRecord("x", logging.INFO, "f.py", 1, "m", None, None))) | {
    "message", "asctime"}


def _extra_keys(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, key) of every constant key given to an ``extra=`` keyword argument."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        for keyword in node.keywords:
            if keyword.arg != "extra":
                continue
            value = keyword.value
            if isinstance(value, ast.Dict):
                found += [(k.lineno, k.value) for k in value.keys
                          if isinstance(k, ast.Constant) and isinstance(k.value, str)]
            elif (isinstance(value, ast.Call) and isinstance(value.func, ast.Name)
                  and value.func.id == "dict"):
                found += [(value.lineno, kw.arg) for kw in value.keywords if kw.arg]
    return found


def test_the_scan_sees_a_clash() -> None:
    tree = ast.parse('log.info("x", extra={"name": 1, "drone": 2})\nf(extra=dict(msg=1))')
    clashes = [key for _, key in _extra_keys(tree) if key in RESERVED]
    assert clashes == ["name", "msg"]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_extra_key_overwrites_a_logrecord_attribute(package: str) -> None:
    clashes = []
    for path in sorted((ROOT / package).rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        clashes += [f"{path.relative_to(ROOT)}:{line}: extra key {key!r}"
                    for line, key in _extra_keys(tree) if key in RESERVED]
    assert not clashes, "these keys overwrite LogRecord attributes:\n" + "\n".join(clashes)


def test_the_debug_slice_runs_with_every_logger_at_debug() -> None:
    """tests/conftest.py runs a representative slice of the suite (``DEBUG_LOGGED``) with
    every logger at DEBUG, as ``--log-level debug`` would in the field; this file is in it."""
    from tests.conftest import DEBUG_LOGGED

    missing = [name for name in DEBUG_LOGGED if not (ROOT / name).is_file()]
    assert not missing, f"DEBUG_LOGGED names files that do not exist: {missing}"
    assert logging.getLogger("companion.app").isEnabledFor(logging.DEBUG)
    assert logging.getLogger("ground_station").isEnabledFor(logging.DEBUG)
