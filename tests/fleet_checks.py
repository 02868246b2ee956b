"""Checks on a finished ``uav-sitl fleet`` run folder and output, shared by the fleet tests."""

from __future__ import annotations

import os
from pathlib import Path


def warm_before_start(run_dir: Path, drone: str) -> None:
    """The companion's own log: "optimiser warmed up" comes before it takes the start."""
    lines = (run_dir / "logs" / f"{drone}.log").read_text().splitlines()
    warm = [i for i, line in enumerate(lines) if "optimiser warmed up in" in line]
    start = [i for i, line in enumerate(lines) if "command start #" in line]
    assert warm and start, "\n".join(lines[-40:])
    assert warm[0] < start[0], "\n".join(lines[max(0, start[0] - 5):warm[0] + 5])


def warm_up_progress(stdout: str, n: int) -> list[str]:
    """The launcher's warm-up lines; the last says all ``n`` are warm, before the start."""
    lines = stdout.splitlines()
    started = next(i for i, line in enumerate(lines) if line.startswith("mission started"))
    warm = [line for line in lines[:started] if "companions" in line and "warm" in line]
    assert warm and warm[-1].startswith(f"companions warm: {n}/{n}"), stdout[-3000:]
    return warm


def summary_drones(run_dir: Path) -> list[str]:
    """The drones of a run, from the companions' log files."""
    return sorted(p.stem for p in (run_dir / "logs").glob("drone*.log"))


def processes_of(run_dir: Path) -> list[str]:
    """Command lines of live processes that mention the run folder (the fleet's children)."""
    found = []
    needle = str(run_dir).encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            state = (entry / "stat").read_text().split(") ")[-1][:1]
        except OSError:
            continue
        if needle in cmdline and state != "Z":
            found.append(cmdline.replace(b"\0", b" ").decode(errors="replace"))
    return found
