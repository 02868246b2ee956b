"""The companion never imports the simulator: ``sitl`` plugs its camera in, not the reverse."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
UPWARD = ("sitl",)


def _upward_imports(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, module) of every import of an upper layer, also inside functions and through
    ``importlib.import_module("...")`` / ``__import__("...")`` with a literal name."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(
                node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("import_module", "__import__"):
                names = [node.args[0].value]
        found += [(node.lineno, n) for n in names if n.split(".")[0] in UPWARD]
    return found


def test_the_scan_sees_every_form_of_import() -> None:
    tree = ast.parse("import sitl.camera\nfrom sitl import geo\ndef f():\n"
                     "    import importlib\n    importlib.import_module('sitl.scenes')\n"
                     "    __import__('sitl')\nimport sitlike\nfrom companion import sitl_x\n")
    assert _upward_imports(tree) == [(1, "sitl.camera"), (2, "sitl"), (5, "sitl.scenes"),
                                     (6, "sitl")]


def test_no_module_under_companion_imports_sitl() -> None:
    hits = []
    for path in sorted((ROOT / "companion").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        hits += [f"{path.relative_to(ROOT)}:{line}: imports {name}"
                 for line, name in _upward_imports(tree)]
    assert not hits, "companion must not import sitl:\n" + "\n".join(hits)


def test_the_companion_runs_its_setup_without_loading_sitl(tmp_path: Path) -> None:
    """Importing the app and the CLI and opening a non-synthetic camera load no sitl module;
    ``synthetic`` comes from sitl's entry point, loaded when a config names it."""
    (tmp_path / "a.png").write_bytes(b"")
    code = (
        "import sys\n"
        "import companion.app, companion.cli\n"
        "from companion.camera import CameraError, open_source\n"
        f"try:\n    open_source({str(tmp_path)!r}, width=64, height=48, rate_hz=1)\n"
        "except CameraError:\n    pass\n"
        "def loaded():\n"
        "    return sorted(m for m in sys.modules if m == 'sitl' or m.startswith('sitl.'))\n"
        "print(loaded())\n"
        "from companion.telemetry import TelemetrySnapshot\n"
        "source = open_source('synthetic', width=64, height=48, rate_hz=1,\n"
        "                     pose=TelemetrySnapshot)\n"
        "print(type(source).__module__, 'sitl.camera_source' in loaded())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, check=False, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["[]", "sitl.camera_source True"]
