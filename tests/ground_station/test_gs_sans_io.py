"""The ground station's cores stay sans-I/O: time comes in as ``now``, nothing else."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "ground_station"
CORES = ["missions.py", "reports.py", "fleet.py", "utility.py", "broadcast.py"]
FORBIDDEN = {"socket", "threading", "time", "sqlite3", "cv2", "aiohttp", "os", "random"}


@pytest.mark.parametrize("name", CORES)
def test_core_imports_no_io(name: str) -> None:
    tree = ast.parse((PACKAGE / name).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{name} imports {sorted(imported & FORBIDDEN)}"
