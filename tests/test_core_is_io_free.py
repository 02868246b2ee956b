"""The sans-I/O cores import no clock, socket, thread, camera or database module, and touch no
file: time and data come in as arguments."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {"asyncio", "socket", "threading", "time", "cv2", "sqlite3", "random", "subprocess"}
CORES = ["utility_specs", "companion/middleware", "companion/protocol"]
# thin tools at the edge: the command line, the plots, the spec/log file loaders
EDGES = {"utility_specs/cli.py", "utility_specs/cli_characteristics.py", "utility_specs/plots.py",
         "utility_specs/files.py"}
FILE_CALLS = {"open", "read_text", "write_text", "read_bytes", "write_bytes", "iterdir", "mkdir",
              "unlink", "files"}


def _core_files() -> list[Path]:
    files: list[Path] = []
    for core in CORES:
        path = ROOT / core
        if path.is_file():
            files.append(path)
        elif path.is_dir():
            files.extend(sorted(path.rglob("*.py")))
    return [f for f in files if str(f.relative_to(ROOT)) not in EDGES]


@pytest.mark.parametrize("path", _core_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_core_module_imports_no_io(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    imported: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{path.name} imports {sorted(imported & FORBIDDEN)}"


@pytest.mark.parametrize("path", _core_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_core_module_touches_no_file(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    calls = {
        node.func.id if isinstance(node.func, ast.Name) else node.func.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name | ast.Attribute)
    }
    assert not calls & FILE_CALLS, f"{path.name} calls {sorted(calls & FILE_CALLS)}"
