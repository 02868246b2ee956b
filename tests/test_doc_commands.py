"""Every console-script command README.md and docs/*.md show exists with the flags they give
it: a newcomer who copies ``uav-sitl fleet --relay-queue 20000`` from the README after a flag
was renamed gets a usage error instead of the run the docs promise. Each command's real
``--help`` (the installed console script, a subprocess) is the reference."""

from __future__ import annotations

import re
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.companion_process import console_script
from utility_specs.files import builtin_specs

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SUBCOMMANDS = {
    "uav-utility": ("evaluate", "plot", "specs"),
    "uav-companion": ("run", "check", "install-service"),
    "uav-ground-station": ("run", "shell", "export", "token", "keygen"),
    "uav-sitl": ("vehicle", "fleet", "camera", "study"),
}
_COMMAND = re.compile(r"(uav-utility|uav-companion|uav-ground-station|uav-sitl) ([a-z-]+)"
                      r"([^`\n]*)")
_FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def documented_commands(text: str) -> dict[tuple[str, ...], set[str]]:
    """``(script, subcommand[, study])`` -> the ``--flags`` written after it on its line (up
    to the end of the code span). Prose like "uav-sitl fleet's summary" names no flag."""
    found: dict[tuple[str, ...], set[str]] = {}
    for script, sub, rest in _COMMAND.findall(text):
        if sub not in SUBCOMMANDS[script]:
            continue
        command: tuple[str, ...] = (script, sub)
        if (script, sub) == ("uav-sitl", "study"):
            study = re.match(r" ([a-z0-9][a-z0-9.-]*)", rest)
            if study is None:  # "uav-sitl study fig5.7 | fig6.1 ..." lists: the first is taken
                continue
            command += (study.group(1).rstrip("."),)
            rest = rest[study.end():]
        found.setdefault(command, set()).update(_FLAG.findall(rest))
    return found


def _help(command: tuple[str, ...]) -> str:
    proc = subprocess.run([console_script(command[0]), *command[1:], "--help"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    return f"exit {proc.returncode}\n{proc.stdout}{proc.stderr}"


def test_documented_commands_and_flags_exist() -> None:
    wanted: dict[tuple[str, ...], set[str]] = {}
    for doc in DOCS:
        for command, flags in documented_commands(doc.read_text(encoding="utf-8")).items():
            wanted.setdefault(command, set()).update(flags)
    assert len(wanted) >= 20  # the docs show that many distinct commands today
    with ThreadPoolExecutor(4) as pool:
        helps = dict(zip(wanted, pool.map(_help, wanted), strict=True))
    problems = [f"{' '.join(c)}: --help failed: {h[:300]}" for c, h in helps.items()
                if not h.startswith("exit 0\n")]
    problems += [f"{' '.join(c)} {flag}: not in its --help" for c, flags in wanted.items()
                 for flag in sorted(flags) if flag not in helps[c]]
    assert problems == []


def test_documented_commands_reads_flags_of_the_right_command() -> None:
    text = ("`uav-sitl fleet --drones 2 --relay-rate 0` and `uav-sitl study fig5.7 --runs 3`;"
            " uav-sitl fleet's summary; `uav-utility plot all --out x`; uav-sitl nothing --x")
    assert documented_commands(text) == {
        ("uav-sitl", "fleet"): {"--drones", "--relay-rate"},
        ("uav-sitl", "study", "fig5.7"): {"--runs"},
        ("uav-utility", "plot"): {"--out"},
    }


def test_readme_names_every_builtin_spec() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert [s for s in builtin_specs() if f"`{s}`" not in readme] == []
