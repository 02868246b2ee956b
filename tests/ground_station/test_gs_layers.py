"""The ground station does not import the simulator (issue 14: no upward import).

``sitl`` may import everything; ``ground_station`` sits below it. KNOWN_UPWARD names the
modules that still reach up (none now: the dashboard map reads scene files through
``utility_specs.scene``, as the simulator does), so the list can only shrink.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.companion.test_companion_layers import _upward_imports

ROOT = Path(__file__).resolve().parents[2]
KNOWN_UPWARD: frozenset[str] = frozenset()


def upward_by_module() -> dict[str, list[str]]:
    hits: dict[str, list[str]] = {}
    for path in sorted((ROOT / "ground_station").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        found = [f"{line}: {name}" for line, name in _upward_imports(tree)]
        if found:
            hits[path.relative_to(ROOT).as_posix()] = found
    return hits


def test_no_module_under_ground_station_imports_sitl() -> None:
    hits = upward_by_module()
    new = {name: lines for name, lines in hits.items() if name not in KNOWN_UPWARD}
    assert new == {}, f"ground_station must not import sitl: {new}"
    stale = sorted(KNOWN_UPWARD - set(hits))
    assert stale == [], f"remove from KNOWN_UPWARD (no longer imports sitl): {stale}"
