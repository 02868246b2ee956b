"""The systemd unit that keeps ``uav-companion run`` alive on the drone.

``Restart=on-failure`` restarts the companion after a crash but not after a clean stop
(SIGTERM from ``systemctl stop`` ends it with status 0). ``install_service`` writes the unit
and, unless told otherwise, runs ``systemctl daemon-reload`` and ``systemctl enable --now``.
"""

from __future__ import annotations

import grp
import os
import pwd
import shlex
import shutil
import stat
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "DEFAULT_UNIT_DIR",
    "SANDBOX",
    "UNIT_NAME",
    "InstallResult",
    "install_service",
    "make_folder_for",
    "unit_text",
    "unreadable_for",
]

DEFAULT_UNIT_DIR = Path("/etc/systemd/system")
UNIT_NAME = "uav-companion.service"

Runner = Callable[[Sequence[str]], int]


def _default_exec() -> list[str]:
    script = shutil.which("uav-companion")
    if script is not None:
        return [script]
    return [sys.executable, "-m", "companion.cli"]


SANDBOX = (
    # Least privilege: what the companion needs is its config and keys (read), its cache
    # and state folders, the mission log's folder, UDP/TCP sockets, and the autopilot's and
    # the camera's devices (so no PrivateDevices, nor ProtectClock: both cut /dev down).
    "NoNewPrivileges=yes",
    "PrivateTmp=yes",
    "ProtectSystem=full",
    "ProtectHome=read-only",
    "ProtectKernelTunables=yes",
    "ProtectKernelModules=yes",
    "ProtectControlGroups=yes",
    "RestrictSUIDSGID=yes",
    "RestrictRealtime=yes",
    "RestrictNamespaces=yes",
    "LockPersonality=yes",
    "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK",
)
"""The unit's hardening (``systemd-analyze security`` scores each). Before, the companion ran
as root with every privilege: any flaw in what parses the radio's datagrams was root's."""


def unit_text(*, config_path: Path, exec_argv: Sequence[str] | None = None,
              user: str | None = None, writable: Sequence[Path] = ()) -> str:
    """The unit file's text (pure; no file is touched). ``writable``: folders the service
    writes besides its cache and state folders (the mission log's)."""
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
        # exit 2 is a configuration error: said once in the journal, not every 2 s
        "RestartPreventExitStatus=2",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=15",
        "Environment=PYTHONUNBUFFERED=1",
        "Environment=MAVLINK20=1",
        # compiled kernels cache here even when the install is read-only (utility_specs.jit)
        "CacheDirectory=uav-companion",
        "Environment=NUMBA_CACHE_DIR=%C/uav-companion",
        "StateDirectory=uav-companion",  # /var/lib/uav-companion: the example's mission log
        *SANDBOX,
    ]
    if writable:  # "-": a folder that is not there yet does not stop the service
        lines.append("ReadWritePaths=" + " ".join(shlex.quote(f"-{p}") for p in writable))
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
                    exec_argv: Sequence[str] | None = None, writable: Sequence[Path] = (),
                    runner: Runner = _run) -> InstallResult:
    """Write the unit into ``unit_dir`` and enable it; ``dry_run`` only reports the plan.

    Raises OSError when the unit cannot be written and RuntimeError when systemctl fails.
    """
    text = unit_text(config_path=config_path, exec_argv=exec_argv, user=user,
                     writable=writable)
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


SERVICE_GROUPS = ("dialout", "video")
"""The groups the unit gives a ``--user`` (``SupplementaryGroups``)."""


def _groups_of(user: pwd.struct_passwd) -> set[int]:
    gids = {user.pw_gid}
    for group in grp.getgrall():
        if user.pw_name in group.gr_mem or group.gr_name in SERVICE_GROUPS:
            gids.add(group.gr_gid)
    return gids


def unreadable_for(user: str, paths: Sequence[Path]) -> str | None:
    """Why ``user`` (as the unit runs it) cannot read one of ``paths`` (None: it can read
    them all). A key only root could read passed install-service; the service then failed
    at every start with "a readable key file (Permission denied)"."""
    account = pwd.getpwnam(user)
    if account.pw_uid == 0:
        return None
    gids = _groups_of(account)
    for path in paths:
        for part in [*reversed(path.parents), path]:
            try:
                info = part.stat()
            except OSError as exc:
                return f"{path}: {exc.strerror}"
            need = stat.S_IROTH if part == path else stat.S_IXOTH
            if info.st_uid == account.pw_uid:
                need <<= 6
            elif info.st_gid in gids:
                need <<= 3
            if not info.st_mode & need:
                return (f"user {user} cannot read {path} ({part}: owner uid {info.st_uid}, "
                        f"mode {stat.S_IMODE(info.st_mode):04o})")
    return None


def make_folder_for(user: str | None, folder: Path) -> None:
    """Make the mission log's ``folder`` (and its missing parents) for the service's user:
    made by the service itself it would be in a read-only tree (``ProtectHome``)."""
    missing = [p for p in [*reversed(folder.parents), folder] if not p.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    if user is not None:
        account = pwd.getpwnam(user)
        for made in missing:
            os.chown(made, account.pw_uid, account.pw_gid)
