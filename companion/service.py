"""The systemd unit that keeps ``uav-companion run`` alive on the drone.

``Restart=on-failure`` restarts the companion after a crash but not after a clean stop
(SIGTERM from ``systemctl stop`` ends it with status 0). ``install_service`` writes the unit
and, unless told otherwise, runs ``systemctl daemon-reload`` and ``systemctl enable --now``.
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ["DEFAULT_UNIT_DIR", "UNIT_NAME", "InstallResult", "install_service", "unit_text"]

DEFAULT_UNIT_DIR = Path("/etc/systemd/system")
UNIT_NAME = "uav-companion.service"

Runner = Callable[[Sequence[str]], int]


def _default_exec() -> list[str]:
    script = shutil.which("uav-companion")
    if script is not None:
        return [script]
    return [sys.executable, "-m", "companion.cli"]


def unit_text(*, config_path: Path, exec_argv: Sequence[str] | None = None,
              user: str | None = None) -> str:
    """The unit file's text (pure; no file is touched)."""
    argv = [*(exec_argv or _default_exec()), "run", "--config", str(config_path)]
    lines = [
        "[Unit]",
        "Description=UAV companion: utility-aware image and telemetry streaming",
        "After=network-online.target",
        "Wants=network-online.target",
        "",
        "[Service]",
        "Type=simple",
        f"ExecStart={shlex.join(argv)}",
        "Restart=on-failure",
        "RestartSec=2",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=15",
        "Environment=PYTHONUNBUFFERED=1",
        "Environment=MAVLINK20=1",
        # compiled kernels cache here even when the install is read-only (utility_specs.jit)
        "CacheDirectory=uav-companion",
        "Environment=NUMBA_CACHE_DIR=%C/uav-companion",
    ]
    if user:
        lines += [f"User={user}", "SupplementaryGroups=dialout video"]
    lines += ["", "[Install]", "WantedBy=multi-user.target", ""]
    return "\n".join(lines)


@dataclass(frozen=True, slots=True, kw_only=True)
class InstallResult:
    unit_path: Path
    text: str
    commands: tuple[tuple[str, ...], ...]
    written: bool


def _run(argv: Sequence[str]) -> int:
    return subprocess.run(list(argv), check=False).returncode


def install_service(*, config_path: Path, unit_dir: Path = DEFAULT_UNIT_DIR,
                    dry_run: bool = False, enable: bool = True, user: str | None = None,
                    exec_argv: Sequence[str] | None = None,
                    runner: Runner = _run) -> InstallResult:
    """Write the unit into ``unit_dir`` and enable it; ``dry_run`` only reports the plan.

    Raises OSError when the unit cannot be written and RuntimeError when systemctl fails.
    """
    text = unit_text(config_path=config_path, exec_argv=exec_argv, user=user)
    unit_path = unit_dir / UNIT_NAME
    commands: tuple[tuple[str, ...], ...] = ()
    if enable:
        commands = (("systemctl", "daemon-reload"), ("systemctl", "enable", "--now", UNIT_NAME))
    if dry_run:
        return InstallResult(unit_path=unit_path, text=text, commands=commands, written=False)
    unit_dir.mkdir(parents=True, exist_ok=True)
    tmp = unit_path.with_suffix(".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(unit_path)
    for argv in commands:
        code = runner(argv)
        if code != 0:
            raise RuntimeError(f"{shlex.join(argv)} failed with exit status {code}")
    return InstallResult(unit_path=unit_path, text=text, commands=commands, written=True)
