"""Every repository path README.md and docs/*.md name in backticks exists: a newcomer who
opens ``tests/middleware/test_mw_defaults_anytime.py`` after a test moved finds nothing."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
TOP = ("tests/", "companion/", "ground_station/", "sitl/", "utility_specs/", "benchmarks/",
       "docs/", "examples/")


def named_paths(text: str) -> list[str]:
    """Backticked repository paths; globs, placeholders and shell lines are not paths."""
    found = []
    for quoted in re.findall(r"`([^`\s]+)`", text):
        path = quoted.split("::")[0].rstrip("/:,.")
        if path.startswith(TOP) and not any(c in path for c in "*<>{}[]|$"):
            found.append(path)
    return found


def test_named_paths_exist() -> None:
    missing = [f"{doc.relative_to(ROOT)}: {path}" for doc in DOCS
               for path in named_paths(doc.read_text(encoding="utf-8"))
               if not (ROOT / path).exists()]
    assert missing == []


def test_named_paths_finds_paths() -> None:
    text = "see `tests/a.py::test_b`, `docs/*.md`, `sitl/relay.py` and `--out DIR`"
    assert named_paths(text) == ["tests/a.py", "sitl/relay.py"]
