"""The codec stays I/O free: no module of companion.protocol imports a clock, socket or thread."""

from __future__ import annotations

import ast
from pathlib import Path

import companion.protocol

FORBIDDEN = {"asyncio", "socket", "threading", "time", "cv2", "sqlite3", "random", "os", "select"}


def imported_modules(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_codec_modules_import_no_io() -> None:
    package = Path(companion.protocol.__file__).parent
    files = sorted(package.glob("*.py"))
    assert len(files) >= 5
    offenders = {
        f.name: sorted(imported_modules(f) & FORBIDDEN)
        for f in files
        if imported_modules(f) & FORBIDDEN
    }
    assert offenders == {}


def test_the_check_itself_catches_a_forbidden_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import time\nfrom asyncio import sleep\n")
    assert imported_modules(bad) & FORBIDDEN == {"time", "asyncio"}
